"""Stage ``rasterize``: DTM, DSM, nDSM and density rasters."""
