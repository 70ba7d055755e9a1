r"""Fitted height fog in the units of the engines artists use (issue 37 §3): ``rtfit fitted convert``.

rtfit's height fog (`rtfit.realtime.height_fog`) has the extinction σt(z) = b·e^(−c·z) per metre, z the height
in metres, with the optical depth τ = ∫ σt ds along the view ray, the transmittance T = e^(−τ) and the
shading L = L₀·T + C·(1 − T). Every fitted method whose parameters hold ``b`` and ``c`` in 1/m (the height-fog
optical-depth forms and shading models, the aerial-perspective fog) is converted; the conversion of each
engine is written once, as a pair (`Engine.to_engine`, `Engine.from_engine`) of closed forms, and each
engine's own fog formula is written once beside it from its documentation and source (`unreal_optical_depth`,
`hdrp_optical_depth`, `godot_extinction`) so that tests evaluate the engine with the converted values against
rtfit's kernel.

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
4π·p_HG ≈ a + k·max(cos θ, 0)^n by least squares over the sphere (`hg_as_power_lobe`), so
FogInscatteringColor = C₀ + a·C₁, DirectionalInscatteringColor = k·C₁, Exponent = n; the fit's relative RMS
error over the sphere is listed as lost (0.14 at g = 0.58: the power lobe has no backward tail). UE 5
clamps the camera's height above the fog (its maximum observer height), which rtfit's fog does not; and
its float32 text takes 2^(−F·z) at the camera's height and 2^(−F·Δz) apart, which leave float32's range
once c·z or |c·Δz| passes ~80 (a camera high above dense fog), where rtfit's stable form stays finite.

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
irradiance (Unreal's directional light), Unreal's ozone (set to 0). Godot's sky is not converted yet.

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

SH irradiance (the irradiance-bases ``sh-l*`` fits) — Unity, Godot, Unreal
---------------------------------------------------------------------------
Unity's SphericalHarmonicsL2, Godot's LightmapGI probe SH and Unreal's FSHVectorRGB3: the layouts, constants,
frames and each engine's evaluation, with the sources, in `rtfit.experiments.engine_presets_sh`
(`SH_LAYOUTS`); the section: `_sh_section`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.nishita_sky import AtmosphereParams
from rtfit.realtime.phase import hg_phase_kernel

from .engine_presets_sh import SH_LAYOUTS, is_sh, sh_preset
from .preset_records import (
    ENGINE_NAMES,
    PRESET_FORMAT,
    ConvertError,
    EnginePresets,
    EngineValue,
    FittedLike,
    MethodLike,
    Preset,
    plain_value,
)
from .records import to_json

__all__ = [
    "ENGINES",
    "HDRP_SCALE_HEIGHT",
    "PRESET_FORMAT",
    "ConvertError",
    "Engine",
    "EngineValue",
    "Preset",
    "convert_fitted",
    "engine_presets_of",
    "engine_section",
    "godot_extinction",
    "hdrp_optical_depth",
    "hdrp_sky_coefficients",
    "preset_document",
    "sky_from_hdrp",
    "sky_from_unreal",
    "sky_to_hdrp",
    "sky_to_unreal",
    "unreal_optical_depth",
    "unreal_sky_coefficients",
]

LN2 = math.log(2.0)
HDRP_SCALE_HEIGHT = 0.144765
"""HDRP's ``ScaleHeightFromLayerDepth`` factor (≈ 1/ln 1000, as the engine writes it)."""
_COLOUR = ("r0", "g0", "b0")
_LOBE = ("r1", "g1", "b1", "g")


@dataclass(frozen=True)
class Engine:
    """One engine's conversion: ``to_engine(b, c, base, colour)`` → its properties; ``from_engine(values,
    base)`` → (b, c, colour) back; ``base``: the height (m) its fog is anchored at (``anchor``: what the
    engine calls it); ``colour``: whether the constant colour C₀ has a property; ``lost``: what the engine's
    model does not hold; ``sources``: the documentation."""

    name: str
    title: str
    anchor: str
    to_engine: Callable[[float, float, float, tuple | None], dict[str, float | tuple]]
    from_engine: Callable[[Mapping[str, float | tuple], float], tuple[float, float, tuple | None]]
    units: Mapping[str, str]
    colour: bool
    lost: tuple[str, ...]
    sources: tuple[str, ...]
    base_from_domain: bool = True


# ------------------------------------------------------------------------------------- the conversions
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
    colour = v.get("FogInscatteringColor")
    return b, c, (tuple(colour) if colour is not None else None)


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
    colour = v.get("Color")
    return b, c, (tuple(colour) if colour is not None else None)


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


ENGINES: dict[str, Engine] = {
    "unreal": Engine(
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
    ),
    "unity-hdrp": Engine(
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
    ),
    "godot": Engine(
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
    ),
}


