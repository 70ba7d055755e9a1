"""The ``probe-specular`` family in `rtfit audit` (and ``rtfit run probe-specular`` on its shipped scene):
glossy surfaces shaded from the nearest (or assigned) pre-rendered cube map, pre-convolved per roughness,
against the path-traced radiance of the pixels that see them.

For each glossy reflector (``roughconductor``, ``roughplastic``) of a Mitsuba XML scene, or of an rtfit
TOML scene (a ``mitsuba_xml`` shape keeping its file's BSDFs), one case per probe placement:

* ``shape<i>-assigned``: one probe, the assigned one (``--probe-at X,Y,Z``, else the shape's bounding-box
  centre: the seed's hand-placed sample point);
* ``shape<i>-grid<k>`` for k in `GRIDS`: k³ probes at the cell centres of a k×k×k grid over the scene's
  bounding box, each pixel shaded from its nearest probe (the seed's nearest sample point). N = k³ is the
  placement knob; each probe costs a capture (its rays, in the case's ``extra_seconds``) and its chain's
  storage (`storage_floats`).

Per probe (the shape itself hidden: an engine leaves an object out of its own probe): the radiance cube map
(`PROBE_RESOLUTION`² a face) by Mitsuba's ``path`` integrator from the probe point along the texel-centre
directions, `--spp` samples a texel in cached passes; its chain pre-convolved per roughness
(`rtfit.realtime.probe_specular.prefilter`: `LEVELS` GGX levels, `PREFILTER_RESOLUTION`² a face), its
irradiance map (`IRRADIANCE_RESOLUTION`², cosine lobe: a plastic's diffuse base), and its distance map
(first hits), whose median (capped at the scene's diagonal) is the sphere proxy's radius. The box proxy
is the scene's bounding box (a room's walls, for a room). Both relative to the probe.

**Reference**: Mitsuba's ``path`` (unbounded depth, Russian roulette) along the pixel-centre camera rays,
independent passes through the pass cache, per-pixel standard errors. **What the shape does with light**
(`surface_lobes`): the mirror direction R, the normal, the glossy lobe's directional albedo w_r and the
diffuse albedo w_d (`LOBE_SAMPLES` BSDF samples a pixel). α is the BSDF's roughness (Mitsuba's default
distribution is Beckmann; the chain's levels are GGX: a Beckmann α is read as a GGX α, stated in the
case's notes). Rows: `rtfit.realtime.probe_specular.METHODS`; the ``*-mip-fit`` rows fit the roughness →
mip exponent p per case.
"""

from __future__ import annotations

import itertools
import time

import numpy as np

from rtfit.realtime import probe_specular as ps
from rtfit.realtime.environment_maps import convolve
from rtfit.reference.reflective_shapes import (
    bsdf_roughness,
    first_hits,
)

from .audit import Applicability, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_geometry import reflective_shape
from .audit_setup import AuditSetup
from .audit_shape_probes import probe_capture, seen_shape, shape_radiance, unit_cube_texels
from .case_inputs import rgb_columns, vector_text, xyz_columns
from .shipped import Sizes

__all__ = ["FAMILY", "GRIDS", "LOBE_SAMPLES", "SCENES", "probe_specular_cases", "storage_floats"]

FORMAT = 1
GRIDS = (2,)
"""Probe grids k (k³ probes over the scene's bounding box) audited beside the assigned probe."""
LOBE_SAMPLES = 128
"""BSDF samples a pixel for the glossy and diffuse albedos."""
GLOSSY = frozenset({"roughconductor", "roughplastic"})
"""The BSDFs this family audits (a rough dielectric's transmission is not a probe's specular)."""

SCENES = (
    Sizes(full=(48, 48, 64), quick=(16, 16, 4)).scene(
        "probe_specular_room.xml",
        "a closed room (red and green side walls, white back wall, a ceiling light) with a rough aluminium "
        "floor (GGX α = 0.1) and a rough plastic sphere (GGX α = 0.3); probes at the shapes' centres and "
        "on a 2×2×2 grid",
    ),
)
"""The scene ``rtfit run probe-specular`` audits (scenes/library/)."""


