"""rtfit.realtime: real-time rendering approximations as Dr.Jit kernels (one kernel text, also run by NumPy).

Imports only drjit and numpy. Public functions accept Python floats, NumPy arrays (evaluated on the default
Dr.Jit backend, see `set_default_backend`) or Dr.Jit arrays (same type out); see `rtfit.realtime._array`.

Modules:
    diffuse   Lambert, half-Lambert, wrap lighting, exact sphere-light irradiance (docs/diffuse.md).
"""

from . import diffuse
from ._array import DRJIT_OPS, NUMPY_OPS, get_default_backend, set_default_backend

__all__ = ["DRJIT_OPS", "NUMPY_OPS", "diffuse", "get_default_backend", "set_default_backend"]
