"""The family registry: one entry per approximation family, the one list that ``rtfit list``, ``rtfit run``,
``rtfit audit`` and the user-quantity tables read (issue 30 §3).

A `Family` says everything the tools need to know about a family, in one place:

* ``name`` — on the command line (``rtfit run NAME``, ``rtfit audit --approx NAME``), in paths and results;
* ``module``, ``title``, ``description`` — its experiment (`rtfit run NAME` on its shipped scenes; the
  module is imported only when it runs, `registry.ExperimentSpec`);
* ``methods`` — its rows: the method table of its ``rtfit.realtime`` module (kernel text, inputs with units
  and domains, free parameters), which the audit evaluates and fits on a user's scene and a user's
  ``@approximation`` of the same quantity joins; ``None`` for a family not audited yet;
* ``audits`` — its audit declarations (`audit_family.AuditFamily`, one per module ``audit_<family>.py``,
  each with the `audit.Rule` s saying when it applies to a scene and why).

Everything else is derived here: `EXPERIMENTS` (``rtfit list``/``run``), `METHOD_TABLES` (the audit's rows
per family, in registry order), `RULES` (``--list``'s decision, in registry order, then declaration order)
and `AUDITED` (name → one declaration joining its roles, `audit_family.by_name`). Adding a family is one
entry here beside its realtime module, its experiment or audit module, its tests and its doc page
(docs/architecture.md, "Adding a family").
"""

from __future__ import annotations

import importlib
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import ModuleType

from rtfit.realtime import (
    ambient_aperture,
    caustics,
    clouds,
    colour_bleeding,
    diffuse,
    environment_bases,
    fresnel,
    height_fog,
    ibl_samples,
    irradiance_volumes,
    layered_materials,
    light_path_maps,
    linear_fog,
    misty_glow,
    nishita_sky,
    obscurances,
    parallax_occlusion,
    pcf_soft_shadows,
    probe_specular,
    raindrops,
    reflections,
    sdf_occlusion,
    sh_sky_bent_normal,
    soft_particles,
    streaky_reflections,
)
from rtfit.realtime.aerial_perspective import METHODS as AERIAL_METHODS
from rtfit.realtime.light_cones import METHODS as CONE_METHODS
from rtfit.realtime.light_cones import QUADRATURE as CONE_QUADRATURE
from rtfit.realtime.methods import Method
from rtfit.realtime.volumetric_lightning import METHODS as LIGHTNING_METHODS
from rtfit.realtime.volumetric_lightning import QUADRATURE as LIGHTNING_QUADRATURE

from . import (
    audit_aerial_perspective,
    audit_ambient_aperture,
    audit_ambient_occlusion,
    audit_caustics,
    audit_clouds,
    audit_colour_bleeding,
    audit_diffuse,
    audit_environment_maps,
    audit_fog_media,
    audit_fresnel,
    audit_height_fog,
    audit_ibl_samples,
    audit_irradiance_bases,
    audit_irradiance_volumes,
    audit_layered_materials,
    audit_light_cones,
    audit_light_path_maps,
    audit_linear_fog,
    audit_misty_glow,
    audit_nishita_sky,
    audit_obscurances,
    audit_parallax_occlusion,
    audit_pcf_soft_shadows,
    audit_probe_specular,
    audit_raindrops,
    audit_sh_sky_bent_normal,
    audit_sky_emitter,
    audit_sky_occlusion,
    audit_soft_particles,
    audit_streaky_reflections,
    audit_volumetric_lightning,
)
from .audit import Rule
from .audit_family import AuditFamily, by_name
from .registry import ALIASES, SPP_MAX, BenchContext, ExperimentSpec, UnknownExperiment, apply_overrides
from .shipped import ShippedScene, Study, StudyContext

__all__ = [
    "AUDITED",
    "EXPERIMENTS",
    "FAMILIES",
    "METHOD_TABLES",
    "RULES",
    "Family",
    "LeafFunction",
    "describe_config",
    "get_experiment",
    "resolve_names",
    "validate_config",
]


@dataclass(frozen=True)
class LeafFunction:
    """A function of a study's leaf module ``rtfit.experiments.<module>``, imported when first called (or
    `target` read): a family's own study and bench run only in ``rtfit run`` / ``rtfit bench`` of that
    family, and importing the fourteen study modules with the registry cost every ``rtfit`` command,
    ``rtfit audit`` included, ~0.3 s (issue 33). An unknown module or name fails at the call, and
    tests/test_families_lazy.py imports every one."""

    module: str
    name: str

    @property
    def target(self) -> Callable:
        """The function itself (its module imported now)."""
        return getattr(importlib.import_module(f"rtfit.experiments.{self.module}"), self.name)

    def __call__(self, *args, **kwargs):
        return self.target(*args, **kwargs)


