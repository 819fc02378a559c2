"""Point-cloud suites: realistic scenes over the models, rooms, real frames, sparse and noisy
scans, speed (whole pipeline, FPFH, whole frames) and the verification of exact poses."""
