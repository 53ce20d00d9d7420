"""The commands that are not stages: evaluate, info, budget, simulate, the config doc."""
