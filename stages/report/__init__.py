"""Stage ``report``: the QC page and the acceptance verdicts."""