ENGINE = "rtfit.experiments.engine_run"
"""The experiment module of every family born on the engine: ``rtfit run NAME`` audits its shipped scenes."""


@dataclass(frozen=True)
class Family:
    """One family of the registry (module docstring)."""

    name: str
    module: str
    title: str
    description: str
    methods: Mapping[str, Method] | None = None
    audits: tuple[AuditFamily, ...] = ()
    scenes: tuple[ShippedScene, ...] = ()
    """Its shipped scenes, for a family born on the engine (``module`` `ENGINE`): ``rtfit run NAME`` is the
    audit engine on each of them, for this family alone (`rtfit.experiments.engine_run`)."""
    study: Callable[[StudyContext], Study] | None = None
    """Its own study (tables and figures only it has), run after the engine on its shipped scenes: a
    function of a leaf module that imports no other family."""
    bench: Callable[[BenchContext], list[dict]] | None = None
    """Its own ``rtfit bench NAME`` rows (given the `registry.BenchContext`: the reference estimators, a
    texture's build), appended to the engine's rows of its methods (`engine_run.EngineExperiment.bench`);
    for a family born on the engine, a function of its study's leaf module."""

    def __post_init__(self):
        stray = [a.name for a in self.audits if a.name != self.name]
        if stray:
            raise ValueError(f"family {self.name!r}: declarations of another family ({', '.join(stray)})")
        if self.audits and self.methods is None:
            raise ValueError(f"family {self.name!r}: an audited family needs its method table")
        if (self.module == ENGINE) != bool(self.scenes) or ((self.study or self.bench) and not self.scenes):
            raise ValueError(f"family {self.name!r}: a family run by the engine ({ENGINE}) ships its scenes")

    @property
    def experiment(self) -> ExperimentSpec:
        return ExperimentSpec(self.name, self.module, self.title, self.description)


def _engine(
    name: str,
    audit: ModuleType,
    methods: Mapping[str, Method],
    title: str,
    description: str,
    study: Callable[[StudyContext], Study] | None = None,
    bench: Callable[[BenchContext], list[dict]] | None = None,
    audits: tuple[AuditFamily, ...] | None = None,
) -> Family:
    """A family born on the engine (module `ENGINE`) from its audit module ``audit``: its declaration
    ``audit.FAMILY`` (or ``audits``, where other declarations join it, in their order) and its shipped
    scenes ``audit.SCENES``."""
    return Family(
        name,
        ENGINE,
        title,
        description,
        methods=methods,
        audits=(audit.FAMILY,) if audits is None else audits,
        scenes=audit.SCENES,
        study=study,
        bench=bench,
    )


