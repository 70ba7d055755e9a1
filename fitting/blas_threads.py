"""One BLAS thread for the span of a fit (`one_blas_thread`): the OpenBLAS copies that NumPy and SciPy load.

SciPy's TRF (`rtfit.fitting.fit_method`, ``solver="trf"``) calls BLAS on the m × p Jacobian several times an
iteration (its gradient, the trust-region SVD, the quadratic models' products) with m ≈ 10⁴ and p ≤ 7: work
of tens of microseconds that OpenBLAS splits over all its threads, which then spin-wait for each other on a
loaded machine. Measured (2 shared cores, load ≈ 2–8): one ``evaluate_quadratic`` on an 11466 × 5 Jacobian
took 0.55 ms CPU with the default threads against 0.037 ms with one; the Cornell-box audit's 29 fits
(64² × 32 spp) 27.9 CPU s against 12.9 s (``OPENBLAS_NUM_THREADS=1``).

The thread count is set through each loaded OpenBLAS library's own ``*_set_num_threads*`` entry point
(found in ``/proc/self/maps`` and called with ctypes, as ``threadpoolctl`` does) and put back on exit. Where
none is found (another BLAS, another OS) nothing changes.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["blas_thread_counts", "one_blas_thread", "one_blas_thread_by_default"]

_SYMBOLS = (
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
    ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
    ("openblas_get_num_threads", "openblas_set_num_threads"),
)


_BLAS_MODULES = ("numpy", "scipy.linalg")
"""The modules whose import loads an OpenBLAS (NumPy's copy, SciPy's): the scan of the loaded libraries
(`_loaded_openblas`) is made again only when one of them has been imported since the last."""
_SCANNED: dict[tuple[str, ...], tuple[str, ...]] = {}


def _loaded_openblas() -> tuple[str, ...]:
    """The paths of the OpenBLAS libraries loaded in this process (none where /proc/self/maps is absent),
    scanned once per set of imported `_BLAS_MODULES`. Issue 33: a process that has run Dr.Jit's LLVM
    kernels maps thousands of regions, and the scan at every fit took ~2 ms (0.5 s of a quick suite's
    ~270 fits)."""
    token = tuple(m for m in _BLAS_MODULES if m in sys.modules)
    known = _SCANNED.get(token)
    if known is None:
        known = _SCANNED[token] = _scan_openblas()
    return known


def _scan_openblas() -> tuple[str, ...]:
    """`_loaded_openblas` read from /proc/self/maps."""
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            return tuple(sorted({ln.split()[-1] for ln in f if "openblas" in ln.rsplit("/", 1)[-1].lower()}))
    except OSError:
        return ()


@functools.cache
def _entry_points(paths: tuple[str, ...]) -> tuple[tuple[str, Callable[[], int], Callable[[int], None]], ...]:
    """(path, get, set) of the thread count of each library of ``paths`` that has them (cached per set of
    loaded libraries: SciPy's copy is loaded with scipy.linalg, after NumPy's)."""
    out = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_LOCAL)
        except OSError:
            continue
        for get_name, set_name in _SYMBOLS:
            if hasattr(lib, get_name) and hasattr(lib, set_name):
                get, put = getattr(lib, get_name), getattr(lib, set_name)
                get.restype, get.argtypes = ctypes.c_int, []
                put.restype, put.argtypes = None, [ctypes.c_int]
                out.append((path, get, put))
                break
    return tuple(out)


_LOCK = threading.Lock()
_HELD: list = [0, {}]  # blocks inside one_blas_thread now; library path → (set, count to restore)


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with one OpenBLAS thread in every loaded OpenBLAS, then restore each one's count.
    Nested or concurrent blocks (fits in several threads) share one setting: the first to enter saves the
    counts, the last to leave restores them; a library loaded inside the outer block (SciPy's copy, by the
    first fit of an audit run in one: `rtfit.experiments.cli.main`) is set to one thread by the next block
    to enter, and restored with the others."""
    with _LOCK:
        if _HELD[0] == 0:
            _HELD[1] = {}
        for path, get, put in _entry_points(_loaded_openblas()):
            if path not in _HELD[1]:
                _HELD[1][path] = (put, get())
                put(1)
        _HELD[0] += 1
    try:
        yield
    finally:
        with _LOCK:
            _HELD[0] -= 1
            if _HELD[0] == 0:
                for put, n in _HELD[1].values():
                    put(n)
                _HELD[1] = {}


def blas_thread_counts() -> list[int]:
    """The thread count of each loaded OpenBLAS whose count can be set (empty where none)."""
    return [get() for _path, get, _put in _entry_points(_loaded_openblas())]


_ENV = "OPENBLAS_NUM_THREADS"


@contextmanager
def one_blas_thread_by_default() -> Iterator[None]:
    """The block (a whole ``rtfit`` command: `rtfit.experiments.cli.main`) with one OpenBLAS thread, unless
    the user set ``OPENBLAS_NUM_THREADS``: the libraries loaded already through `one_blas_thread`, those
    loaded inside the block (SciPy's copy; a spawned job worker's NumPy) through the variable, which is put
    back on exit.

    Why (issue 33, session 29): rtfit's BLAS work is small (a fit's m × p Jacobian products, p ≤ 8; a
    probe's least squares), and OpenBLAS's worker threads spin-wait after each call, on the cores that
    Mitsuba's and Dr.Jit's threads render and time kernels on. Measured on Mitsuba's Cornell box at 64² ×
    32 spp (2 cores, four alternated pairs): the audit's user CPU 14.5–15.5 s → 10.5–12.9 s, its wall time
    9.45–10.39 s → 7.74–9.70 s; one case's six fits (colour bleeding's) 0.70–0.76 s → 0.42–0.52 s."""
    if _ENV in os.environ:
        yield
        return
    os.environ[_ENV] = "1"
    try:
        with one_blas_thread():
            yield
    finally:
        os.environ.pop(_ENV, None)
