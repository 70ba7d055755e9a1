"""rtfit: a reference-and-fit validator for real-time rendering approximations.

The subpackages (one namespace, folders at the repository's top level):

* `rtfit.scenes` — the scene model and its TOML format;
* `rtfit.reference` — Mitsuba 3 ground truth with its noise;
* `rtfit.realtime` — the approximations, one kernel text each (Dr.Jit, NumPy, JAX);
* `rtfit.fitting` — metrics with noise floors, z-statistics, least-squares fits;
* `rtfit.experiments` — one experiment per family, reports and the ``rtfit`` command line.

Importing ``rtfit`` imports none of them (and neither Mitsuba nor Dr.Jit): ``rtfit.__version__`` is cheap.
The user-approximation API is loaded on first use (module ``__getattr__``)::

    from rtfit import approximation, Param           # rtfit.realtime.quantities, rtfit.realtime.methods
    from rtfit import load_approximation, check_approximation   # rtfit.experiments.user_methods
    from rtfit import audit, AuditResult                         # rtfit.experiments.audit_run
    from rtfit import compare, CompareResult                     # rtfit.experiments.compare
"""

from importlib import import_module as _import_module
from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("rtfit")
except _metadata.PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

_LAZY = {
    "approximation": "rtfit.realtime.quantities",
    "QUANTITIES": "rtfit.realtime.quantities",
    "Param": "rtfit.realtime.methods",
    "load_approximation": "rtfit.experiments.user_methods",
    "check_approximation": "rtfit.experiments.user_methods",
    "audit": "rtfit.experiments.audit_run",
    "AuditResult": "rtfit.experiments.audit_run",
    "compare": "rtfit.experiments.compare",
    "CompareResult": "rtfit.experiments.compare",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(_import_module(module), name)
    globals()[name] = value  # later look-ups skip this hook
    return value


def __dir__():
    return sorted([*globals(), *_LAZY])
