"""What the suites share: report headers and paths (`report`), the peer methods (`peers`)."""