FAMILIES: dict[str, Family] = {
    f.name: f
    for f in (
        _engine(
            "diffuse",
            audit_diffuse,
            diffuse.METHODS,
            "Half-Lambert and wrap lighting vs exact sphere-light irradiance",
            "White diffuse sphere under a distant spherical light of angular radius 0.27°–30°: Lambert, "
            "half-Lambert and wrap lighting (fitted per α and as one smooth law w(α), p(α)) against Mitsuba.",
            study=LeafFunction("diffuse_study", "study"),
        ),
        _engine(
            "irradiance-bases",
            audit_irradiance_bases,
            environment_bases.ALL_METHODS,
            "Irradiance bases: ambient cube vs spherical harmonics against path-traced irradiance",
            "Valve ambient cube (axis-sampled and NNLS-optimal), SH L1–L4 plain and windowed, ZH3, spherical "
            "Gaussians, Ambient Dice and the lightmap bases (H-basis, RNM) on a white sphere under a "
            "constant, sunsky, studio and overcast environment (shipped scenes), with the lone suns, "
            "ringing, hemisphere and storage-budget study.",
            study=LeafFunction("irradiance_bases_study", "study"),
        ),
        _engine(
            "irradiance-volumes",
            audit_irradiance_volumes,
            {**irradiance_volumes.METHODS, **irradiance_volumes.SPLIT_METHODS},
            "Irradiance volumes: a grid of ambient cubes / SH L2 probes, nearest vs trilinear",
            "Path-traced probes over a room with a bright point light and an occluder (one shipped scene per "
            "probe grid), looked up nearest and trilinear against path-traced irradiance at the visible "
            "points: error vs spacing, popping, storage per probe.",
            study=LeafFunction("irradiance_volumes_study", "study"),
        ),
        _engine(
            "ambient-aperture",
            audit_ambient_aperture,
            ambient_aperture.METHODS,
            "Ambient aperture lighting: spherical-cap intersection, exact vs smoothstep vs fitted",
            "Solid angle of two intersecting spherical caps over the whole domain (study), and each visible "
            "point's baked cap against a sphere light's shadowed irradiance, the occluded sky and ray-cast "
            "AO on a plate with a hole, a well and bumps (the engine), with fitted Ω and Lambert weights.",
            study=LeafFunction("ambient_aperture_study", "study"),
            audits=(audit_sky_occlusion.APERTURE_FILL, audit_ambient_aperture.FAMILY),
        ),
        _engine(
            "sdf-occlusion",
            audit_ambient_occlusion,
            sdf_occlusion.METHODS,
            "SDF occlusion and skylight (Evans) vs path-traced ambient occlusion and sky light",
            "Multi-scale signed-distance sampling and cone-traced soft occlusion against Mitsuba AO and "
            "sky-lit irradiance, with steps-vs-error-vs-cost and fitted contrast.",
            study=LeafFunction("sdf_occlusion_study", "study"),
            audits=(audit_sky_occlusion.SKY_OCCLUSION, audit_ambient_occlusion.FAMILY),
        ),
        _engine(
            "height-fog",
            audit_height_fog,
            height_fog.METHODS,
            "Exponential height fog: closed-form optical depth and fog colour vs path-traced media",
            "Closed-form, seed-listing and Taylor optical-depth forms over the whole domain, and fog "
            "shading against Mitsuba transmittance and aerial perspective, with fitted artist parameters.",
            study=LeafFunction("height_fog_study", "study"),
            audits=(audit_height_fog.FAMILY, audit_fog_media.FAMILY),
        ),
        _engine(
            "nishita-sky",
            audit_nishita_sky,
            nishita_sky.METHODS,
            "Nishita sky: single-scattering sky texture vs a path-traced spherical-shell atmosphere",
            "The 128×64 Nishita sky texture with per-pixel phase on shipped sky files, one per sun elevation "
            "(multiple-scattering Mitsuba reference, fitted artist parameters), and its study: single "
            "scattering checked by quadrature, viewer altitude, spectral reference, sunsky, layers-vs-error.",
            study=LeafFunction("nishita_sky_study", "study"),
            audits=(audit_nishita_sky.FAMILY, audit_sky_emitter.FAMILY),
            bench=LeafFunction("nishita_sky_study", "bench"),
        ),
        _engine(
            "volumetric-lightning",
            audit_volumetric_lightning,
            {**LIGHTNING_METHODS, "quadrature": LIGHTNING_QUADRATURE},
            "Volumetric lightning: the seed's softened point light along the view ray vs single scattering",
            "The closed-form line integral of i/(1 + a·r²) (stable float32 form vs the printed one) against "
            "path-traced single scattering of a point light in thin and dense media, with fitted i and a.",
            study=LeafFunction("volumetric_lightning_study", "study"),
        ),
        _engine(
            "misty-glow",
            audit_misty_glow,
            misty_glow.METHODS,
            "Misty glow: the seed's Kawase bloom as the atmospheric PSF vs a path-traced point light in fog",
            "The glow around a point light in a forward-scattering homogeneous medium (volpathmis, all "
            "orders) against the seed's 4-pass Kawase bloom of the light's direct image, 1–8 passes with "
            "scale and amplitude fitted per optical depth, a Gaussian bloom and single scattering alone.",
            study=audit_misty_glow.study,
        ),
        _engine(
            "layered-materials",
            audit_layered_materials,
            layered_materials.METHODS,
            "Layered materials: the seed's parallax offset through a coat vs Mitsuba's refraction",
            "Where a smooth dielectric coat covers a base: the offset at which each pixel sees the base, "
            "from Mitsuba's own refraction of the camera ray, against the seed's parallax offset without "
            "refraction (given and with its depth fitted), the paraxial apparent depth and Snell's refracted "
            "offset; under a sky, the coated base's path-traced radiance against the seed's layer composite, "
            "a Fresnel lerp and the coated-diffuse closed form; the study measures the seed's offset error "
            "against view angle (the issue's ≈ 2× at 60°).",
            study=audit_layered_materials.study,
        ),
        _engine(
            "raindrops",
            audit_raindrops,
            raindrops.METHODS,
            "Raindrops: the seed's refracted + reflected look-up with a Fresnel blend vs a path-traced drop",
            "A water drop (a smooth dielectric sphere, η = 1.33) under an environment map, path traced, "
            "against the seed's Fresnel blend of a reflected and a once-refracted environment look-up "
            "(000:822-887; fitted effective η and brightness; the particle's Fresnel opacity), the ray "
            "optics of a sphere (two refractions, 0, 1 and 8 internal reflections) and the background it "
            "hides; the seed's claim that a drop is brighter than its background measured.",
            study=audit_raindrops.study,
        ),
        _engine(
            "clouds",
            audit_clouds,
            {**clouds.METHODS, **clouds.RADIANCE_METHODS},
            "Cloud shadows: the seed's 2-D density plane vs the sun's transmittance through a gridvolume",
            "The sun's transmittance through a heterogeneous (gridvolume) cloud to the ground, by ratio "
            "tracking through the medium, against the seed's cloud-shadow texture (the density plane "
            "projected along the sun), the plane extruded with the distance clouds' nested march, and a 3-D "
            "ray march of 4–64 samples; and the sunlit cloud's radiance (volpathmis) against the seed's "
            "gradient-lit clouds (Wang 2003's artist colours, fitted) and the sun's single scattering.",
            study=audit_clouds.study,
        ),
        _engine(
            "aerial-perspective",
            audit_aerial_perspective,
            AERIAL_METHODS,
            "Aerial perspective matched to the sky: the fog blend under a Nishita atmosphere + height fog",
            "The seed's sky-matched fog blend on Mitsuba sunsky scenes through a fog bank and a height fog "
            "(given and fitted b, c, colour), and its error budget per sun elevation under a Nishita "
            "atmosphere + height fog by quadrature (checked against Mitsuba).",
            study=LeafFunction("aerial_perspective_study", "study"),
        ),
        _engine(
            "soft-particles",
            audit_soft_particles,
            soft_particles.METHODS,
            "Soft particles: depth fade, 2007 box, spherical billboards vs exact clipped Beer–Lambert",
            "Particle opacity where geometry cuts the volume: the seed's linear fade, the camera-aligned "
            "box, spherical billboards and a fitted fade against analytic chords checked by Mitsuba.",
            study=LeafFunction("soft_particles_study", "study"),
        ),
        _engine(
            "light-cones",
            audit_light_cones,
            {**CONE_METHODS, "quadrature": CONE_QUADRATURE},
            "Light cones in fog: the seed's shell (edge fade, v² attenuation) vs spot-light scattering",
            "The pseudo-volumetric cone shell and §1's integral over the view ray's chord against path-traced"
            " single scattering of a spot light in fog, from beside, inside and along the cone, with fits.",
            study=LeafFunction("light_cones_study", "study"),
        ),
        _engine(
            "environment-maps",
            audit_environment_maps,
            reflections.METHODS,
            "Pre-convolved and localised environment maps, distance impostors vs exact traces in a room",
            "A mirror and a glass sphere in an emitting room audited by the engine (classic, distance "
            "impostor, secant search against path tracing), plus the study: cube-map convolution "
            "solid-angle rules, the seed's localised convolution against depth-1 Monte Carlo, impostor hits "
            "against exact traces, and the lookups against path-traced spheres over map size, iterations "
            "and Fresnel.",
            study=LeafFunction("environment_maps_study", "study"),
        ),
        _engine(
            "parallax-occlusion",
            audit_parallax_occlusion,
            {**parallax_occlusion.DEPTH_METHODS, **parallax_occlusion.SHADOW_AUDIT_METHODS},
            "Parallax occlusion mapping vs a displaced mesh, error vs samples vs cost, the listing's hazards",
            "The seed's linear search + piecewise-linear intersection (as printed and stable, three sample "
            "ranges) against Mitsuba's first hits on the displaced height field of a shipped bump-mapped "
            "floor at three views and two depths; the printed listing's float32 hazards (normal incidence, "
            "no crossing, unclamped offset, the soft shadow's LOD pop) against the stable form.",
            study=LeafFunction("parallax_occlusion_study", "study"),
        ),
        _engine(
            "obscurances",
            audit_obscurances,
            obscurances.METHODS,
            "Obscurances (Zhukov/Iones) vs their Monte Carlo definition and uniform-ambient path tracing",
            "The K-ray obscurance estimator with the seed's √(d/d_max) against the model's ray-cast "
            "definition (error vs rays vs cost), and fitted d_max, exponent and ambient scale against "
            "path-traced interreflections under a uniform ambient, on the sdf-occlusion scenes.",
            study=LeafFunction("obscurances_study", "study"),
        ),
        _engine(
            "fresnel",
            audit_fresnel,
            fresnel.METHODS,
            "Fresnel reflectance: Schlick, its fitted exponent, the seeds' forms and F82 vs exact Fresnel",
            "The reflectance of every visible conductor and dielectric at its viewing angle, from Mitsuba's "
            "own BSDF, against Schlick (F0 from the IOR, fitted exponent), the seeds' slider, rim and metal "
            "forms, Hoffman's F82 tint and the exact dielectric and conductor formulas.",
        ),
        _engine(
            "linear-fog",
            audit_linear_fog,
            linear_fog.METHODS,
            "Linear, exp and exp² distance fog (the seed's luminance-faded linear fog) vs Beer–Lambert",
            "Classic fixed-function fog factors on the view distance through a homogeneous medium, given "
            "(ρ = σt: Beer–Lambert) and fitted, against ratio-tracked transmittance, and the fog blend "
            "L₀·f + C·(1 − f) with fitted colour against the path-traced fogged radiance.",
        ),
        _engine(
            "sh-sky-bent-normal",
            audit_sh_sky_bent_normal,
            sh_sky_bent_normal.METHODS,
            "Sky ambient from the sky's SH along the bent normal (the skybox's lookup) vs occluded sky",
            "The seed's SH L2 sky radiance read at the bent normal × AO, the SH irradiance at the bent "
            "normal and at the normal × AO, and the SH irradiance through the visible cone, with scale and "
            "AO exponent fitted, against the sky's irradiance with the scene's occlusion (shadow rays).",
        ),
        _engine(
            "pcf-soft-shadows",
            audit_pcf_soft_shadows,
            pcf_soft_shadows.METHODS,
            "Soft shadows by filtering a shadow map (PCF, PCSS) vs an area light's penumbra",
            "The seed's 8-tap Poisson PCF (fixed and rotated per pixel), 16-tap rotated Poisson, 3×3 and 5×5 "
            "box PCF and PCSS of a shadow map cast from the light's centre (256² and 1024²), kernel radius, "
            "bias and light size fitted, times the light's closed-form irradiance, against its path-traced "
            "shadowed irradiance.",
        ),
        _engine(
            "ibl-samples",
            audit_ibl_samples,
            ibl_samples.METHODS,
            "Image-based lighting from N directional light samples (Lloyd, median cut) vs occluded envmap",
            "The environment map split into N = 4…256 directional lights — the seed's energy samples with "
            "Lloyd's relaxation on the sphere (with shadow rays, and with the seed's depth maps), the same "
            "without relaxation, Debevec's median cut — against the environment's irradiance with the "
            "scene's occlusion.",
        ),
        _engine(
            "colour-bleeding",
            audit_colour_bleeding,
            colour_bleeding.METHODS,
            "Colour bleeding (per-channel SDF bias, RGB obscurances, one-bounce gather) vs one bounce",
            "The seed's per-channel SDF biased by the surface colour (bias fitted per channel), the seed's "
            "RGB obscurances' colour part (√ transfer, and fitted) and a one-bounce gather reading the "
            "direct light at each hit, on K = 4 and 16 rays, against the path-traced one-bounce indirect "
            "irradiance per channel (path max_depth 2 − 1 along cosine rays).",
        ),
        _engine(
            "light-path-maps",
            audit_light_path_maps,
            light_path_maps.METHODS,
            "Light path maps (clustered virtual lights, blended by the moving light) vs one bounce",
            "The seed's path maps: entry points on the surfaces clustered into K = 1, 4, 16 and 32 panes, "
            "each the baked one-bounce transfer of its entry points as virtual lights (the seed's cut; and "
            "fitted), "
            "blended by the light's mean direct irradiance per cluster, against the path-traced one-bounce "
            "indirect irradiance (path max_depth 2 − 1) with the light moved across the scene.",
            study=audit_light_path_maps.study,
        ),
        _engine(
            "probe-specular",
            audit_probe_specular,
            probe_specular.METHODS,
            "Glossy specular from the nearest pre-convolved cube map (placement, parallax, mip) vs path",
            "The seed's nearest (or assigned) pre-rendered cube map pre-convolved per roughness (GGX chain), "
            "with Lagarde's box and sphere parallax correction and a fitted roughness → mip exponent, from "
            "the assigned probe and a 2×2×2 grid, against the path-traced radiance of glossy shapes.",
        ),
        _engine(
            "caustics",
            audit_caustics,
            caustics.METHODS,
            "Caustics (photon snippets splatted into the receiver's texture) vs light tracing",
            "The seed's photon hits traced through a glass or metal caster and splatted into the receiver's "
            "texture as Gaussian snippets of constant width (fitted), density-adaptive snippets and the "
            "photon-map gather, at 1024, 4096 and 16384 photons, against the caustic irradiance by light "
            "tracing through the caster connected to the camera (ptracer's estimator); energy conservation "
            "through a glass sphere against its closed-form ray optics.",
            study=audit_caustics.study,
        ),
        _engine(
            "streaky-reflections",
            audit_streaky_reflections,
            streaky_reflections.METHODS,
            "Streaky reflections: the seed's vertically streaked mirror image of a lamp vs a rough wet plane",
            "A street lamp's glossy reflection in a rough specular plane (GGX, η = 1.33), path traced with "
            "each light alone, against the seed's mirror image streaked vertically with σy = k·distance, the "
            "same streak without the distance law, an isotropic blur and the GGX BRDF toward the light.",
        ),
    )
}
"""Every family, by name, in the order ``rtfit list`` and ``rtfit run all`` use."""

