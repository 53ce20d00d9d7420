"""Stage ``parse``: the survey's input files into points, or a trajectory and pulses."""
