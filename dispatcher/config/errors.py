"""The dispatcher's exceptions: one hierarchy, messages that name the file and key at fault."""


class DispatcherError(Exception):
    """Base of every error the dispatcher raises on bad input or a failed link."""


class ConfigError(DispatcherError, ValueError):
    """A scenario or fleet file is not valid; the message names the file and key."""
