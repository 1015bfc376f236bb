"""Simulated tractors that speak MAVLink over Zenoh like an ArduPilot Rover."""
