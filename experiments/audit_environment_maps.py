"""The ``environment-maps`` family in `rtfit audit`: a mirror, glass or glossy shape of the user's scene
shaded from one cube map captured at its centre, against the path-traced radiance of the pixels that see it.

For each reflective shape (`rtfit.reference.reflective_shapes.REFLECTIVE_BSDFS`: ``conductor``,
``dielectric``, ``thindielectric``, ``plastic`` and their rough versions) of a Mitsuba XML scene, or of an
rtfit TOML scene (a ``mitsuba_xml`` shape keeping its file's BSDFs), one case ``shape<i>``:

* **pixels**: the pixel-centre camera rays whose first hit is that shape (`shape_pixels`);
* **reference**: Mitsuba's ``path`` integrator (unbounded depth, Russian roulette) along those rays, in
  independent passes through the pass cache, with per-pixel standard errors (W/(m²·sr), RGB);
* **the probe** an engine would capture, at the shape's bounding-box centre c (``--probe-at X,Y,Z``
  overrides): the radiance cube map of `PROBE_RESOLUTION`² texels a face by the same integrator along the
  texel-centre directions from c, with the shape itself hidden (each ray passes through it first: an
  engine leaves an object out of its own probe), `--spp` samples a texel in passes of their own; the
  distance cube map (first hits from c, the shape hidden; a ray that leaves the scene stores
  `FAR_FACTOR` × the scene's bounding-box diagonal, a finite stand-in for infinity); from the radiance
  map, by `rtfit.realtime.environment_maps.convolve` with exact texel solid angles, the irradiance map
  (`IRRADIANCE_RESOLUTION`², cosine lobe) and, for a rough BSDF, the glossy pre-filtered map
  (`GLOSSY_RESOLUTION`², normalised Phong lobe of exponent s = (2/α² − 2)/4 from the BSDF's roughness α:
  Walter et al. 2007's Beckmann–Phong correspondence on the half vector, a quarter of it on the mirror
  direction, whose angle from R is about twice the half vector's from n);
* **what the shape does with light** (`surface_lobes`, from Mitsuba's own BSDF at each first hit): the
  mirror direction R, the refracted direction T (straight through for thin glass) and the lobe weights per
  channel — Fresnel × reflectance for a delta reflection, (1 − F) × transmittance for a delta transmission,
  the directional albedo of a glossy or diffuse lobe (`LOBE_SAMPLES` BSDF samples a pixel);
* **rows**: `rtfit.realtime.reflections.METHODS` — ``classic`` (L at R and T), ``parallax`` and
  ``iterative`` (the distance impostor's one-lookup and secant hits), and on rough shapes
  ``preconvolved`` and ``preconvolved-parallax`` (the glossy map). No row has free parameters. A user's
  ``@approximation(quantity="reflected_radiance")`` reads the same pixel inputs, the radiance, irradiance
  and distance maps and their resolutions (`on_probe`); the glossy map is not in its ``g``.

What the numbers mean: under a distant environment alone (nothing else in the scene) the cube map is the
environment wherever it is captured and ``classic`` is exact for a mirror (L·F); the reference's noise is
then its only error (tests/test_audit_environment_maps.py checks it against the closed form). Nearby
geometry (a floor) is where the probe's position matters: the impostor rows correct the parallax the
classic lookup ignores. Glass rows use one refraction (what the shader does), not the path through the
shape; rough rows show what pre-filtering with one lobe shape misses.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from rtfit.realtime import environment_maps as em
from rtfit.realtime.methods import Method
from rtfit.realtime.reflections import (
    GLOSSY_RESOLUTION,
    IRRADIANCE_RESOLUTION,
    PROBE_RESOLUTION,
)
from rtfit.reference.reflective_shapes import (
    REFLECTIVE_BSDFS,
    bsdf_roughness,
    first_hits,
)

from .audit import Applicability, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_geometry import reflective_shape
from .audit_setup import AuditSetup
from .audit_shape_probes import probe_capture, seen_shape, shape_radiance, unit_cube_texels
from .case_inputs import rgb_columns, vector_text, xyz_columns
from .shipped import ShippedScene

__all__ = [
    "FAMILY",
    "FAR_FACTOR",
    "LOBE_SAMPLES",
    "SCENES",
    "environment_maps_cases",
    "filtered_tables",
    "on_probe",
    "phong_exponent",
]

FORMAT = 1
FAR_FACTOR = 100.0
"""A ray that leaves the scene stores this many bounding-box diagonals in the distance map."""
LOBE_SAMPLES = 256
"""BSDF samples a pixel for the albedo of a glossy or diffuse lobe."""


def phong_exponent(alpha: float) -> float:
    """The normalised-Phong exponent of the mirror-direction lobe for a Beckmann roughness α (module
    docstring): (2/α² − 2)/4, within [10⁻³, 10⁴] (a Phong lobe, not the clamped cosine of s ≤ 0)."""
    if alpha <= 0.0:
        return 1e4  # a smooth BSDF: the sharpest lobe the table allows
    return min(max((2.0 / (alpha * alpha) - 2.0) / 4.0, 1e-3), 1e4)


def filtered_tables(prefix: str, rad: np.ndarray, resolution: int, shininess: float) -> dict[str, np.ndarray]:
    """The radiance map ``rad`` (6N², 3) convolved with the lobe of ``shininess`` (0: clamped cosine) at the
    texel centres of a ``resolution``² map, one table per channel: Σ_t L_t·lobe(q·ω_t)·Ω_t divided by the
    lobe's own sum Σ_t lobe(q·ω_t)·Ω_t and times its integral (π for the cosine, 1 for the normalised Phong
    lobe), as an engine's filter normalises its weights, so that a lobe narrower than a texel (a nearly
    smooth BSDF: s in the thousands) keeps its energy; where no texel centre falls inside it at all, the
    map's own bilinear value at q."""
    q = unit_cube_texels(resolution)
    weight = em.convolve(np.ones(len(rad)), q, shininess, "exact")
    integral = math.pi if shininess <= 0.0 else 1.0
    out = {}
    for k, c in enumerate("rgb"):
        sums = em.convolve(rad[:, k], q, shininess, "exact")
        direct = np.asarray(em.cube_lookup(rad[:, k], q, numpy=True), np.float64) * integral
        out[f"{prefix}_{c}"] = np.where(weight > 1e-6, integral * sums / np.maximum(weight, 1e-300), direct)
    return out


