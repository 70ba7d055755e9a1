r"""The ``clouds`` family in `rtfit audit`: the sun's transmittance to the ground through a cloud, from the
seed's cloud-shadow texture (000:2322-2343, 002:349-387) and a 3-D ray march, against ratio tracking through
the scene's own heterogeneous medium.

When it applies (its ``rules``): a Mitsuba ``heterogeneous`` medium whose ``sigma_t`` is a ``gridvolume``
(the ``grid-fog`` part) in a scene with a light and a surface; its cases then need a **distant** light (a
``directional`` emitter, or a ``sunsky``'s sun): a cloud shadow is the sun's. Without one it gives no case
(``--list`` says it needs one; an error there would stop every other family's audit of the scene). The
grid's box must be axis-aligned (a shadow texture is a plane of the world's xy; +z up).

One case ``cloudK-shadow`` per such medium, on the pixels that show a surface facing the sun (n·s > 0):

* **Reference**: T(p) = exp(−∫σt(p + t·s) dt) from each visible point p along the unit direction s towards
  the sun, by ratio tracking through the loaded medium (`rtfit.reference.cloud_shadow`: Mitsuba's own
  trilinear ``gridvolume`` lookup), in passes through the pass cache. The ground's sun irradiance is then
  E = E_sun·max(n·s, 0)·T: T is the factor the cloud puts on it.
* **Inputs**: p (px, py, pz), s (sx, sy, sz) and the cloud (`rtfit.realtime.clouds.CloudGrid`: the grid read
  back from the medium, `rtfit.reference.grid_fit.grid_of_medium`).
* **Rows**: `rtfit.realtime.clouds.METHODS`: the seed's texture (``plane``: k = 1, h = the cloud's mean
  height, then fitted), the plane extruded and marched (``slab-4``, ``slab-16``: k = 1 and the box's bottom
  and top, then fitted), the 3-D march with 4 … 64 samples (no free parameter).

A second case ``cloudK-radiance`` (quantity ``cloud_radiance``, rows `rtfit.realtime.clouds.RADIANCE_METHODS`)
on the pixels whose ray crosses the cloud's box: the reference is ``volpathmis`` with the cloud alone
(`audit_media.radiance_passes`), L_bg the same pixels with it switched off; inputs: the camera ray, the sun,
its irradiance (a ``directional`` emitter's), the medium's constant albedo and HG g (no case otherwise);
rows: the seed's gradient-lit cloud (fitted colours) and the sun's single scattering marched.

The shipped scenes: the grid of `cloud_blobs` (four Gaussian blobs, written to
``scenes/library/volumes/clouds_blobs.vol`` by `write_blobs`) over a grey ground under a directional sun at
two elevations (``scenes/library/clouds_sun.xml``: its shadows), and against a black sky from two sides
(``clouds_sky.xml``: its radiance).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from rtfit.realtime.clouds import MARCH_STEPS, METHODS, RADIANCE_METHODS, CloudGrid
from rtfit.reference.cache import array_digest
from rtfit.reference.cloud_shadow import sun_transmittance_pass
from rtfit.reference.estimators import gbuffer_points
from rtfit.reference.grid_fit import grid_of_medium

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_media import RADIANCE_INTEGRATOR, opened_medium, radiance_passes, sun_direction_of
from .audit_setup import AuditSetup, pooled_passes
from .records import Check, Section
from .shipped import ShippedScene, Sizes, Study, StudyContext

__all__ = [
    "BLOBS",
    "BOX",
    "FAMILY",
    "RADIANCE_SCENES",
    "SCENES",
    "cloud_blobs",
    "cloud_cases",
    "study",
    "sun_direction",
    "write_blobs",
]

FORMAT = 1
BOX = ((-4.0, -4.0, 2.0), (4.0, 4.0, 4.0))
"""The shipped cloud's box (m): lo, hi."""
RESOLUTION = (40, 40, 10)
"""The shipped grid's voxels (nx, ny, nz): 0.2 m cubes."""
BLOBS = (
    # centre (m), standard deviation per axis (m), peak extinction (1/m)
    ((-1.5, -1.0, 3.0), (0.9, 0.7, 0.35), 3.0),
    ((1.2, 0.8, 2.9), (0.7, 1.0, 0.3), 2.5),
    ((0.3, -2.0, 3.2), (0.5, 0.5, 0.3), 4.0),
    ((-0.5, 2.2, 3.0), (1.0, 0.4, 0.4), 1.5),
)
"""The shipped cloud: σ(p) = Σ_b A_b·exp(−½·Σ_k ((p_k − c_bk)/σ_bk)²) (a few blobs, as the brief asks)."""
SUN_ELEVATIONS = (60.0, 30.0)
"""The shipped scenes' sun elevations (degrees; azimuth along +x)."""


