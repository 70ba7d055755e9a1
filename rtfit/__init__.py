"""rtfit: a reference-and-fit validator for real-time rendering approximations.

The subpackages (one namespace, folders at the repository's top level):

* `rtfit.scenes` — the scene model and its TOML format;
* `rtfit.reference` — Mitsuba 3 ground truth with its noise;
* `rtfit.realtime` — the approximations, one kernel text each (Dr.Jit, NumPy, JAX);
* `rtfit.fitting` — metrics with noise floors, z-statistics, least-squares fits;
* `rtfit.experiments` — one experiment per family, reports and the ``rtfit`` command line.

Importing ``rtfit`` imports none of them (and neither Mitsuba nor Dr.Jit): ``rtfit.__version__`` is cheap.
"""

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("rtfit")
except _metadata.PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = ["__version__"]