EXPERIMENTS: dict[str, ExperimentSpec] = {name: f.experiment for name, f in FAMILIES.items()}
"""Family name → its experiment (``rtfit run NAME``)."""

METHOD_TABLES: dict[str, Mapping[str, Method]] = {
    name: f.methods for name, f in FAMILIES.items() if f.methods is not None and f.audits
}
"""Audited family → its method table (the rows the audit evaluates on a user's scene)."""

RULES: tuple[Rule, ...] = tuple(r for f in FAMILIES.values() for a in f.audits for r in a.rules)
"""When each audited family applies to a scene: every declaration's rules, in registry order."""

AUDITED: dict[str, AuditFamily] = by_name(a for f in FAMILIES.values() for a in f.audits)
"""Audited family → one declaration joining its roles (`audit_family.by_name`)."""


def get_experiment(name: str) -> ExperimentSpec:
    """The experiment called ``name`` (or an `registry.ALIASES` name of it)."""
    try:
        return EXPERIMENTS[ALIASES.get(name, name)]
    except KeyError:
        raise UnknownExperiment(
            f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)}; or 'all')"
        ) from None


def resolve_names(names: tuple[str, ...] | list[str]) -> list[ExperimentSpec]:
    """Expand ``all`` and validate every name before anything runs."""
    if not names:
        raise UnknownExperiment(f"name an experiment (known: {', '.join(EXPERIMENTS)}; or 'all')")
    specs: list[ExperimentSpec] = []
    for name in names:
        for spec in list(EXPERIMENTS.values()) if name == "all" else [get_experiment(name)]:
            if spec not in specs:
                specs.append(spec)
    return specs


def validate_config(experiment: str, quick: bool, spp: int | None, overrides: dict | None = None) -> dict:
    """The configuration ``experiment`` will run with, every value checked (type, range and the deeper
    checks: files readable, names known) — what the command line calls before anything runs or is
    written. A one-line ``ValueError`` otherwise."""
    if spp is not None and not 2 <= spp <= SPP_MAX:
        raise ValueError(f"spp = {spp}: out of range [2, {SPP_MAX}] (registry.SPP_MAX)")
    spec = get_experiment(experiment)
    defaults = spec.load().configure(quick, spp)
    return apply_overrides(defaults, dict(overrides or {}), spec.name, deep=True, declared=spec.config)


def describe_config(experiment: str, quick: bool) -> str:
    """``key = default  # type and range — meaning`` lines (``rtfit sweep --show-config``)."""
    spec = get_experiment(experiment)
    cfg = spec.load().configure(quick, None)
    declared = spec.config or {}
    lines = []
    for k, v in cfg.items():
        line = f"{k} = {json.dumps(v)}"
        if k in declared:
            d = declared[k]
            line += f"  # {d.describe()}" + (f" — {d.doc}" if d.doc else "")
        lines.append(line)
    return "\n".join(lines)
