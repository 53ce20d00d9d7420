"""Stage ``contours``: contour lines of the DTM."""
