"""Deployment tools: the bridge to a real ArduPilot autopilot, the Zenoh router, and the demo
that runs a whole farm on one machine."""
