"""Stage ``classify_objects``: buildings (6) and vegetation (3, 4, 5) above the ground."""