def storage_floats(probes: int) -> int:
    """Floats stored for ``probes`` probes: each chain (levels × 6·N² × RGB) and irradiance map."""
    per = ps.LEVELS * 6 * ps.PREFILTER_RESOLUTION**2 * 3 + 6 * ps.IRRADIANCE_RESOLUTION**2 * 3
    return probes * per


def _shape(setup: AuditSetup, app: Applicability):
    return reflective_shape(setup, app, "probe-specular", check_label=False)


def _grid(lo: np.ndarray, hi: np.ndarray, k: int) -> np.ndarray:
    axes = [lo[a] + (np.arange(k) + 0.5) * (hi[a] - lo[a]) / k for a in range(3)]
    return np.array(list(itertools.product(*axes)), np.float64)


def _capture(setup: AuditSetup, index: int, shape, probe: np.ndarray, far: float, label: str):
    """(radiance (6N², 3), irradiance (6N_E², 3), sphere radius, seconds, spp) of one probe."""
    mi, scene = setup.mi, setup.scene
    pooled = probe_capture(setup, FORMAT, index, shape, probe, ps.PROBE_RESOLUTION, label)
    rad = pooled.mean
    texels = unit_cube_texels(ps.PROBE_RESOLUTION)
    dist = np.minimum(first_hits(mi, scene, probe, texels, skip=shape), far)
    q = unit_cube_texels(ps.IRRADIANCE_RESOLUTION)
    irr = np.stack([convolve(rad[:, c], q, 0.0, "exact") for c in range(3)], axis=1)
    return rad, irr, float(np.median(dist)), pooled.seconds, pooled.spp


