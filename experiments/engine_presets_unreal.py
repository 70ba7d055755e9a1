r"""Unreal Engine's fog and sky: fitted height fog and Nishita-sky fits in Unreal's properties.

Unreal Engine 4/5 — Exponential Height Fog
------------------------------------------
Properties ``FogDensity``, ``FogHeightFalloff`` ("Height density factor, controls how the density increases as
height decreases"), the actor's Z, ``FogInscatteringColor`` (UE 5: "Fog Inscattering Luminance"),
``StartDistance``, ``FogMaxOpacity``, ``FogCutoffDistance``: the user guide
https://docs.unrealengine.com/4.26/en-US/BuildingWorlds/FogEffects/HeightFog and the API reference
https://dev.epicgames.com/documentation/en-us/unreal-engine/python-api/class/ExponentialHeightFogData
(defaults 0.02 and 0.2; the falloff's UI range 0.001–2,
https://dev.epicgames.com/documentation/unreal-engine/API/Runtime/Engine/Components/FExponentialHeightFogData/FogHeightFalloff).
Units: lengths in centimetres
(https://dev.epicgames.com/documentation/en-us/unreal-engine/units-of-measurement-in-unreal-engine). The
scales the pages do not state are the engine's own: ``FExponentialHeightFogSceneInfo`` divides both
properties by 1000 ("Artists edit the densities scaled up so they aren't entering in minuscule floating point
numbers"), and the shader (``HeightFogCommon.ush``) works in base 2: ρ₀ = (FogDensity/1000)·2^(−F·(z_cam −
z_fog)), F = FogHeightFalloff/1000 per cm, the line integral ρ₀·L·(1 − 2^(−F·Δz))/(F·Δz) (its first-order
Taylor polynomial ln 2 − ½(ln 2)²·x where |x = F·Δz| ≤ 0.01, x clamped at −127) and the fog factor
T = 2^(−that). Since (1 − 2^(−x))/x = ln 2·∫₀¹ 2^(−x·t) dt, the natural optical depth is
τ = (ln 2)²·∫ (FogDensity/1000)·2^(−F(z − z_fog)) ds (s, z in cm), so per metre

    b = (ln 2)²·FogDensity/10 · e^(c·z_fog),    c = ln 2·FogHeightFalloff/10      (z_fog in metres)

and back FogDensity = 10·b·e^(−c·z_fog)/(ln 2)², FogHeightFalloff = 10·c/ln 2. Exact for every ray: the
height law is the same. Kept: ``StartDistance`` 0, ``FogMaxOpacity`` 1, ``FogCutoffDistance`` 0 (rtfit's
fog has none of these). The constant colour C₀ is ``FogInscatteringColor`` (UE's blend is L₀·T + C·(1 − T),
the same). The ``phase`` model's lobe C₁·4π·p_HG(θ, g) becomes Unreal's directional inscattering,
DirectionalInscatteringColor·max(v·l, 0)^Exponent (start distance 0, so its fog factor is the same T):
4π·p_HG ≈ a + k·max(cos θ, 0)^n by least squares over the sphere (`engine_presets_fog.hg_as_power_lobe`), so
FogInscatteringColor = C₀ + a·C₁, DirectionalInscatteringColor = k·C₁, Exponent = n; the fit's relative RMS
error over the sphere is listed as lost (0.14 at g = 0.58: the power lobe has no backward tail). UE 5
clamps the camera's height above the fog (its maximum observer height), which rtfit's fog does not; and
its float32 text takes 2^(−F·z) at the camera's height and 2^(−F·Δz) apart, which leave float32's range
once c·z or |c·Δz| passes ~80 (a camera high above dense fog), where rtfit's stable form stays finite.

The Nishita sky — Unreal's SkyAtmosphere (4.26+/5)
---------------------------------------------------
The sky's artist fit (``rayleigh_scale``, ``mie_scale``, ``mie_g``, ``ambient``: `AtmosphereParams`) is
written as SkyAtmosphere properties (`sky_to_unreal`; the properties page
https://dev.epicgames.com/documentation/en-us/unreal-engine/sky-atmosphere-component-properties-in-unreal-engine):
Ground Radius and Atmosphere Height in km; each scattering or absorption coefficient as a scale (1/km) times
a colour, at altitude 0; the exponential distributions ("the altitude in kilometers at which the scattering
effect is reduced to 40%", i.e. e^(−1): the scale heights) in km; Mie Anisotropy = g. rtfit's unscaled
parameters (Bruneton's) are Unreal's defaults — 0.0331 × (0.175287, 0.409607, 1), 8 km, 0.003996, 0.000444,
1.2 km, 0.8 — which `tests/test_fitted_convert.py` checks. Lost: ``ambient`` (Unreal computes multiple
scattering itself; MultiScattering is set to 0 to keep the fitted single-scattering model), the sun's
irradiance (Unreal's directional light), Unreal's ozone (set to 0).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .engine_presets_fog import LN2, Engine

__all__ = [
    "SKY_UNREAL_LOST",
    "SKY_UNREAL_SOURCES",
    "UNREAL_FOG",
    "colour_property",
    "sky_from_unreal",
    "sky_to_unreal",
    "unreal_optical_depth",
    "unreal_sky_coefficients",
]


# ------------------------------------------------------------------------------ the height fog's conversion
def colour_property(values: Mapping, key: str) -> tuple | None:
    """An engine's colour property ``key`` of ``values`` as an RGB tuple, or None where it is not given."""
    colour = values.get(key)
    return tuple(colour) if colour is not None else None


