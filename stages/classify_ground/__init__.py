"""Stage ``classify_ground``: ground (2) and the rest (1)."""
