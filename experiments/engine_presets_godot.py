r"""Godot's volumetric fog: fitted height fog as a FogVolume with its FogMaterial.

Godot 4 — volumetric fog with a FogVolume and its FogMaterial
-------------------------------------------------------------
The ``Environment`` height fog (``fog_height``, ``fog_height_density``) is evaluated at the receiver's height,
not integrated along the ray: it cannot hold an exponential medium. The volumetric fog can: a ``FogVolume``
(origin at height y₀, Y up, metres) with a ``FogMaterial`` of ``density`` and ``height_falloff``
(https://docs.godotengine.org/en/4.4/classes/class_fogmaterial.html), whose built-in shader sets
DENSITY = density·clamp(2^(−height_falloff·(y − y₀)), 0, 1) (``fog_material.cpp``), the extinction per metre
the froxel grid integrates. So with y₀ = B as for HDRP

    density = b·e^(−c·B),   height_falloff = c/ln 2;   back c = ln 2·height_falloff, b = density·e^(c·B).

Set ``edge_fade`` 0 and size the volume over the scene. Lost: the colours (Godot's volumetric fog scatters
its lights with ``albedo`` and adds ``emission``; a fitted constant or phase-lobe colour has no property), fog
below y₀ (constant there), fog beyond ``Environment.volumetric_fog_length`` (64 m by default) and the froxel
grid's discretisation of the integral.

Godot's sky is not converted yet; its SH layout is in `rtfit.experiments.engine_presets_sh`.
"""

from __future__ import annotations

import math

import numpy as np

from .engine_presets_fog import LN2, Engine

__all__ = ["GODOT_FOG", "godot_extinction"]


# ------------------------------------------------------------------------------ the height fog's conversion
def _godot_to(b, c, base, colour):
    return {
        "FogMaterial.density": b * math.exp(-c * base),
        "FogMaterial.height_falloff": c / LN2,
        "FogMaterial.edge_fade": 0.0,
        "FogVolume.position.y": base,
    }


def _godot_from(v, base):
    c = LN2 * v["FogMaterial.height_falloff"]
    return v["FogMaterial.density"] * math.exp(c * v["FogVolume.position.y"]), c, None


GODOT_FOG = Engine(
    "godot",
    "Godot 4 volumetric fog: FogVolume + FogMaterial",
    "FogVolume.position.y (m): the lowest height the fit saw",
    _godot_to,
    _godot_from,
    {
        "FogMaterial.density": "1/m",
        "FogMaterial.height_falloff": "1/m (base 2)",
        "FogMaterial.edge_fade": "1",
        "FogVolume.position.y": "m",
    },
    False,
    (
        "the fog colour (Godot's volumetric fog scatters its lights with albedo, plus emission)",
        "fog below the FogVolume's origin (constant there), and beyond volumetric_fog_length (64 m by "
        "default)",
        "the froxel grid's discretisation of the integral",
    ),
    ("https://docs.godotengine.org/en/4.4/classes/class_fogmaterial.html",),
)
"""Godot 4's volumetric fog (a FogVolume at the lowest height the fit saw, with its FogMaterial)."""


# --------------------------------------------------------------------------- the engine's own fog formula
def godot_extinction(density, height_falloff, y0, y, dtype=np.float32):
    """Godot's FogMaterial density at height ``y`` (module docstring), in ``dtype``: extinction per metre."""
    y = np.asarray(y, dtype)
    return dtype(density) * np.clip(np.exp2(-dtype(height_falloff) * (y - dtype(y0))), dtype(0.0), dtype(1.0))