def probe_specular_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The assigned-probe case and one case per grid of `GRIDS` for a glossy shape the camera sees (module
    docstring); none for a rough dielectric or a shape the camera does not see."""
    mi, scene = setup.mi, setup.scene
    index, shape, plugin = _shape(setup, app)
    if plugin not in GLOSSY:
        return []
    seen = seen_shape(setup, index, shape)
    if seen is None:
        return []
    mask, points, assigned = seen.mask, seen.points, seen.probe
    sbox = scene.bbox()
    lo, hi = np.array(sbox.min, np.float64), np.array(sbox.max, np.float64)
    far = max(float(np.linalg.norm(hi - lo)), 1e-6)
    tag = f"shape{index}"
    pooled, lobes = shape_radiance(setup, app, FORMAT, seen, LOBE_SAMPLES)
    alpha = bsdf_roughness(mi, shape)
    distribution = _distribution(shape)
    placements = [("assigned", assigned[None, :])] + [(f"grid{k}", _grid(lo, hi, k)) for k in GRIDS]
    placed, waited = [], []
    for _, probes in placements:
        t0 = time.perf_counter()
        placed.append(
            [
                _capture(
                    setup, index, shape, p, far, f"{tag}: probe {j + 1}/{len(probes)} at {vector_text(p)}"
                )
                for j, p in enumerate(probes)
            ]
        )
        waited.append(time.perf_counter() - t0)
    # Every probe's chain in one pass: each level's matrix is built once for the shape (`prefilter_many`),
    # its time shared among the placements by their probe counts.
    t0 = time.perf_counter()
    chain_of = iter(ps.prefilter_many([c[0] for captures in placed for c in captures]))
    per_probe = (time.perf_counter() - t0) / sum(len(probes) for _, probes in placements)
    cases = []
    for (name, probes), captures, wait in zip(placements, placed, waited, strict=True):
        spent, t0 = wait + per_probe * len(probes), time.perf_counter()  # its captures, its chains' share
        chains = np.concatenate([next(chain_of) for _ in captures], axis=0)
        irr = np.concatenate([c[1] for c in captures], axis=0)
        nearest = np.argmin(np.linalg.norm(points[:, None, :] - probes[None, :, :], axis=2), axis=1)
        rel = points - probes[nearest]
        b0, b1 = lo[None, :] - probes[nearest], hi[None, :] - probes[nearest]
        radius = np.array([c[2] for c in captures])[nearest]
        inputs = {
            **{c: np.ascontiguousarray(rel[:, k]) for k, c in enumerate("xyz")},
            **xyz_columns("r", lobes.reflect),
            **xyz_columns("n", lobes.normal),
            **rgb_columns("wr", lobes.w_reflect),
            **rgb_columns("wd", lobes.w_diffuse),
            "alpha": np.full(len(points), alpha),
            "probe": nearest.astype(np.float64),
            **{f"b{c}0": np.ascontiguousarray(b0[:, k]) for k, c in enumerate("xyz")},
            **{f"b{c}1": np.ascontiguousarray(b1[:, k]) for k, c in enumerate("xyz")},
            "radius": radius,
            "chains": ps.ProbeChains(chains, irr),
        }
        capture_seconds = sum(c[3] for c in captures) + spent + time.perf_counter() - t0
        ref = pooled.reference(
            mask,
            quantity="radiance of the pixels that see the glossy shape (W/m²/sr)",
            integrator="path (unbounded depth, Russian roulette) along the pixel-centre camera rays",
            integrator_reason=(
                f"{plugin}: Mitsuba's own BSDF and every path around the shape; the rows read "
                f"{len(probes)} pre-rendered cube map(s) pre-convolved per roughness"
            ),
            extra_seconds=capture_seconds,
        )
        parameters = {
            "shape": app.part,
            "bsdf": plugin,
            "alpha": alpha,
            "distribution": distribution,
            "placement": name,
            "probes": [[float(c) for c in p] for p in probes],
            "probe_count": len(probes),
            "probe_from": ("--probe-at" if setup.probe_at is not None else "the shape's bounding-box centre")
            if name == "assigned"
            else f"cell centres of a {name[4:]}³ grid over the scene's bounding box",
            "resolution": ps.PROBE_RESOLUTION,
            "prefilter_resolution": ps.PREFILTER_RESOLUTION,
            "levels": ps.LEVELS,
            "storage_floats": storage_floats(len(probes)),
            "capture_spp": captures[0][4],
            "capture_seconds": capture_seconds,
            "pixels": int(mask.sum()),
        }
        notes = (
            f"{len(probes)} probe(s) ({parameters['probe_from']}), the shape hidden: {ps.PROBE_RESOLUTION}² "
            f"texels a face, {captures[0][4]} path samples a texel; chains of {ps.LEVELS} GGX levels at "
            f"{ps.PREFILTER_RESOLUTION}², {storage_floats(len(probes))} floats stored; capture + "
            f"pre-convolution {capture_seconds:.3g} s",
            f"α = {alpha:.4g} ({distribution}"
            + (": read as a GGX α by the chain" if distribution != "ggx" else "")
            + f"); box proxy: the scene's bounding box {vector_text(lo)}–{vector_text(hi)}; sphere proxy: "
            "the median distance the probe sees",
        )
        cases.append(
            FamilyCase(
                id=f"{tag}-{name}",
                label=f"{app.part}, {name} probe{'s' if len(probes) > 1 else ''}",
                reference=ref,
                channel_inputs=(inputs,),
                parameters=parameters,
                units="W/m²/sr",
                notes=notes,
            )
        )
    return cases


def _distribution(shape) -> str:
    """The microfacet distribution the BSDF prints (``distribution = ggx`` or ``beckmann``)."""
    text = str(shape.bsdf())
    return "ggx" if "distribution = ggx" in text else "beckmann"


FAMILY = AuditFamily(
    name="probe-specular",
    quantity="probe_specular_radiance",
    cases=probe_specular_cases,
    describe=(
        "Per glossy shape (roughconductor, roughplastic): the radiance of the pixels that see it, "
        "path-traced along the pixel-centre camera rays, against the seed's nearest pre-rendered cube map "
        f"pre-convolved per roughness ({ps.LEVELS} GGX levels, Karis 2013), from the assigned probe (the "
        f"shape's centre or --probe-at) and from the nearest of a {'/'.join(f'{k}³' for k in GRIDS)} grid "
        "over the scene's box; rows without parallax correction, with Lagarde 2012's box and sphere "
        "proxies, and with the roughness → mip exponent fitted."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "probe-specular",
            "glossy probe specular",
            ("rough-shape",),
            "{part} is glossy: an engine shades its specular from the nearest pre-rendered cube map, "
            "pre-convolved per roughness",
            "path-traced radiance of the pixels that see the shape",
            "path (unbounded depth, Russian roulette) along the pixel-centre camera rays; the probes "
            "captured by the same integrator, the shape itself hidden",
            supplies=frozenset(i.name for i in ps.INPUTS),
        ),
    ),
)
