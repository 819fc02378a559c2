"""Many scans and long use: `pointclm batch` throughput, faults (local and Ray), soak, and the
limits of what a scan may load."""
