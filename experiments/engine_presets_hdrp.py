r"""Unity HDRP's fog and sky: fitted height fog and Nishita-sky fits in HDRP's properties.

Unity HDRP — Fog volume override
--------------------------------
Properties ``Fog Attenuation Distance`` (the mean free path at the base, metres: "At this distance, the fog
has absorbed and out-scattered 63% of background light"), ``Base Height`` ("the boundary between the constant
(homogeneous) fog and the exponential fog"), ``Maximum Height``:
https://docs.unity3d.com/Packages/com.unity.render-pipelines.high-definition%4017.0/manual/fog-volume-override-reference.html
(Unity lengths are metres). HDRP's ``Fog.cs`` sets the extinction 1/MFP at the base and the scale height
H = 0.144765·(Maximum − Base) (``ScaleHeightFromLayerDepth``: e^(−d/H) = 0.001 across the layer depth d,
which it clamps to ≥ 0.01 m); ``OpticalDepthHeightFog`` integrates σ = (1/MFP)·e^(−max(h − Base, 0)/H) in
closed form, with |cos zenith| clamped to ≥ 0.001. So, with the base at height B,

    MFP = e^(c·B)/b,   Maximum − Base = 1/(0.144765·c);
    back c = 1/(0.144765·(Maximum − Base)),   b = e^(c·B)/MFP.

Exact for rays that stay above B; below it HDRP's fog is constant where rtfit's keeps growing, so B is the
lowest height the fit saw (the file's domain), else 0. The constant colour C₀ is the fog's ``Color`` (Color
Mode: Constant Color). Lost: the ``phase`` lobe (HDRP scatters its lights in the volumetric fog, with a phase
``Anisotropy``; no fitted colour lobe), and near-horizontal rays (|cos zenith| < 0.001) follow HDRP's clamp.

The Nishita sky — Unity HDRP's Physically Based Sky (Type: Custom)
-------------------------------------------------------------------
Properties (metres) Planetary Radius, Air/Aerosol Maximum Altitude, Air Density (per channel) and Aerosol
Density — "opacity … as measured by an observer on the ground looking towards the zenith" — Air/Aerosol
Tint, Aerosol Anisotropy (https://docs.unity3d.com/Packages/com.unity.render-pipelines.high-definition@16.0/
manual/physically-based-sky-volume-override-reference.html). HDRP's ``PhysicallyBasedSky.cs`` turns them
into the medium: H = 0.144765 × Maximum Altitude, extinction −ln(1 − α)/H at sea level, scattering =
extinction × tint (`hdrp_sky_coefficients`). So (`sky_to_hdrp`) Maximum Altitude = H/0.144765, Density =
1 − e^(−σt·H), Air Tint 1 (rtfit's air does not absorb), Aerosol Tint = β_M/β_M^ext (0.9), Anisotropy = g,
Number Of Bounces 1. rtfit's unscaled air is HDRP's built-in Earth air (5.8e-6, 1.35e-5, 3.31e-5 per m)
within 0.5 %. Lost: ``ambient``, the sun, the atmosphere's top (HDRP's ends at 55.3 km for this air, rtfit's
at 60 km) and HDRP's ozone where the version has one (set to 0).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .engine_presets_fog import Engine
from .engine_presets_unreal import SKY_UNREAL_LOST, colour_property

__all__ = [
    "HDRP_FOG",
    "HDRP_SCALE_HEIGHT",
    "SKY_HDRP_LOST",
    "SKY_HDRP_SOURCES",
    "hdrp_optical_depth",
    "hdrp_sky_coefficients",
    "sky_from_hdrp",
    "sky_to_hdrp",
]

HDRP_SCALE_HEIGHT = 0.144765
"""HDRP's ``ScaleHeightFromLayerDepth`` factor (≈ 1/ln 1000, as the engine writes it)."""


# ------------------------------------------------------------------------------ the height fog's conversion
def _hdrp_to(b, c, base, colour):
    out = {
        "FogAttenuationDistance": math.exp(c * base) / b,
        "BaseHeight": base,
        "MaximumHeight": base + 1.0 / (HDRP_SCALE_HEIGHT * c),
    }
    if colour is not None:
        out["Color"] = tuple(colour)
    return out


def _hdrp_from(v, base):
    c = 1.0 / (HDRP_SCALE_HEIGHT * (v["MaximumHeight"] - v["BaseHeight"]))
    b = math.exp(c * v["BaseHeight"]) / v["FogAttenuationDistance"]
    return b, c, colour_property(v, "Color")


HDRP_FOG = Engine(
    "unity-hdrp",
    "Unity HDRP Fog volume override",
    "Base Height (m): the lowest height the fit saw",
    _hdrp_to,
    _hdrp_from,
    {
        "FogAttenuationDistance": "m",
        "BaseHeight": "m",
        "MaximumHeight": "m",
        "Color": "linear RGB, the scene's radiance units",
    },
    True,
    (
        "fog below Base Height (constant in HDRP, growing in rtfit)",
        "phase model: C₁·4π·p_HG(θ, g) (HDRP scatters its lights in the volumetric fog, Anisotropy)",
        "rays with |cos zenith| < 0.001 (HDRP's clamp)",
    ),
    (
        "https://docs.unity3d.com/Packages/com.unity.render-pipelines.high-definition%4017.0/manual/"
        "fog-volume-override-reference.html",
    ),
)
"""Unity HDRP's Fog volume override (anchored at Base Height: the lowest height the fit saw)."""


