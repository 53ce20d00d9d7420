"""Stage ``export_las``: the classified points as LAZ (and COPC)."""
