"""The dispatcher daemon (:mod:`~dispatcher.daemon.server`) and the fleet state it keeps
(:mod:`~dispatcher.daemon.state`)."""