# --------------------------------------------------------------------------- the engine's own fog formula
def hdrp_optical_depth(
    attenuation_distance, base, maximum, cos_zenith, start_height, length, dtype=np.float32
):
    """HDRP's ``OpticalDepthHeightFog`` (module docstring) in ``dtype``: the optical depth of a segment of
    ``length`` m from ``start_height`` along a ray of ``cos_zenith``."""
    ext = dtype(1.0) / np.asarray(attenuation_distance, dtype)
    scale = dtype(HDRP_SCALE_HEIGHT) * np.maximum(dtype(0.01), dtype(maximum) - dtype(base))
    z, h0, t = (np.asarray(v, dtype) for v in (cos_zenith, start_height, length))
    absz = np.maximum(np.abs(z), dtype(0.001))
    lowest = np.minimum(h0, h0 + t * z)
    h = np.maximum(lowest - dtype(base), dtype(0.0))
    hom = np.clip((dtype(base) - lowest) / absz, dtype(0.0), t)
    exp_part = np.exp(-h / scale) * (dtype(1.0) - np.exp(-(t - hom) * absz / scale)) * (scale / absz)
    return ext * (hom + exp_part)


# ----------------------------------------------------------------- the Nishita sky: Physically Based Sky
SKY_HDRP_SOURCES = (
    "https://docs.unity3d.com/Packages/com.unity.render-pipelines.high-definition@16.0/manual/"
    "physically-based-sky-volume-override-reference.html",
)
SKY_HDRP_LOST = (
    SKY_UNREAL_LOST[0]
    .replace("Unreal computes", "HDRP computes")
    .replace("MultiScattering, set to 0 here", "Number Of Bounces, set to 1 here"),
    "the sun: rtfit's solar irradiance E₀ per channel is the directional light's intensity in HDRP",
    "the atmosphere's top: HDRP's ends at the larger layer depth (e^(−d/H) = 0.001: 55.3 km for rtfit's "
    "air), rtfit's at 60 km",
    "HDRP's ozone layer (versions that have one): set its density to 0, rtfit's atmosphere has none",
)


def sky_to_hdrp(params) -> dict[str, float | tuple]:
    """`AtmosphereParams` as HDRP Physically Based Sky properties (Type: Custom; metres): each layer's
    Maximum Altitude = H/0.144765 (HDRP's ``ScaleHeightFromLayerDepth``), its Density the zenith opacity
    1 − e^(−σt·H) that HDRP turns back into the extinction σt = −ln(1 − α)/H (``ExtinctionFromZenithOpacity
    AndScaleHeight``), its Tint the single-scattering albedo (scattering = extinction × tint)."""
    br, bm, bme = params.betas()
    mie_ext = max(bme)
    return {
        "PlanetaryRadius": params.planet_radius_m,
        "AirMaximumAltitude": params.rayleigh_height_m / HDRP_SCALE_HEIGHT,
        "AirDensity": tuple(-math.expm1(-b * params.rayleigh_height_m) for b in br),
        "AirTint": (1.0, 1.0, 1.0),
        "AerosolMaximumAltitude": params.mie_height_m / HDRP_SCALE_HEIGHT,
        "AerosolDensity": -math.expm1(-mie_ext * params.mie_height_m),
        "AerosolTint": tuple(s / mie_ext for s in bm),
        "AerosolAnisotropy": params.mie_g,
        "NumberOfBounces": 1,
    }


def hdrp_sky_coefficients(values: Mapping, altitude_m, dtype=np.float64):
    """HDRP's Physically Based Sky medium at ``altitude_m`` (its ``PhysicallyBasedSky.cs``): (air
    scattering, aerosol scattering, aerosol extinction) per channel in 1/m."""
    h = np.asarray(altitude_m, dtype)
    h_air = dtype(HDRP_SCALE_HEIGHT * values["AirMaximumAltitude"])
    h_aer = dtype(HDRP_SCALE_HEIGHT * values["AerosolMaximumAltitude"])
    air = [-np.log1p(-dtype(a)) / h_air * dtype(t) * np.exp(-h / h_air)
           for a, t in zip(values["AirDensity"], values["AirTint"], strict=True)]  # fmt: skip
    ext = -np.log1p(-dtype(min(values["AerosolDensity"], 0.999999))) / h_aer * np.exp(-h / h_aer)
    return air, [dtype(t) * ext for t in values["AerosolTint"]], [ext] * len(values["AerosolTint"])


def sky_from_hdrp(values: Mapping, params) -> tuple[float, float, float]:
    """(rayleigh_scale, mie_scale, mie_g) of HDRP ``values`` against the unscaled ``params``."""
    air, _aer, ext = hdrp_sky_coefficients(values, 0.0)
    k = max(range(len(params.rayleigh_beta)), key=lambda i: params.rayleigh_beta[i])
    j = max(range(len(params.mie_extinction)), key=lambda i: params.mie_extinction[i])
    return (
        float(air[k]) / params.rayleigh_beta[k],
        float(ext[j]) / params.mie_extinction[j],
        float(values["AerosolAnisotropy"]),
    )
