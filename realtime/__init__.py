"""rtfit.realtime: real-time rendering approximations as Dr.Jit kernels (one kernel text, also run by NumPy).

Imports only drjit and numpy. Public functions accept Python floats, NumPy arrays (evaluated on the default
Dr.Jit backend, see `set_default_backend`) or Dr.Jit arrays (same type out); see `rtfit.realtime._array`.

Modules:
    aperture  ambient aperture lighting: exact / smoothstep / fitted spherical-cap intersection and shading
              (docs/ambient-aperture.md).
    diffuse   Lambert, half-Lambert, wrap lighting, exact sphere-light irradiance (docs/diffuse.md).
    irradiance  irradiance bases: ambient cube (Valve, NNLS), SH L1/L2, windowed SH, Geomerics L1
              (docs/irradiance-bases.md).
    fog       exponential height fog: stable closed-form optical depth, fog colour, fog volumes
              (docs/height-fog.md).
    sdf_grid    signed distance fields: analytic primitives, mesh → voxel grid, mip chain, 8-bit
              (docs/sdf-occlusion.md).
    sdf_occlusion  Evans multi-scale SDF skylight/occlusion, curvature term, cone-traced soft occlusion.
    sky         Nishita single-scattering sky texture, atmosphere optical depth, aerial perspective
              (docs/nishita-sky.md).
"""

from . import aperture, diffuse, fog, irradiance, sdf_grid, sdf_occlusion, sky
from ._array import DRJIT_OPS, NUMPY_OPS, get_default_backend, set_default_backend

__all__ = [
    "DRJIT_OPS",
    "NUMPY_OPS",
    "aperture",
    "diffuse",
    "fog",
    "get_default_backend",
    "irradiance",
    "sdf_grid",
    "sdf_occlusion",
    "set_default_backend",
    "sky",
]
