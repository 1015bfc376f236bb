"""Simulated tractors that speak MAVLink over Zenoh like an ArduPilot Rover.

* :mod:`sim_vehicles.mission_server` -- the vehicle side of the mission protocol
  (:class:`~sim_vehicles.mission_server.MissionServer`), sans-IO.
* :mod:`sim_vehicles.tractor` -- one simulated vehicle
  (:class:`~sim_vehicles.tractor.SimTractor`, :class:`~sim_vehicles.tractor.RoverParams`),
  sans-IO, exact in simulated time.
* :mod:`sim_vehicles.runner` -- :func:`~sim_vehicles.runner.run`, the Zenoh I/O for any
  number of them; ``python -m sim_vehicles`` is its command line.
"""