assert tuple(ENGINES) == ENGINE_NAMES  # one list of engine names: the fitted files' keys, the CLI's choices


# ------------------------------------------------------------------- the engines' own formulas (tests)
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


def godot_extinction(density, height_falloff, y0, y, dtype=np.float32):
    """Godot's FogMaterial density at height ``y`` (module docstring), in ``dtype``: extinction per metre."""
    y = np.asarray(y, dtype)
    return dtype(density) * np.clip(np.exp2(-dtype(height_falloff) * (y - dtype(y0))), dtype(0.0), dtype(1.0))


# ------------------------------------------------------------------ the phase lobe as Unreal's power lobe
@functools.cache
def _nodes() -> tuple[np.ndarray, np.ndarray]:
    """512-point Gauss–Legendre nodes μ and weights on [−1, 1], made on first use (at import they cost
    `rtfit --help` seconds: an eigen-decomposition of a 512 × 512 matrix)."""
    return np.polynomial.legendre.leggauss(512)


LOBE_EXPONENTS = np.geomspace(1.0, 512.0, 600)
"""The exponents n `hg_as_power_lobe` searches (Unreal's DirectionalInscatteringExponent)."""


def _lobe_fit(w: np.ndarray, n: float) -> tuple[float, float, float]:
    """(a, k, squared error) of the least-squares a + k·max(μ, 0)^n ≈ w(μ) over the sphere (dΩ = 2π dμ)."""
    mu, mu_w = _nodes()
    basis = np.stack([np.ones_like(mu), np.maximum(mu, 0.0) ** n], axis=1)
    sw = np.sqrt(mu_w)
    (a, k), *_ = np.linalg.lstsq(basis * sw[:, None], w * sw, rcond=None)
    return float(a), float(k), float(np.sum(mu_w * (basis @ (a, k) - w) ** 2))


def hg_as_power_lobe(g: float) -> tuple[float, float, float, float]:
    """The fitted colour lobe 4π·p_HG(θ, g) (`rtfit.realtime.phase`, mean 1 over the sphere) as
    a + k·max(cos θ, 0)^n, Unreal's constant plus directional inscattering: (a, k, n, relative RMS error
    over the sphere). n from `LOBE_EXPONENTS`, (a, k) by linear least squares for each."""
    mu, mu_w = _nodes()
    w = 4.0 * math.pi * np.asarray(hg_phase_kernel(NUMPY_OPS, mu, float(g)), dtype=np.float64)
    # every n at once by the 2 × 2 normal equations (the choice of n), then that n's least squares itself
    f = _powers()
    s1, sf, sff = float(np.sum(mu_w)), f @ mu_w, (f * f) @ mu_w
    sy, sfy = float(mu_w @ w), f @ (mu_w * w)
    det = s1 * sff - sf * sf
    a_n, k_n = (sff * sy - sf * sfy) / det, (s1 * sfy - sf * sy) / det
    errs = ((a_n[:, None] + k_n[:, None] * f - w) ** 2) @ mu_w
    n = float(LOBE_EXPONENTS[int(np.argmin(errs))])
    a, k, err = _lobe_fit(w, n)
    return a, k, n, math.sqrt(err / float(np.sum(mu_w * w**2)))


@functools.cache
def _powers() -> np.ndarray:
    """max(μ, 0)^n at the quadrature nodes for every n of `LOBE_EXPONENTS` (600 × 512), made once."""
    return np.maximum(_nodes()[0], 0.0)[None, :] ** LOBE_EXPONENTS[:, None]


# ------------------------------------------------------------------------------------------ the files
def _is_fog(m: MethodLike) -> bool:
    p = m.parameters
    return all(k in p and p[k].unit == "1/m" for k in ("b", "c"))


def _base(m: MethodLike, engine: Engine, base: float | None) -> float:
    if base is not None or not engine.base_from_domain:
        return float(base or 0.0)
    lows = [m.domain[k].lower for k in ("z0", "z1") if k in m.domain]
    return float(min(lows)) if lows else 0.0


