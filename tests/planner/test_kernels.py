"""Compiling the solver's kernels: a compile is told apart from a load from numba's cache
(on a tiny function of its own, not the solver's kernels)."""

import importlib.util
import textwrap

from planner.kernels import Compilation, drop_stale, watch_compiles

TINY = textwrap.dedent(
    """
    from numba import njit

    @njit(cache=True)
    def add_one(x):
        return x + 1
    """
)


def load_module(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_an_empty_cache_compiles_and_a_filled_one_loads(tmp_path):
    source = tmp_path / "tiny_kernel.py"
    source.write_text(TINY)
    told = []
    with watch_compiles(lambda: told.append("compiling")) as cold:
        assert load_module(source, "tiny_kernel_a").add_one(1) == 2
    assert cold.compiled == 1 and told == ["compiling"]  # said once, at the start
    assert list((tmp_path / "__pycache__").glob("*.nbi"))  # numba cached it beside the source
    # Another process would see a new dispatcher on the same source: it loads, says nothing.
    with watch_compiles(lambda: told.append("again")) as cached:
        assert load_module(source, "tiny_kernel_b").add_one(2) == 3
    assert cached.compiled == 0 and told == ["compiling"]


def test_a_compilation_is_cold_when_numba_compiled_something():
    assert Compilation(31.0, 167, "/cache").cold
    assert not Compilation(0.3, 0, "/cache").cold


def test_the_api_offers_it():
    import agrifleet
    from planner.kernels import compile_kernels

    assert agrifleet.compile_kernels is compile_kernels


def test_a_cache_filled_from_other_sources_is_emptied_once(tmp_path):
    sources, cache = tmp_path / "src", tmp_path / "src" / "__pycache__"
    sources.mkdir()
    (sources / "a.py").write_text("def inner(): return 1\n")
    (sources / "b.py").write_text("from a import inner\n")
    cache.mkdir()
    kept = cache / "b.cpython-311.pyc"
    for name in ("b.outer-1.py311.nbi", "b.outer-1.py311.1.nbc", kept.name):
        (cache / name).write_text("x")
    assert drop_stale(cache, sources)  # no stamp yet: filled from sources unknown
    assert [p.name for p in cache.iterdir() if p.suffix in (".nbi", ".nbc")] == []
    assert kept.exists()
    (cache / "b.outer-1.py311.nbi").write_text("x")  # filled again from these sources
    assert not drop_stale(cache, sources)
    assert (cache / "b.outer-1.py311.nbi").exists()
    # b's kernel calls a's: numba would load b's stale, a's file alone having changed.
    (sources / "a.py").write_text("def inner(): return 2\n")
    assert drop_stale(cache, sources)
    assert not (cache / "b.outer-1.py311.nbi").exists()
    assert not drop_stale(cache, sources)


WARMED = textwrap.dedent(
    """
    import importlib, pkgutil
    from numba.core.registry import CPUDispatcher
    import planner
    from planner.cost import Objective
    from planner.problem import Machine, Problem, Task
    from planner.solve import solve, stop_after, warm_up

    names = [m.name for m in pkgutil.iter_modules(planner.__path__)]
    modules = [importlib.import_module(f"planner.{name}") for name in names]

    def signatures():
        return {
            (module.__name__, name, str(sig))
            for module in modules
            for name, kernel in vars(module).items()
            if isinstance(kernel, CPUDispatcher)
            for sig in kernel.signatures
        }

    warm_up()
    warmed = signatures()
    machines = [Machine(f"w{i}", 2.0 + i, 10.0, 5.0 + i, 0.01, 1.0, 2.0) for i in range(3)]
    tasks = [Task(f"t{j}", j * 7 % 13, j * 5 % 11, 10.0, 4.0, 2.5) for j in range(12)]
    problem = Problem.build(machines, tasks, (0.0, 0.0))
    for objective in Objective:
        for algorithm in ("hybrid", "ighoa", "ga"):
            solve(problem, objective, algorithm, stop_after(3), seed=1)
    solve(problem, "makespan", "hybrid", stop_after(3), seed=1, finish_within_h=100.0)
    solve(problem, "makespan", "hybrid", stop_after(3), seed=1, makespan_slack=0.05)
    print(sorted(signatures() - warmed))
    """
)


def test_the_warm_up_makes_ready_every_kernel_a_plan_or_a_bench_uses():
    """`agrifleet warm` left the sweep of hybrid's min-max start out: the first min-max or
    makespan run compiled it in silence, inside its own time limit (a 1 s bench took
    11.6 s, 10 % off the best known)."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-c", WARMED], capture_output=True, text=True, timeout=300, check=True
    )
    assert done.stdout.strip() == "[]", done.stdout
