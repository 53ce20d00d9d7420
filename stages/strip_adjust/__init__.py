"""Stage ``strip_adjust``: overlapping flight strips made to agree."""
