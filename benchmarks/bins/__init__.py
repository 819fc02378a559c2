"""The bin-picking suite: bins of 20-80 parts seen by one depth camera."""
