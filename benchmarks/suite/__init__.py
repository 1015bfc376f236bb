"""Benchmark instances and peer solvers, installed as ``agrifleet_bench``.

``farm``: a seeded farm generator (fields x machines of different speeds, widths and
capacities) and a lower bound on its makespan that ignores travel; ``peers``: OR-Tools
and PyVRP models of the same problems (the optional extra ``agrifleet[bench]``).
``agrifleet bench mtsp`` and ``agrifleet bench farm`` (dispatcher.tools.bench) run them.
"""