def _unreal_to(b, c, base, colour):
    out = {
        "FogDensity": 10.0 * b * math.exp(-c * base) / LN2**2,
        "FogHeightFalloff": 10.0 * c / LN2,
        "ActorLocationZ": 100.0 * base,
        "StartDistance": 0.0,
        "FogMaxOpacity": 1.0,
        "FogCutoffDistance": 0.0,
    }
    if colour is not None:
        out["FogInscatteringColor"] = tuple(colour)
    return out


def _unreal_from(v, base):
    c = LN2 * v["FogHeightFalloff"] / 10.0
    z_fog = v.get("ActorLocationZ", 100.0 * base) / 100.0  # the actor's height (cm) in rtfit's metres
    b = LN2**2 * v["FogDensity"] / 10.0 * math.exp(c * z_fog)
    return b, c, colour_property(v, "FogInscatteringColor")


UNREAL_FOG = Engine(
    "unreal",
    "Unreal Engine 4/5 Exponential Height Fog",
    "the actor's Z (rtfit's height origin, in cm)",
    _unreal_to,
    _unreal_from,
    {
        "FogDensity": "1 (×1000 per cm, base 2)",
        "FogHeightFalloff": "1 (×1000 per cm, base 2)",
        "ActorLocationZ": "cm",
        "StartDistance": "cm",
        "FogMaxOpacity": "1",
        "FogCutoffDistance": "cm",
        "FogInscatteringColor": "linear RGB, the scene's radiance units",
        "DirectionalInscatteringColor": "linear RGB, the scene's radiance units",
        "DirectionalInscatteringExponent": "1",
        "DirectionalInscatteringStartDistance": "cm",
    },
    True,
    (
        "phase model: C₁·4π·p_HG(θ, g) (Unreal's directional inscattering is a max(v·l, 0)^Exponent lobe "
        "with its own start distance)",
        "UE 5's maximum observer height clamp (a camera far above the fog), and its float32 range: it "
        "takes 2^(−F·z) at the camera's height, 0 or ∞ once c·z or |c·Δz| passes ~80 (rtfit's form "
        "stays finite)",
        "colour units: rtfit's W/m²/sr against the scene's own lights; scale by the factor your scene's "
        "lights were converted with",
    ),
    (
        "https://docs.unrealengine.com/4.26/en-US/BuildingWorlds/FogEffects/HeightFog",
        "https://dev.epicgames.com/documentation/en-us/unreal-engine/python-api/class/ExponentialHeightFogData",
        "https://dev.epicgames.com/documentation/en-us/unreal-engine/units-of-measurement-in-unreal-engine",
    ),
    base_from_domain=False,
)
"""Unreal's Exponential Height Fog (anchored at the actor's Z, 0 unless given)."""


# --------------------------------------------------------------------------- the engine's own fog formula
def unreal_optical_depth(
    fog_density, fog_height_falloff, fog_z_cm, z0_cm, z1_cm, length_cm, dtype=np.float32
):
    """Unreal's exponential height fog along a camera-to-receiver segment (module docstring), as its shader
    evaluates it in ``dtype``: returns the natural optical depth −ln T (T = 2^(−line integral))."""
    f = np.asarray(fog_height_falloff, dtype) / dtype(1000.0)
    rho = np.asarray(fog_density, dtype) / dtype(1000.0)
    z0, z1, length = (np.asarray(v, dtype) for v in (z0_cm, z1_cm, length_cm))
    origin = rho * np.exp2(-f * (z0 - dtype(fog_z_cm)))
    x = np.maximum(dtype(-127.0), f * (z1 - z0))
    safe = np.where(np.abs(x) > dtype(0.01), x, dtype(1.0))
    line = np.where(
        np.abs(x) > dtype(0.01),
        (dtype(1.0) - np.exp2(-safe)) / safe,
        dtype(LN2) - dtype(0.5 * LN2**2) * x,
    )
    return dtype(LN2) * (origin * line * length)


