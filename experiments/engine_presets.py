r"""Fitted height fog in the units of the engines artists use (issue 37 §3): ``rtfit fitted convert``.

`engine_section` is the one conversion behind both ``rtfit fitted convert`` and a fitted file's
``engine_presets`` (`engine_presets_of`): every method of a fitted file that an engine has the same effect
for, in the engine's own properties, with what the engine cannot hold.

rtfit's height fog (`rtfit.realtime.height_fog`) has the extinction σt(z) = b·e^(−c·z) per metre, z the height
in metres, with the optical depth τ = ∫ σt ds along the view ray, the transmittance T = e^(−τ) and the
shading L = L₀·T + C·(1 − T). Every fitted method whose parameters hold ``b`` and ``c`` in 1/m (the height-fog
optical-depth forms and shading models, the aerial-perspective fog) is converted; the conversion of each
engine is written once, as a pair (`Engine.to_engine`, `Engine.from_engine`) of closed forms, and each
engine's own fog formula is written once beside it from its documentation and source (`unreal_optical_depth`,
`hdrp_optical_depth`, `godot_extinction`) so that tests evaluate the engine with the converted values against
rtfit's kernel.

The rooms, each with its engine's derivation and sources in its docstring:

* `rtfit.experiments.engine_presets_fog`: the `Engine` record, a fog method in an engine's properties
  (`convert_method`), the phase lobe as Unreal's power lobe (`hg_as_power_lobe`), the `Preset` maker;
* `rtfit.experiments.engine_presets_unreal`: Unreal Engine 4/5's Exponential Height Fog and SkyAtmosphere;
* `rtfit.experiments.engine_presets_hdrp`: Unity HDRP's Fog volume override and Physically Based Sky;
* `rtfit.experiments.engine_presets_godot`: Godot 4's volumetric fog (FogVolume + FogMaterial); Godot's sky
  is not converted yet;
* `rtfit.experiments.engine_presets_sh`: SH irradiance (the irradiance-bases ``sh-l*`` fits) — Unity's
  SphericalHarmonicsL2, Godot's LightmapGI probe SH and Unreal's FSHVectorRGB3: the layouts, constants,
  frames and each engine's evaluation, with the sources (`SH_LAYOUTS`); the section: `_sh_section`.
"""

from __future__ import annotations

import dataclasses

from rtfit.realtime.nishita_sky import AtmosphereParams

from .engine_presets_fog import Engine, convert_method, is_fog, make_preset
from .engine_presets_godot import GODOT_FOG, godot_extinction
from .engine_presets_hdrp import (
    HDRP_FOG,
    HDRP_SCALE_HEIGHT,
    SKY_HDRP_LOST,
    SKY_HDRP_SOURCES,
    hdrp_optical_depth,
    hdrp_sky_coefficients,
    sky_from_hdrp,
    sky_to_hdrp,
)
from .engine_presets_sh import SH_LAYOUTS, is_sh, sh_preset
from .engine_presets_unreal import (
    SKY_UNREAL_LOST,
    SKY_UNREAL_SOURCES,
    UNREAL_FOG,
    sky_from_unreal,
    sky_to_unreal,
    unreal_optical_depth,
    unreal_sky_coefficients,
)
from .preset_records import (
    ENGINE_NAMES,
    PRESET_FORMAT,
    ConvertError,
    EnginePresets,
    EngineValue,
    FittedLike,
    MethodLike,
    Preset,
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


ENGINES: dict[str, Engine] = {"unreal": UNREAL_FOG, "unity-hdrp": HDRP_FOG, "godot": GODOT_FOG}
"""Each engine's height-fog conversion, by its name."""

assert tuple(ENGINES) == ENGINE_NAMES  # one list of engine names: the fitted files' keys, the CLI's choices


# ------------------------------------------------------------------------------------------ the files
_SKY_KEYS = ("rayleigh_scale", "mie_scale", "mie_g")


def _is_sky(m: MethodLike) -> bool:
    return all(k in m.parameters for k in _SKY_KEYS)


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
    return make_preset(engine, m, 0.0, values, units, lost if p.get("ambient", 0.0) > 0 else lost[1:], p)


def _sh_section(engine: str, methods: list[MethodLike]) -> EnginePresets:
    """The SH methods of a file in ``engine``'s SH layout (`rtfit.experiments.engine_presets_sh`)."""
    lay = SH_LAYOUTS[engine]
    presets = []
    for m in methods:
        lam = float(m.parameters["lam"].value) if "lam" in m.parameters else None
        values, lost = sh_preset(engine, m.id, lam)
        presets.append(make_preset(engine, m, 0.0, values, {}, lost, {} if lam is None else {"lam": lam}))
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
        ([m for m in doc.methods if is_fog(m)], lambda ms: _fog_section(engine, ms, base)),
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