def cloud_blobs(points: np.ndarray) -> np.ndarray:
    """σ (1/m) of `BLOBS` at ``points`` (..., 3) m."""
    p = np.asarray(points, np.float64)
    out = np.zeros(p.shape[:-1])
    for centre, sd, peak in BLOBS:
        q = (p - np.asarray(centre)) / np.asarray(sd)
        out += peak * np.exp(-0.5 * np.sum(q * q, axis=-1))
    return out


def blob_grid() -> np.ndarray:
    """(nz, ny, nx) float32: `cloud_blobs` at the voxel centres of `BOX` × `RESOLUTION`."""
    lo, hi = (np.asarray(b) for b in BOX)
    axes = [lo[k] + (np.arange(n) + 0.5) / n * (hi[k] - lo[k]) for k, n in enumerate(RESOLUTION)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    return cloud_blobs(np.stack([x, y, z], axis=-1)).astype(np.float32)


def write_blobs(mi, path: Path) -> None:
    """Write `blob_grid` as a Mitsuba ``.vol`` file (the shipped scenes/library/volumes/clouds_blobs.vol)."""
    mi.VolumeGrid(blob_grid()[..., None]).write(str(path))


def sun_direction(elevation_deg: float) -> tuple[float, float, float]:
    """The unit direction towards a sun at ``elevation_deg`` above the horizon, azimuth +x."""
    e = math.radians(elevation_deg)
    return (math.cos(e), 0.0, math.sin(e))


_ground = Sizes(full=(48, 48, 256), quick=(16, 16, 32))
_sky = Sizes(full=(32, 32, 256), quick=(12, 12, 32))


def _scene(elevation: float) -> ShippedScene:
    s = sun_direction(elevation)
    return _ground.scene(
        "clouds_sun.xml",
        f"four Gaussian blobs of cloud (peak σt 1.5–4 /m) 2–4 m above a grey ground, sun at {elevation:g}°",
        defines={"dx": f"{-s[0]:.6f}", "dy": "0", "dz": f"{-s[2]:.6f}"},
        name=f"sun{elevation:g}",
        quick=elevation == SUN_ELEVATIONS[0],
        quantities=("cloud_transmittance",),  # the radiance: clouds_sky.xml's (no ground behind the cloud)
    )


CAMERAS = {"backlit": (-9.0, -1.3, 0.7), "front": (9.0, 1.3, 0.7), "sun-behind": (-9.0, -1.3, 0.7)}
"""clouds_sky.xml's camera positions (m): from −x it looks towards the sun (azimuth +x), from +x with it;
``sun-behind``: the backlit camera with the sun straight behind the cloud's centre (`SKY_TARGET`)."""
SKY_TARGET = (0.011, 0.013, 3.0)
"""clouds_sky.xml's camera target (m): the cloud's centre (its lookat)."""


def _sky_sun(view: str) -> tuple[float, float, float]:
    """The direction towards the sun of a sky view: 60° elevation, azimuth +x; for ``sun-behind`` the
    camera's own line of sight to `SKY_TARGET` (elevation 14°: the cloud partly covers the sun, the seed's
    back-lighting case 000:2324)."""
    if view != "sun-behind":
        return sun_direction(SUN_ELEVATIONS[0])
    d = np.asarray(SKY_TARGET) - np.asarray(CAMERAS[view])
    d = d / np.linalg.norm(d)
    return float(d[0]), float(d[1]), float(d[2])


def _sky_scene(view: str) -> ShippedScene:
    s, c = _sky_sun(view), CAMERAS[view]
    return _sky.scene(
        "clouds_sky.xml",
        f"the blobs' cloud against a black sky, sun at {math.degrees(math.asin(s[2])):.3g}°, seen {view}",
        defines={
            "dx": f"{-s[0]:.6f}",
            "dy": f"{-s[1]:.6f}" if s[1] else "0",
            "dz": f"{-s[2]:.6f}",
            "cx": f"{c[0]:g}",
            "cy": f"{c[1]:g}",
            "cz": f"{c[2]:g}",
        },
        name=f"sky-{view}",
        quick=view == "backlit",
        quantities=("cloud_radiance",),
    )


RADIANCE_SCENES = tuple(_sky_scene(v) for v in CAMERAS)
"""The cloud's radiance scenes (scenes/library/clouds_sky.xml, three views)."""
SCENES = (*(_scene(e) for e in SUN_ELEVATIONS), *RADIANCE_SCENES)
"""The scenes ``rtfit run clouds`` audits (clouds_sun.xml per sun elevation; clouds_sky.xml per view)."""


def _sun(setup: AuditSetup) -> np.ndarray | None:
    """The unit direction towards the scene's distant light (directional, or a sunsky's sun); None without
    one."""
    xml = setup.info.xml
    if xml is not None:
        for e in xml.emitters:
            if e.kind == "directional" and e.direction is not None:
                d = np.asarray(e.direction, np.float64)
                return d / np.linalg.norm(d)
    return sun_direction_of(setup)


def _grid(setup: AuditSetup, medium) -> CloudGrid:
    """The medium's grid as a `CloudGrid` (axis-aligned box only)."""
    try:
        g = grid_of_medium(setup.mi, medium)
    except ValueError as e:
        raise AuditError(f"clouds: {e}") from None
    m = g.to_world
    if not np.allclose(m[:3, :3], np.diag(np.diag(m[:3, :3])), atol=1e-6 * np.abs(m[:3, :3]).max()):
        raise AuditError("clouds: the cloud's grid is rotated: a shadow texture needs an axis-aligned box")
    scale = np.diag(m[:3, :3])
    if not np.all(scale > 0.0):
        raise AuditError(
            "clouds: the cloud's grid is mirrored: a shadow texture needs a box of positive axes"
        )
    lo, hi = m[:3, 3], m[:3, 3] + scale
    return CloudGrid(np.maximum(g.data, 0.0), tuple(lo), tuple(hi))


def _params(cloud: CloudGrid) -> dict:
    """The rows' given values (module docstring) with bounds from the cloud's box."""
    lo, hi = cloud.lo[2], cloud.hi[2]
    base = METHODS["plane"].params
    span = hi - lo

    def height(name: str, value: float, what: str):
        return dataclasses.replace(
            base["h"], initial=value, lower=lo - span, upper=hi + span, description=what
        )

    plane = {"h": height("h", cloud.mean_height(), "plane height h (given: the cloud's mean height)")}
    slab = {"h0": height("h0", lo, "slab bottom h₀ (given: the box's bottom)"),
            "h1": height("h1", hi, "slab top h₁ (given: the box's top)")}  # fmt: skip
    return {k: (plane if k.startswith("plane") else slab) for k in METHODS if not k.startswith("march")}


def _sun_irradiance(setup: AuditSetup) -> np.ndarray | None:
    """The directional light's irradiance (3,) W/m² (None: no directional light of a plain RGB value)."""
    xml = setup.info.xml
    for e in xml.emitters if xml is not None else ():
        if e.kind == "directional" and e.scale_name == "irradiance" and e.scale and len(e.scale) in (1, 3):
            return np.broadcast_to(np.asarray(e.scale, np.float64), (3,)).copy()
    return None


def _scattering(mi, medium) -> tuple[np.ndarray, float] | str:
    """The medium's albedo (3,) and Henyey–Greenstein g; or why the radiance rows cannot read them."""
    params = mi.traverse(medium)
    if "albedo.value.value" not in params:
        return "its albedo is not a constant (the rows read one ϖ per channel)"
    albedo = np.broadcast_to(np.asarray(params["albedo.value.value"], np.float64).ravel(), (3,)).copy()
    if "phase_function.g" in params:
        return albedo, float(np.asarray(params["phase_function.g"]).ravel()[0])
    if "Isotropic" in str(medium.phase_function()):
        return albedo, 0.0
    return "its phase function is neither Henyey–Greenstein nor isotropic"


def _radiance_case(
    setup: AuditSetup, app: Applicability, med, dirs, t_in, t_out, cloud, s
) -> list[FamilyCase]:
    """The cloud's radiance at the camera (docs/clouds.md): volpathmis with the cloud alone against the rows
    of `RADIANCE_METHODS`, on the pixels whose ray crosses the cloud; L_bg: the same pixels without it."""
    if not setup.wants("cloud_radiance"):
        return []
    e_sun = _sun_irradiance(setup)
    read = _scattering(setup.mi, med.medium)
    crosses = np.isfinite(t_in) & (np.nan_to_num(t_out, nan=0.0) > np.nan_to_num(t_in, nan=0.0))
    if e_sun is None or isinstance(read, str) or not crosses.any() or med.on_sensor:
        return []  # no directional irradiance, an albedo or phase the rows cannot read, no pixel, or inside
    albedo, g = read
    tag = f"cloud{app.source}"
    origin = np.asarray(med.origin, np.float64)
    what = {"format": FORMAT, "medium": app.source, "rays": array_digest(origin, dirs[crosses])}
    fogged, clear = radiance_passes(setup, med, crosses, what, f"{tag}: cloud radiance")
    mask = crosses.reshape(setup.gbuffer.view_dir.shape[:2])
    reference = fogged.reference(
        mask,
        quantity="radiance at the camera with the cloud alone (W/m²/sr, RGB)",
        integrator=RADIANCE_INTEGRATOR,
        integrator_reason="unbiased for the cloud's multiple scattering (Mitsuba's volumetric path tracer)",
    )
    d = dirs[crosses]
    common = {"ox": float(origin[0]), "oy": float(origin[1]), "oz": float(origin[2]), "dx": d[:, 0],
              "dy": d[:, 1], "dz": d[:, 2], "sx": float(s[0]), "sy": float(s[1]), "sz": float(s[2]), "g": g,
              "cloud": cloud}  # fmt: skip
    channels = tuple(
        {**common, "e_sun": float(e_sun[c]), "albedo": float(albedo[c]), "l_bg": clear.mean[:, c]}
        for c in range(3)
    )
    return [
        FamilyCase(
            id=f"{tag}-radiance",
            label=f"{app.part}, the sunlit cloud's radiance at the camera",
            reference=reference,
            channel_inputs=channels,
            parameters={
                "medium": app.part,
                "albedo": albedo.tolist(),
                "g": g,
                "e_sun": e_sun.tolist(),
                "pixels": int(mask.sum()),
                "cos_sun_view_mean": float(np.mean(d @ s)),
            },
            units="W/m²/sr",
            notes=(
                f"albedo {albedo.tolist()}, HG g = {g:.3g}, E_sun = {e_sun.tolist()} W/m²; L_bg: the pixels "
                "with the cloud removed (same integrator, spp and seed)",
                "gradient-N: the seed's gradient-lit cloud (Wang 2003's artist colours: the shadow and lit "
                "sides and the base's brightness, fitted; their lerp is rtfit's reading); "
                "gradient-N-rim[-blended]: plus the seed's back-light (a glow below an alpha threshold, "
                "soft, times an HG lobe about the sun: rtfit's reading of a figure caption, all fitted); "
                "single-N-M: the sun's single scattering marched (no parameter)",
            ),
            methods=RADIANCE_METHODS,
            quantity="cloud_radiance",
        )
    ]


def cloud_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """Per gridvolume medium: the sun's transmittance to the visible points facing the sun (``-shadow``) and
    the cloud's radiance at the camera (``-radiance``; module docstring); none in a scene without a distant
    light (its rule's "needs a distant sun"): a cloud is lit by the sun, and refusing there would stop the
    audit of every other family on the scene."""
    s = _sun(setup)
    if s is None:
        return []
    med, dirs, t_in, t_out = opened_medium(setup, app, "clouds")
    cloud = _grid(setup, med.medium)
    radiance = _radiance_case(setup, app, med, dirs, t_in, t_out, cloud, s)
    if not setup.wants("cloud_transmittance"):
        return radiance
    points, normals = gbuffer_points(setup.gbuffer, setup.mask)
    facing = normals @ s > 0.0
    mask = setup.mask.copy()
    mask[setup.mask] = facing
    if not mask.any():  # the sun below every visible surface (below the horizon): no sunlight to shadow
        return radiance
    pts = points[facing]
    tag = f"cloud{app.source}"
    what = {"format": FORMAT, "quantity": "sun-transmittance", "medium": app.source,
            "rays": array_digest(pts, s)}  # fmt: skip

    def render(spp: int, seed: int):
        return sun_transmittance_pass(setup.mi, med.medium, pts, s, spp, seed)

    reference = pooled_passes(setup, what, render, (-1, 3), f"{tag}: sun transmittance").reference(
        mask,
        quantity="the sun's transmittance T through the cloud to each visible point (1, grey)",
        integrator="ratio tracking toward the sun (Mitsuba Medium.get_scattering_coefficients, the grid's "
        "own trilinear lookup)",
        integrator_reason="unbiased estimate of exp(−∫σt ds) along the sun's ray with the medium's own "
        "density",
    )
    inputs = {"px": pts[:, 0], "py": pts[:, 1], "pz": pts[:, 2], "sx": float(s[0]), "sy": float(s[1]),
              "sz": float(s[2]), "cloud": cloud}  # fmt: skip
    elevation = math.degrees(math.asin(max(-1.0, min(1.0, float(s[2])))))
    nx, ny, nz = cloud.resolution
    return [
        FamilyCase(
            id=f"{tag}-shadow",
            label=f"{app.part}, the sun's transmittance to the ground",
            reference=reference,
            channel_inputs=(inputs, inputs, inputs),
            parameters={
                "medium": app.part,
                "sun_elevation_deg": elevation,
                "grid": [nx, ny, nz],
                "box": [list(cloud.lo), list(cloud.hi)],
                "mean_height": cloud.mean_height(),
                "max_column_depth": float(cloud.columns().max()),
                "pixels": int(mask.sum()),
            },
            units="1",
            notes=(
                f"sun at {elevation:.3g}° (s = ({', '.join(f'{x:.4g}' for x in s)})); grid {nx}×{ny}×{nz} "
                f"over {cloud.lo} … {cloud.hi} m; largest column optical depth {cloud.columns().max():.3g}",
                "plane: k = 1 (a thin layer's Beer–Lambert) and h = the cloud's density-weighted mean height "
                f"{cloud.mean_height():.4g} m given; slab-N: k = 1 and the box's bottom and top; then fitted",
                "the seed prints no formula for the cloud shadows (its figures are lost): the texture rows "
                "are Beer–Lambert on the density plane, rtfit's reading (docs/clouds.md)",
            ),
            methods=METHODS,
            params=_params(cloud),
        ),
        *radiance,
    ]


FAMILY = AuditFamily(
    name="clouds",
    quantity="cloud_transmittance",
    cases=cloud_cases,
    describe=(
        "Per heterogeneous gridvolume medium lit by a distant sun: the sun's transmittance through the cloud "
        "to each visible surface facing the sun, by ratio tracking through the loaded medium, against the "
        "seed's cloud-shadow texture (the 2-D density plane projected along the sun, 000:2322-2343, "
        "002:349-387), the plane extruded to a slab with the nested march of the seed's distance clouds, and "
        "a 3-D ray march with 4–64 samples."
    ),
    quantities=("cloud_radiance",),
    formats=("mitsuba-xml",),
    rules=(
        Rule(
            "clouds",
            "cloud shadow",
            ("grid-fog", "light", "surface"),
            "{part} is a density grid over lit surfaces: a cloud that shadows the ground (needs a distant "
            "sun: a directional light or a sunsky)",
            "the sun's transmittance T through the cloud to each visible surface facing the sun (1)",
            "ratio tracking toward the sun through the scene's own medium",
            supplies=frozenset(
                {
                    "px",
                    "py",
                    "pz",
                    "sx",
                    "sy",
                    "sz",
                    "cloud",
                    "ox",
                    "oy",
                    "oz",
                    "dx",
                    "dy",
                    "dz",
                    "e_sun",
                    "albedo",
                    "g",
                    "l_bg",
                }
            ),
        ),
    ),
)


# ------------------------------------------------------------------------------------------------ study
def _steps(row: str) -> str:
    base = row.removesuffix("-fitted")
    return (
        base.split("-")[1]
        if "-" in base and base.split("-")[1].isdigit()
        else ("1 tap" if base.startswith("plane") else "—")
    )


def study(ctx: StudyContext) -> Study:
    """Cost beside error: per scene and row, RMSE over the reference's noise floor, the largest |error|, the
    texel reads per pixel (march, gradient: 8 per sample; plane: 4 per tap; single: 8 per view and sun sample)
    and the kernel's measured ns per pixel."""
    lines = ["| case | row | samples | texel reads / px | RMSE | RMSE / floor | max abs err | kernel ns/px |",
             "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    checks = []
    finest = f"march-{MARCH_STEPS[-1]}"
    for result in ctx.audits:
        for case in result.cases:
            ref = case.reference.mean[case.mask][:, 0]
            shadow = case.id.endswith("-shadow")
            for row_id, out in result.outcomes.get(case.id, {}).items():
                rmse = out.metrics["rmse"]
                ratio = rmse.value / rmse.noise_floor if rmse.noise_floor else float("nan")
                values = out.image[case.mask]
                # every row finite; a transmittance in [0, 1], a radiance ≥ 0 (float32 rounding allowed)
                upper = 1.0 + 1e-6 if shadow else np.inf
                ok = bool(np.all(np.isfinite(values)) and np.all(values >= -1e-6) and np.all(values <= upper))
                what = "finite and in [0, 1]" if shadow else "finite and ≥ 0"
                checks.append(
                    Check(name=f"{case.id} {row_id}: {what}", value=str(ok), expected="True", passed=ok)
                )
                if shadow and row_id == finest and rmse.noise_floor:
                    # converged: RMSE² = floor² + bias², so ≤ 2 floors allows a bias (the grid's trilinear
                    # read along a discrete march) of up to √3 floors (measured 0.99 floors at 60° and 30°)
                    checks.append(Check(name=f"{case.id} {finest}: the finest march converges on the ref.",
                                        value=round(ratio, 4), expected="RMSE ≤ 2 × the noise floor",
                                        passed=bool(ratio <= 2.0)))  # fmt: skip
                err = float(np.max(np.abs(out.image[case.mask][:, 0] - ref))) if ref.size else float("nan")
                steps = _steps(row_id)
                base = row_id.removesuffix("-fitted")
                parts = base.split("-")
                if base.startswith("single"):  # N view samples, each with an M-sample sun march
                    steps, reads = f"{parts[1]} × {parts[2]}", 8 * int(parts[1]) * (int(parts[2]) + 1)
                elif base.startswith(("march", "gradient")):
                    reads = 8 * int(steps)
                else:
                    reads = 4 * int(steps) if steps.isdigit() else 4
                cost = result.costs.get(out.method.id, {}).get("ns_per_pixel")
                ns = f"{cost:.3g}" if cost else "—"
                lines.append(f"| {case.id} | {row_id} | {steps} | {reads} | {rmse.value:.3g} | {ratio:.3g} | "
                             f"{err:.3g} | {ns} |")  # fmt: skip
    text = (
        "The error of each row beside what it costs: the 3-D march reads 8 texels per sample "
        f"({', '.join(str(n) for n in MARCH_STEPS)} samples), the seed's texture 4 (one bilinear tap of the "
        "density plane), the slab's nested march 4 per sample; kernel ns per pixel as measured on the "
        "scene's own inputs (Dr.Jit, this machine).\n\n" + "\n".join(lines)
    )
    return Study(
        sections=(Section("cost-steps", "Error beside cost across the march samples", text),),
        checks=tuple(checks),
    )
