"""The run's MCAP log: every frame, position, plan, status and log line, written by the
daemon and read back (also when cut short) by the review."""
