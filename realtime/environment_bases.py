"""Every irradiance basis of an environment as one method table: the ``irradiance-bases`` family.

`METHODS` joins the three tables that evaluate an environment's irradiance E(n) (W/m², RGB) at a unit
normal from stored coefficients (quantity ``environment_irradiance``):

* `rtfit.realtime.irradiance_bases.METHODS`: ambient cubes (Valve, NNLS), SH L1/L2/L3/L4 with their
  windows, ZH3, and the exact ``quadrature`` row;
* `rtfit.realtime.spherical_gaussians.SG_METHODS`: spherical Gaussians ``sg{N}-{fit}``;
* `rtfit.realtime.ambient_dice.DICE_METHODS`: Ambient Dice.

It is the one definition both the irradiance-bases experiment and `rtfit audit` read (and
`rtfit.realtime.quantities` lists as the family's shipped methods). The lightmap (hemisphere) bases of
`rtfit.realtime.hemisphere_bases` are not in it: they are expressed in a surface's tangent frame, not
over the sphere of world normals. `ALL_METHODS` adds them (H-basis, radiosity normal mapping): the table
`rtfit audit` lists, which evaluates them in the UV tangent frame of the visible surfaces.

Not exported from the package root (every family has its own ``METHODS``): import it from this module.
"""

from __future__ import annotations

from collections.abc import Mapping

from .ambient_dice import DICE_METHODS
from .hemisphere_bases import HEMISPHERE_METHODS
from .irradiance_bases import METHODS as SH_CUBE_METHODS
from .methods import Method, method_table
from .spherical_gaussians import SG_METHODS

__all__: list[str] = []

METHODS: Mapping[str, Method] = method_table(
    [*SH_CUBE_METHODS.values(), *SG_METHODS.values(), *DICE_METHODS.values()]
)
"""Cube and SH rows (the exact ``quadrature`` among them, in their table's order), then the SG bases, then
Ambient Dice."""

ALL_METHODS: Mapping[str, Method] = method_table([*METHODS.values(), *HEMISPHERE_METHODS.values()])
"""`METHODS`, then the lightmap (hemisphere) bases of `rtfit.realtime.hemisphere_bases`, whose normals are in
a surface's tangent frame: the irradiance-bases family as `rtfit audit` lists it."""
