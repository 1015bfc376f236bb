"""From a farm plan to what leaves the planner: MAVLink waypoint missions
(:mod:`~dispatcher.mission.build`), mission files (:mod:`~dispatcher.mission.files`), the plan
document and the files of ``agrifleet plan`` (:mod:`~dispatcher.mission.plan`), the map."""