def _shape(setup: AuditSetup, app: Applicability):
    return reflective_shape(setup, app, "environment-maps")


def environment_maps_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case per reflective shape the camera sees (module docstring); none where it sees none of it."""
    mi, scene = setup.mi, setup.scene
    index, shape, plugin = _shape(setup, app)
    seen = seen_shape(setup, index, shape)
    if seen is None:
        return []
    mask, points, probe = seen.mask, seen.points, seen.probe
    sbox = scene.bbox()
    far = FAR_FACTOR * max(float(np.linalg.norm(np.array(sbox.max) - np.array(sbox.min))), 1e-6)
    tag = f"shape{index}"
    texels = unit_cube_texels(PROBE_RESOLUTION)
    dist = np.minimum(first_hits(mi, scene, probe, texels, skip=shape), far)
    capture = probe_capture(
        setup, FORMAT, index, shape, probe, PROBE_RESOLUTION, f"{tag}: cube map at {vector_text(probe)}"
    )
    rad = capture.mean
    pooled, lobes = shape_radiance(setup, app, FORMAT, seen, LOBE_SAMPLES)
    rough = REFLECTIVE_BSDFS[plugin].rough
    alpha = bsdf_roughness(mi, shape) if rough else 0.0
    shininess = phong_exponent(alpha)
    inputs: dict = {
        **{c: np.ascontiguousarray(points[:, k] - probe[k]) for k, c in enumerate("xyz")},
        **xyz_columns("r", lobes.reflect),
        **xyz_columns("t", lobes.refract),
        **xyz_columns("n", lobes.normal),
        **rgb_columns("wr", lobes.w_reflect),
        **rgb_columns("wt", lobes.w_refract),
        **rgb_columns("wd", lobes.w_diffuse),
        **{f"rad_{c}": np.ascontiguousarray(rad[:, k]) for k, c in enumerate("rgb")},
        **filtered_tables("irr", rad, IRRADIANCE_RESOLUTION, 0.0),
        "dist": dist,
    }
    if rough:
        inputs.update(filtered_tables("glossy", rad, GLOSSY_RESOLUTION, shininess))
    ref = pooled.reference(
        mask,
        quantity="radiance of the pixels that see the shape (W/m²/sr)",
        integrator="path (unbounded depth, Russian roulette) along the pixel-centre camera rays",
        integrator_reason=(
            f"{plugin}: Mitsuba's own BSDF and every path through and around the shape; the real-time rows "
            "read one cube map captured at the probe point"
        ),
        extra_seconds=capture.seconds,
    )
    missed = int(np.sum(dist >= far))
    parameters = {
        "shape": app.part,
        "bsdf": plugin,
        "probe": [float(c) for c in probe],
        "probe_from": "--probe-at" if setup.probe_at is not None else "the shape's bounding-box centre",
        "resolution": PROBE_RESOLUTION,
        "glossy_resolution": GLOSSY_RESOLUTION if rough else 0,
        "irradiance_resolution": IRRADIANCE_RESOLUTION,
        "alpha": alpha,
        "shininess": shininess if rough else 0.0,
        "far_distance": far,
        "texels_missing_the_scene": missed,
        "capture_spp": capture.spp,
        "pixels": int(mask.sum()),
    }
    notes = (
        f"cube maps captured at {vector_text(probe)} ({parameters['probe_from']}), the shape hidden: "
        f"{PROBE_RESOLUTION}² texels a face, {capture.spp} path samples a texel; {missed} of {len(texels)} "
        f"texels see no surface (distance {far:.4g}, {FAR_FACTOR:g} × the scene's diagonal)",
        "lobe weights from Mitsuba's BSDF: delta lobes exact, glossy and diffuse albedos from "
        f"{LOBE_SAMPLES} BSDF samples a pixel"
        + (f"; glossy map: Phong s = {shininess:.4g} from α = {alpha:.4g}" if rough else ""),
    )
    return [
        FamilyCase(
            id=tag,
            label=f"{app.part}, radiance",
            reference=ref,
            channel_inputs=(inputs,),
            parameters=parameters,
            units="W/m²/sr",
            notes=notes,
            user_rows=on_probe,
        )
    ]


def on_probe(method: Method) -> Method:
    """A user's approximation of ``reflected_radiance`` with the maps' resolutions as fixed keywords (as
    the rows hold them: `rtfit.realtime.reflections`): Python ints its text may loop over, not arrays."""
    sizes = {"resolution": PROBE_RESOLUTION, "irr_resolution": IRRADIANCE_RESOLUTION}
    return replace(
        method, inputs=tuple(i for i in method.inputs if i.name not in sizes), fixed={**method.fixed, **sizes}
    )


FAMILY = AuditFamily(
    name="environment-maps",
    quantity="reflected_radiance",
    cases=environment_maps_cases,
    describe=(
        "Per reflective shape (conductor, dielectric, thin dielectric, plastic and their rough versions): "
        "the radiance of the pixels that see it, path-traced along the pixel-centre camera rays (unbounded "
        "depth), against what an engine shades from one probe captured at the shape's centre (or "
        "--probe-at): a radiance and a distance cube map "
        f"({PROBE_RESOLUTION}² a face, the shape hidden), an irradiance map ({IRRADIANCE_RESOLUTION}²) and, "
        f"for a rough BSDF, a glossy pre-filtered map ({GLOSSY_RESOLUTION}², Phong s from the BSDF's α). "
        "Each row is w_r·M(R) + w_t·M(T) + w_d·E(n)/π with the BSDF's own lobe weights (Fresnel, albedo) "
        "and the row's lookup M: classic (L at the direction), the distance impostor's one-lookup and "
        "secant hits, the pre-convolved glossy map."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        *(
            Rule(
                "environment-maps",
                role,
                (kind,),
                "{part} shows its surroundings: a cube map captured at its centre stands in for them",
                "path-traced radiance of the pixels that see the shape",
                "path (unbounded depth, Russian roulette) along the pixel-centre camera rays; the cube maps "
                "captured by the same integrator from the probe point, the shape itself hidden",
            )
            for role, kind in (("reflections", "reflective-shape"), ("glossy reflections", "rough-shape"))
        ),
    ),
)


ROOM_CENTRE = "0, 0, 1.25"
"""The room's centre (m): where the experiment before the engine captured its cube maps."""
SPHERES = {"moved": "1, 0.4, 0.75", "at-reference": ROOM_CENTRE}
"""The sphere's centre (m) in scenes/library/environment_maps_room_*.xml: moved 1.2 m from the room's centre
(its cube maps captured at the room's centre: the parallax the impostors correct) or at the centre."""


def _scene(material: str, where: str) -> ShippedScene:
    what = "perfect mirror" if material == "mirror" else "glass sphere (n = 1.5)"
    return ShippedScene(
        f"environment_maps_room_{material}.xml",
        f"{what} {'moved 1.2 m from' if where == 'moved' else 'at'} the centre of the textured emitting "
        "room, cube maps captured at the room's centre",
        size=(96, 96),
        spp=2048 if material == "glass" else 16,
        quick_size=(16, 16),
        quick_spp=64 if material == "glass" else 4,
        options={"probe_at": tuple(float(c) for c in ROOM_CENTRE.split(","))},
        defines={"centre": SPHERES[where]},
        name=f"{material}-{where}",
        quick=where == "moved" and material == "mirror",
    )


SCENES = tuple(_scene(m, w) for w in SPHERES for m in ("mirror", "glass"))
"""The scenes ``rtfit run environment-maps`` audits: the experiment's room (walls emitting its closed-form
texture, reflecting nothing) with a perfect-mirror or a glass sphere, moved from the room's centre (quick) or
at it, the cube maps captured at the room's centre (the cases of the experiment's path-traced part)."""