def convert_method(m: MethodLike, engine: Engine, base: float | None = None) -> Preset:
    """One fitted fog method (``b``, ``c`` in 1/m; optional C₀ = r0, g0, b0) in ``engine``'s properties."""
    p = m.parameters
    b, c = float(p["b"].value), float(p["c"].value)
    if not (b > 0.0 and c > 0.0 and math.isfinite(b) and math.isfinite(c)):
        raise ConvertError(f"{m.id}: b = {b}, c = {c}: the engines' height fog needs b > 0 and c > 0")
    at = _base(m, engine, base)
    colour = tuple(float(p[k].value) for k in _COLOUR) if all(k in p for k in _COLOUR) else None
    lobe = tuple(float(p[k].value) for k in _LOBE) if all(k in p for k in _LOBE) else None
    if engine.name == "unreal" and lobe is not None and colour is not None:
        a, k, n, rel = hg_as_power_lobe(lobe[3])
        colour = tuple(c0 + a * c1 for c0, c1 in zip(colour, lobe[:3], strict=True))
        values = engine.to_engine(b, c, at, colour)
        values |= {
            "DirectionalInscatteringColor": tuple(k * c1 for c1 in lobe[:3]),
            "DirectionalInscatteringExponent": n,
            "DirectionalInscatteringStartDistance": 0.0,
        }
        lost = [
            f"the phase lobe's shape: 4π·p_HG(θ, g = {lobe[3]:.3g}) as {a:.4g} + {k:.4g}·"
            f"max(cos θ, 0)^{n:.3g} (relative RMS error over the sphere {rel:.2g}); "
            f"FogInscatteringColor holds C₀ + {a:.4g}·C₁",
            *engine.lost[1:],
        ]
        return _preset(engine, m, at, values, lost, p, colour_kept=True)
    values = engine.to_engine(b, c, at, colour if engine.colour else None)
    lost = list(engine.lost)
    if not engine.colour and colour is not None:
        lost.insert(0, f"the fitted colour C₀ = ({', '.join(f'{x:.4g}' for x in colour)}) W/m²/sr")
    if any(k in p for k in _LOBE):
        lobe = ", ".join(f"{k} = {float(p[k].value):.4g}" for k in _LOBE if k in p)
        lost.insert(0, f"the fitted phase lobe ({lobe})")
    return _preset(engine, m, at, values, lost, p)


def _preset(engine: Engine, m: MethodLike, at: float, values: dict, lost, p, colour_kept: bool = False):
    kept = [k for k in ("b", "c", *_COLOUR, *(_LOBE if colour_kept else ())) if k in p]
    return _make(engine.name, m, at, values, engine.units, lost, {k: float(p[k].value) for k in kept})


def _make(engine: str, m: MethodLike, at: float, values: Mapping, units: Mapping[str, str], lost, fitted):
    """The `Preset` of method ``m``: ``values`` {property: value} with their ``units`` (missing: "1")."""
    return Preset(
        engine=engine,
        method=m.id,
        case=m.case,
        base_height_m=float(at),
        fitted=dict(fitted),
        values=[EngineValue(k, plain_value(v), units.get(k, "1")) for k, v in values.items()],
        lost=list(dict.fromkeys(lost)),
    )


# --------------------------------------------------------------------- the Nishita sky: Unreal only
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
_SKY_KEYS = ("rayleigh_scale", "mie_scale", "mie_g")


def _is_sky(m: MethodLike) -> bool:
    return all(k in m.parameters for k in _SKY_KEYS)


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


def _sky_preset(m: MethodLike, engine: str) -> Preset:
    p = {k: float(m.parameters[k].value) for k in (*_SKY_KEYS, "ambient") if k in m.parameters}
    params = AtmosphereParams(rayleigh_scale=p["rayleigh_scale"], mie_scale=p["mie_scale"], mie_g=p["mie_g"])
    if engine == "unity-hdrp":
        values = sky_to_hdrp(params)
        units = {"PlanetaryRadius": "m", "AirMaximumAltitude": "m", "AerosolMaximumAltitude": "m"}
        lost = SKY_HDRP_LOST
    else:
        values = sky_to_unreal(params)
        km = (
            "GroundRadius",
            "AtmosphereHeight",
            "RayleighExponentialDistribution",
            "MieExponentialDistribution",
        )
        per_km = ("RayleighScatteringScale", "MieScatteringScale", "MieAbsorptionScale")
        units = {**dict.fromkeys(km, "km"), **dict.fromkeys(per_km, "1/km")}
        lost = SKY_UNREAL_LOST
    return _make(engine, m, 0.0, values, units, lost if p.get("ambient", 0.0) > 0 else lost[1:], p)


def _sh_section(engine: str, methods: list[MethodLike]) -> EnginePresets:
    """The SH methods of a file in ``engine``'s SH layout (`rtfit.experiments.engine_presets_sh`)."""
    lay = SH_LAYOUTS[engine]
    presets = []
    for m in methods:
        lam = float(m.parameters["lam"].value) if "lam" in m.parameters else None
        values, lost = sh_preset(engine, m.id, lam)
        presets.append(_make(engine, m, 0.0, values, {}, lost, {} if lam is None else {"lam": lam}))
    return EnginePresets(
        engine_title=lay.title, anchor=lay.anchor, sources=list(lay.sources), presets=presets
    )


