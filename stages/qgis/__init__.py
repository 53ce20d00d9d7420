"""Stage ``qgis``: QGIS styles beside the products (.qml) and a project of the delivery (project.qgz)."""
