"""What every stage shares: point clouds, rasters, tiles, grids, units, CRSs, geodesy."""
