"""The shipped scenarios, fleets and farms (see README.md in this folder), installed with
agrifleet as the package ``agrifleet_config`` so that ``agrifleet demo`` and the paper's
experiments find them from an installed package as from a checkout."""
