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
