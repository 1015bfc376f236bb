"""The solver's numba kernels: compiled once per install, and said so while it happens.

The kernels are ``@njit(cache=True, nogil=True)``: numba compiles each on its first call
(about a minute for all of them, :data:`COMPILE_ESTIMATE_S`) and keeps the machine code
in its on-disk cache (``__pycache__`` beside the sources, or under ``NUMBA_CACHE_DIR``),
which later processes load in a fraction of a second. They release the GIL while they run:
the dispatcher re-plans in a thread beside its main loop, which goes on reading the fleet's
telemetry meanwhile (on another core when there is one). ``agrifleet warm`` (run by ``make`` after
installing) pays the compile at install; otherwise the first plan does.

Whether a process compiles or loads is told by numba's event API: numba broadcasts a
``numba:compile`` event for a real compile only, never for a load from its cache.

numba keys each cached kernel on its own source file only: a kernel whose callee in another
file changed (an upgrade, an edit) would load from the cache with the old callee compiled
in. :func:`drop_stale_kernels` (at the first solve of a process, and by ``agrifleet warm``)
empties the planner's cache when the planner's sources differ from those it was filled
from (a hash kept beside it, :data:`SOURCES_STAMP`); the cache's files are only deleted,
never read.
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from numba.core import event

log = logging.getLogger(__name__)

COMPILE_ESTIMATE_S = 55
"""Wall seconds to compile every kernel from an empty cache on our 2-core x86 machines (53 s
measured 2026-11-28 with 229 kernels, benchmarks/RESULTS.md, `agrifleet bench compile`); a
small ARM board takes longer."""


@dataclass(frozen=True)
class Compilation:
    """What making the kernels ready took: ``seconds`` of wall time, ``compiled`` functions
    numba compiled (0: all loaded from its cache), and where that cache is (None: unknown,
    or no JIT)."""

    seconds: float
    compiled: int
    cache_dir: str | None

    @property
    def cold(self) -> bool:
        """Whether numba had to compile (an empty or stale cache)."""
        return self.compiled > 0


class CompileWatch(event.Listener):
    """Counts numba's compiles while installed; calls ``on_first`` at the first one."""

    def __init__(self, on_first: Callable[[], None] | None = None) -> None:
        self.compiled = 0
        self._on_first = on_first

    def on_start(self, event: event.Event) -> None:
        self.compiled += 1
        if self.compiled == 1 and self._on_first is not None:
            self._on_first()

    def on_end(self, event: event.Event) -> None:
        pass


@contextmanager
def watch_compiles(on_first: Callable[[], None] | None = None) -> Iterator[CompileWatch]:
    """Within the block, count numba's compiles (loads from its cache are not counted)."""
    watch = CompileWatch(on_first)
    with event.install_listener("numba:compile", watch):
        yield watch


def cache_dir() -> str | None:
    """Where numba keeps the compiled kernels (it chooses: ``NUMBA_CACHE_DIR``, else
    ``__pycache__`` beside the sources when writable, else a per-user cache)."""
    from planner import cost

    stats = getattr(cost.evaluate, "stats", None)  # none under NUMBA_DISABLE_JIT
    return getattr(stats, "cache_path", None)


SOURCES_STAMP = "agrifleet-sources.sha256"
"""The file, in the kernels' cache folder, that holds the hash of the sources it was filled
from."""


def drop_stale(cache: Path, sources: Path) -> bool:
    """Delete numba's cached kernels in ``cache`` (``*.nbi``, ``*.nbc``) when the ``*.py``
    files of ``sources`` are not those the stamp in ``cache`` names, and stamp it with them;
    True when it did. Under a lock, so that processes starting together agree."""
    digest = hashlib.sha256()
    for path in sorted(sources.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    now = digest.hexdigest()
    cache.mkdir(parents=True, exist_ok=True)
    stamp = cache / SOURCES_STAMP
    with open(cache / (SOURCES_STAMP + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if stamp.exists() and stamp.read_text() == now:
            return False
        for path in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
            path.unlink(missing_ok=True)
        stamp.write_text(now)
    return True


def drop_stale_kernels() -> bool:
    """:func:`drop_stale` on the planner's kernels (nothing without a cache: no JIT)."""
    where = cache_dir()
    if where is None:
        return False
    dropped = drop_stale(Path(where), Path(__file__).parent)
    if dropped:
        log.info("the planner's sources changed: its compiled kernels are compiled again")
    return dropped


def compile_kernels(on_compile: Callable[[], None] | None = None) -> Compilation:
    """Make every solver kernel ready in this process: load it from numba's cache, or
    compile it (and cache it for later processes) when the cache is empty or stale.
    ``on_compile`` is called once, when numba starts to compile (never on a warm cache)."""
    from planner.solve import warm_up

    def first() -> None:
        log.info("compiling the solver's kernels (numba), once for this install")
        if on_compile is not None:
            on_compile()

    started = time.perf_counter()
    with watch_compiles(first) as watch:
        warm_up()
    return Compilation(time.perf_counter() - started, watch.compiled, cache_dir())
