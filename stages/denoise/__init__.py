"""Stage ``denoise``: isolated points and low outliers classed as noise."""
