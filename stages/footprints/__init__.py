"""Stage ``footprints``: building outlines (buildings.gpkg) and canopy height (canopy_height.tif)."""
