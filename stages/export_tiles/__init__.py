"""Stage ``export_tiles``: the DTM as COG tiles and a VRT."""
