"""agrifleet's command line (placeholder until the sub-commands land)."""


def main() -> int:
    return 0
