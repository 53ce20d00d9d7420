"""Stage ``georeference``: trajectory + pulses -> georeferenced points in strips."""
