"""Correspondence-level suites: the synthetic protocol, the numpy reference, the learned
embeddings and their ablations, network speed and the limits of each stage."""
