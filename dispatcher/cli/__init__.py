"""The ``agrifleet`` command: argument parsing only, each command forwarded to a typed
function of the package that does the work (``dispatcher.cli.main``)."""

from dispatcher.cli.main import main

__all__ = ["main"]
