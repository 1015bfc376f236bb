"""The wire between the dispatcher and the vehicles: Zenoh key expressions and options
(:mod:`~dispatcher.link.wire`), MAVLink encoding and constants (:mod:`~dispatcher.link.mavlink`),
the mission item (:mod:`~dispatcher.link.mission_item`), the ground-station side of the mission
and command protocols (:mod:`~dispatcher.link.mission_protocol`), and stopping on signals.
Everything a simulated tractor or the bridge needs, and nothing of the planner."""
