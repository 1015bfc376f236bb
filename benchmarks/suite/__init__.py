"""Benchmark instances and peer solvers, installed as ``agrifleet_bench``.

``farm``: a seeded farm generator (fields x machines of different speeds, widths and
capacities) and two lower bounds on its makespan, one that ignores travel and one that
counts the travel no plan avoids; ``peers``: OR-Tools
and PyVRP models of the same problems (the optional extra ``agrifleet[bench]``).
``agrifleet bench mtsp`` and ``agrifleet bench farm`` (dispatcher.tools.bench) run them.
"""
