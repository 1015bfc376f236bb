"""agrifleet's dispatcher: missions, the MAVLink-over-Zenoh link, the daemon, recording,
review and the command line."""
