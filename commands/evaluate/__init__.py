"""``pipeline evaluate``: a run's ground and DTM against references."""
