"""The validation matrix: every scene kind times every sensor, pooled per row."""
