"""The planner's exceptions: one hierarchy, messages a farm operator can act on."""


class PlannerError(Exception):
    """Base of every error the planner raises on bad input."""


class ProblemError(PlannerError, ValueError):
    """A problem instance (machines, tasks, arrays) is not valid."""


class TSPLIBError(PlannerError, ValueError):
    """A TSPLIB file cannot be read; the message names the file and line."""


class GeometryError(PlannerError, ValueError):
    """A field polygon or coordinate cannot be used; the message names the field."""
