"""agrifleet's dispatcher: from a planned farm to tractors driving it, and back to a review.

Data flows one way, and so do the imports (checked by ``make lint``, import-linter):

* :mod:`dispatcher.config` -- scenario and fleet files, the error hierarchy;
* :mod:`dispatcher.link` -- the wire: Zenoh key expressions and options, the MAVLink codec
  and constants, mission items, the mission and command protocols (what a vehicle needs);
* :mod:`dispatcher.mission` -- missions built from a plan, mission files, the plan document
  and its map;
* :mod:`dispatcher.recording` -- the MCAP log, written and read;
* :mod:`dispatcher.daemon` -- the dispatcher daemon and its fleet state;
* :mod:`dispatcher.review` -- what a run did, from its log: report, driving quality, plot;
* :mod:`dispatcher.tools` -- deployment tools: the bridge to a real autopilot, the router,
  the demo;
* :mod:`dispatcher.cli` -- the ``agrifleet`` command (parsing only).
"""
