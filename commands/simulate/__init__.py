"""``pipeline simulate``: a survey with known truth in every raw format."""
