"""Stage ``classify_water``: water (ASPRS class 9) from the points and from a polygon layer."""
