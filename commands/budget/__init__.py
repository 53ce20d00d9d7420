"""``pipeline budget``: seed 2's error budget."""
