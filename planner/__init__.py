"""agrifleet's planner: problem model, cost model, solvers and coverage geometry.

It knows nothing of MAVLink or Zenoh: it turns fields and machines into ordered routes.
"""
