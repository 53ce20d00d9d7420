"""Stage ``accuracy``: the DTM against check points and a truth raster."""
