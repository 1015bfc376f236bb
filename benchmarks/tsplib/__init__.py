"""The TSPLIB instances of the paper's tables, installed with agrifleet as the package
``agrifleet_tsplib`` (``agrifleet bench paper`` reads them)."""
