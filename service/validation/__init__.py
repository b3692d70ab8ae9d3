"""Validation of the measurements against the ones a crew took by hand (the paper's Table 1)."""