def _sky_section(engine: str, sky: list[MethodLike]) -> EnginePresets:
    if engine == "godot":
        raise ConvertError(
            "the Nishita sky converts to Unreal's SkyAtmosphere and HDRP's "
            "Physically Based Sky (--engine unreal|unity-hdrp); Godot's sky is not converted yet"
        )
    hdrp = engine == "unity-hdrp"
    return EnginePresets(
        engine_title="Unity HDRP Physically Based Sky (Type: Custom)"
        if hdrp
        else "Unreal Engine 4.26+/5 SkyAtmosphere",
        anchor="sea level at the world origin (Spherical Mode off)"
        if hdrp
        else "the planet's top at the world origin (Transform Mode: planet top at absolute world origin)",
        sources=list(SKY_HDRP_SOURCES if hdrp else SKY_UNREAL_SOURCES),
        presets=[_sky_preset(m, engine) for m in sky],
    )


def _fog_section(engine: str, fog: list[MethodLike], base: float | None) -> EnginePresets:
    # Each fit on its own: one an engine cannot hold (a constant fog fitted to c < 0) is named in ``skipped``,
    # the others converted; none convertible is the first one's error.
    eng = ENGINES[engine]
    presets, skipped = [], []
    for m in fog:
        try:
            presets.append(convert_method(m, eng, base))
        except ConvertError as e:
            skipped.append(str(e))
    if not presets:
        raise ConvertError(skipped[0])
    return EnginePresets(
        engine_title=eng.title, anchor=eng.anchor, sources=list(eng.sources), presets=presets, skipped=skipped
    )


def engine_section(doc: FittedLike, engine: str, base: float | None = None) -> EnginePresets:
    """Every method of ``doc`` that ``engine`` has the same effect for, in its properties (`EnginePresets`:
    ``skipped`` names the fits the engine cannot hold, each with why); `ConvertError` (one line) when none
    converts. The one conversion behind both ``rtfit fitted convert`` and a fitted file's
    ``engine_presets``. A file of several families (an audit's) gives one section of all of them: each
    preset names its engine ``feature``; the titles, anchors and sources are those of every feature."""
    kinds = (
        ([m for m in doc.methods if _is_fog(m)], lambda ms: _fog_section(engine, ms, base)),
        ([m for m in doc.methods if _is_sky(m)], lambda ms: _sky_section(engine, ms)),
        ([m for m in doc.methods if is_sh(m.id)], lambda ms: _sh_section(engine, ms)),
    )
    parts: list[EnginePresets] = []
    refused: list[str] = []
    for methods, section in kinds:
        if not methods:
            continue
        try:
            parts.append(section(methods))
        except ConvertError as e:
            refused.append(str(e))
    if not parts and refused:
        raise ConvertError(refused[0])
    if not parts:
        ids = ", ".join(m.id for m in doc.methods) or "none"
        raise ConvertError(
            f"no height-fog method (parameters b and c in 1/m) to convert for "
            f"{engine} (methods: {ids}; converted: the height-fog and aerial-perspective fog fits, and the "
            f"Nishita sky's artist fits for unreal and unity-hdrp, SH L2+ irradiance for all three)"
        )
    presets = [dataclasses.replace(p, feature=part.engine_title) for part in parts for p in part.presets]
    if len(parts) == 1:
        return dataclasses.replace(parts[0], presets=presets, skipped=[*parts[0].skipped, *refused])
    return EnginePresets(
        engine_title=" + ".join(p.engine_title for p in parts),
        anchor="; ".join(f"{p.engine_title}: {p.anchor}" for p in parts),
        sources=list(dict.fromkeys(s for p in parts for s in p.sources)),
        presets=presets,
        skipped=[s for p in parts for s in p.skipped] + refused,
    )


def engine_presets_of(doc: FittedLike) -> dict[str, EnginePresets]:
    """A fitted file's ``engine_presets`` section: `engine_section` of every engine that converts one of its
    methods (at the default anchor heights), in `ENGINE_NAMES` order; empty where none does."""
    out = {}
    for engine in ENGINE_NAMES:
        try:
            out[engine] = engine_section(doc, engine)
        except ConvertError:
            continue
    return out


def convert_fitted(doc: FittedLike, engine: str, base: float | None = None, source: str = "") -> dict:
    """The ``rtfit.engine-preset/1`` document of ``doc`` in ``engine``: its header (format, source file,
    experiment, engine) and `engine_section` as JSON; `ConvertError` (one line, naming ``source``)."""
    try:
        section = engine_section(doc, engine, base)
    except ConvertError as e:
        raise ConvertError(f"{source or doc.title}: {e}") from None
    return preset_document(section, engine, doc.provenance.experiment, source)


def preset_document(section: EnginePresets, engine: str, experiment: str, source: str = "") -> dict:
    """The ``rtfit.engine-preset/1`` document of one engine's section (a fitted file's or a conversion's)."""
    body = to_json(section)
    assert isinstance(body, dict)
    return {"format": PRESET_FORMAT, "source": source, "experiment": experiment, "engine": engine, **body}
