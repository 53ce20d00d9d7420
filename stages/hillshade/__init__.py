"""Stage ``hillshade``: the shaded relief of the DTM."""