# ------------------------------------------------------------------------- the Nishita sky: SkyAtmosphere
SKY_UNREAL_SOURCES = (
    "https://dev.epicgames.com/documentation/en-us/unreal-engine/sky-atmosphere-component-properties-in-unreal-engine",
    "https://dev.epicgames.com/documentation/en-us/unreal-engine/python-api/class/SkyAtmosphereComponent?application_version=5.1",
)
SKY_UNREAL_LOST = (
    "ambient: rtfit's isotropic multiple-scattering term (P_R → P_R + A/4π) has no property; Unreal computes "
    "multiple scattering itself (MultiScattering, set to 0 here to keep the fitted single-scattering model)",
    "the sun: rtfit's solar irradiance E₀ per channel (W·m⁻²·nm⁻¹) is the directional light's illuminance "
    "in Unreal (lux), set there",
    "Unreal's ozone (Other Absorption, a tent profile): set to 0, rtfit's atmosphere has none",
    "mie_phase: Unreal evaluates its own Mie phase with Mie Anisotropy = g; rtfit's fit used the file's "
    "phase",
)


def sky_to_unreal(params) -> dict[str, float | tuple]:
    """`rtfit.realtime.nishita_sky.AtmosphereParams` (with the fitted artist scales) as SkyAtmosphere
    properties: lengths in km, scattering and absorption coefficients per km as a scale times a colour
    (the defaults 0.0331 and 0.003996 are Bruneton's β_R(440 nm) and β_M in 1/km), the exponential
    distributions = the scale heights in km ("the altitude at which the scattering is reduced to 40%":
    e^(−1)); the colour is the per-channel β over its largest channel."""
    br, bm, bme = params.betas()
    rs = max(br) * 1e3
    ms = max(bm) * 1e3
    absorption = [(e - s) * 1e3 for e, s in zip(bme, bm, strict=True)]
    ma = max(absorption)
    return {
        "GroundRadius": params.planet_radius_m / 1e3,
        "AtmosphereHeight": params.top_m / 1e3,
        "MultiScatteringFactor": 0.0,
        "GroundAlbedo": (params.ground_albedo,) * 3,
        "RayleighScatteringScale": rs,
        "RayleighScattering": tuple(b * 1e3 / rs for b in br),
        "RayleighExponentialDistribution": params.rayleigh_height_m / 1e3,
        "MieScatteringScale": ms,
        "MieScattering": tuple(b * 1e3 / ms for b in bm),
        "MieAbsorptionScale": ma,
        "MieAbsorption": tuple(a / ma for a in absorption) if ma > 0 else (0.0, 0.0, 0.0),
        "MieAnisotropy": params.mie_g,
        "MieExponentialDistribution": params.mie_height_m / 1e3,
        "OtherAbsorptionScale": 0.0,
    }


def sky_from_unreal(values: Mapping, params) -> tuple[float, float, float]:
    """(rayleigh_scale, mie_scale, mie_g) of SkyAtmosphere ``values`` against the base ``params`` (the
    unscaled `AtmosphereParams`): the inverse of `sky_to_unreal` on the blue channel."""
    k = max(range(len(params.rayleigh_beta)), key=lambda i: params.rayleigh_beta[i])
    rayleigh = (
        values["RayleighScatteringScale"] * values["RayleighScattering"][k] / 1e3 / params.rayleigh_beta[k]
    )
    j = max(range(len(params.mie_beta)), key=lambda i: params.mie_beta[i])
    mie = values["MieScatteringScale"] * values["MieScattering"][j] / 1e3 / params.mie_beta[j]
    return rayleigh, mie, float(values["MieAnisotropy"])


def unreal_sky_coefficients(values: Mapping, altitude_km, dtype=np.float64):
    """SkyAtmosphere's medium at ``altitude_km`` as its documentation defines it: (Rayleigh scattering,
    Mie scattering, Mie absorption) per channel in 1/km, each scale × colour × e^(−h/distribution)."""
    h = np.asarray(altitude_km, dtype)
    ray = np.exp(-h / dtype(values["RayleighExponentialDistribution"]))
    mie = np.exp(-h / dtype(values["MieExponentialDistribution"]))
    return (
        [dtype(values["RayleighScatteringScale"] * c) * ray for c in values["RayleighScattering"]],
        [dtype(values["MieScatteringScale"] * c) * mie for c in values["MieScattering"]],
        [dtype(values["MieAbsorptionScale"] * c) * mie for c in values["MieAbsorption"]],
    )
