r"""The ``caustics`` family in `rtfit audit` (and ``rtfit run caustics`` on its shipped scenes): the caustic
irradiance a glass or metal caster focuses onto a diffuse receiver, against the seed's photon snippets
splatted into the receiver's texture (001:887-939, 941-1606).

Role (its ``rules``): ``caustic caster`` — a smooth mirror or glass shape (``conductor``, ``dielectric``,
``thindielectric``) in a scene with a light. One case per delta light (point, spot, directional) of the
scene: ``caster<k>-light<j>``, on the visible pixels whose surface has a non-delta lobe (the receivers; the
caster's own pixels and other mirrors are left out). An area or environment light gets no case (a path
tracer from the receiver finds those caustics itself, and the seed's photons leave a point-like light); a
``plastic`` caster gets none either (its diffuse base stores the photons: no caustic).

* **reference**: the caustic irradiance at the pixels (W/m², RGB), light paths L S+ D only, by light tracing
  (`rtfit.reference.caustic_pass`: photons from the light into the caster's bounding sphere, Mitsuba's ray
  intersection and BSDF sampling in importance transport, each stored photon connected to the pinhole like
  ``ptracer``; Σ Φ/A over each pixel's footprint). Batches of `PHOTONS_PER_SAMPLE` × pixels photons are the
  samples; independent passes through the pass cache, per-pixel standard errors.
* **inputs** (one mapping per channel; `rtfit.realtime.caustics.CAUSTIC_INPUTS`): for each photon count N of
  `PHOTON_COUNTS` (its own rows ``<form>-n<N>``, ``row_inputs``) a photon set traced the same way from the
  seed's regular hit map (N = m² cells of the light's view of the caster, one photon each; independent of the
  reference's), and per pixel its `NEAREST` nearest photon hits (distance d_k, flux f_k in this channel) and
  every other photon binned into `RINGS` rings beyond them (flux g_j at RMS distance q_j).
* **rows**: `rtfit.realtime.caustics.METHODS`: the seed's constant-width Gaussian snippets (h fitted, in
  units of the caster's bounding radius), density-adaptive snippets (h = c·r₈(x), c fitted), the photon-map
  gather (no parameter), each at every N.

Energy conservation (each case's ``energy`` parameters, the study's check): where the caster is a
``dielectric`` sphere and the receiver a rectangle, the flux the N-photon set puts on the rectangle against
closed-form ray optics of the sphere on the same emitted rays (`caustic_pass.sphere_flux`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rtfit.realtime.caustics import (
    CAUSTIC_INPUTS,
    METHODS,
    NEAREST,
    NO_PHOTON,
    PHOTON_COUNTS,
    RING_RATIO,
    RINGS,
)
from rtfit.realtime.methods import Method
from rtfit.reference import caustic_pass as cp
from rtfit.reference.cache import array_digest
from rtfit.reference.estimators import device_vectors, sub_seed

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase, Precompute
from .audit_fit import length_scaled_params
from .audit_geometry import reflective_shape
from .audit_setup import AuditSetup, pooled_passes
from .records import Check, Section
from .shipped import Sizes, Study, StudyContext

__all__ = [
    "CASTERS",
    "FAMILY",
    "PHOTONS_PER_SAMPLE",
    "SCENES",
    "caustic_cases",
    "energy_balance",
    "nearest_photons",
    "photon_set",
    "study",
]

FORMAT = 1
CASTERS = frozenset({"conductor", "dielectric", "thindielectric"})
"""The BSDFs whose shapes cast caustics here (smooth: every interaction a delta)."""
PHOTONS_PER_SAMPLE = 4
"""Photons per reference sample, per compared pixel: a sample is a batch of 4 × pixels photons."""
LENGTHS = frozenset({"width"})
"""Parameters declared in units of the caster's bounding radius (multiplied by it here)."""

_sizes = Sizes(full=(32, 32, 256), quick=(24, 24, 32))
SCENES = (
    _sizes.scene(
        "caustics_sphere_sun.xml",
        "a glass ball (η 1.5) over a white floor, a directional light 30° off the vertical",
    ),
    _sizes.scene(
        "caustics_sphere_point.xml",
        "a glass ball (η 1.5) over a white floor, a point light 2.5 m away (the caustic near focus)",
    ),
)
"""The scenes ``rtfit run caustics`` audits (scenes/library/caustics_*.xml)."""


def _caster(setup: AuditSetup, app: Applicability):
    return reflective_shape(setup, app, "caustics", check_label=False)


def _bounding_sphere(mi, shape) -> tuple[np.ndarray, float]:
    """The caster's bounding sphere (centre, radius m): a sphere shape's own, else its box's."""
    box = shape.bbox()
    lo = np.array([float(box.min[i]) for i in range(3)])
    hi = np.array([float(box.max[i]) for i in range(3)])
    if shape.shape_type() == mi.ShapeType.Sphere:
        return 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo))
    return 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))


def _receivers(setup: AuditSetup) -> np.ndarray:
    """(H, W): the masked pixels whose first surface has a non-delta lobe (a receiver of photons)."""
    mi, gb = setup.mi, setup.gbuffer
    m = np.asarray(setup.sensor.world_transform().matrix, np.float64).reshape(4, 4, -1)[..., 0]
    dirs = gb.view_dir.reshape(-1, 3).astype(np.float64)
    origin = np.broadcast_to(m[:3, 3], dirs.shape)
    ray = mi.Ray3f(device_vectors(mi, mi.Point3f, origin), device_vectors(mi, mi.Vector3f, dirs))
    si = setup.scene.ray_intersect(ray)
    smooth = np.asarray(si.is_valid() & mi.has_flag(si.bsdf(ray).flags(), mi.BSDFFlags.Smooth), bool)
    return setup.mask & smooth.reshape(setup.mask.shape)


def photon_set(setup: AuditSetup, light, centre, radius: float, n: int, seed: int):
    """The rows' N-photon set: emitted from the seed's regular hit map (``stratified``), traced by
    `caustic_pass.trace_photons`; returns (origins, dirs, flux) as emitted and the `PhotonHits`."""
    far = 2.0 * _scene_size(setup)
    o, d, f = cp.emit_photons(setup.mi, light, centre, radius, n, seed, stratified=True, far=far)
    return (o, d, f), cp.trace_photons(setup.mi, setup.scene, o, d, f, seed + 1)


def _scene_size(setup: AuditSetup) -> float:
    box = setup.scene.bbox()
    return float(np.linalg.norm([float(box.max[i]) - float(box.min[i]) for i in range(3)])) + 1.0


CHUNK_ELEMENTS = 1 << 17
"""`nearest_photons` works on this many (point, photon) distances at a time (1 MiB a float64 array): its
temporaries stay in the CPU's cache. Issue 33: 256 points at a time (3.5 M distances at M ≈ 14k photons) took
0.39 s where 9 at a time took 0.24 s."""


def nearest_photons(
    points: np.ndarray, hits: cp.PhotonHits, chunk: int | None = None
) -> dict[str, np.ndarray]:
    """What each point reads of the photon set (`rtfit.realtime.caustics`): its `NEAREST` nearest hits
    ``d`` (P, K) m (`NO_PHOTON` where fewer exist) and their flux ``f`` (P, K, 3) W (0 there); every other
    photon in `RINGS` rings beyond d_K (ratio `RING_RATIO`, the last open): ring flux ``g`` (P, R, 3) W and
    flux-weighted (channels' mean) RMS distance ``q`` (P, R) m (`NO_PHOTON` for an empty ring). ``chunk``:
    points a pass (default: `CHUNK_ELEMENTS` distances a pass)."""
    p, m = len(points), len(hits.points)
    out = {"d": np.full((p, NEAREST), NO_PHOTON), "f": np.zeros((p, NEAREST, 3)),
           "g": np.zeros((p, RINGS, 3)), "q": np.full((p, RINGS), NO_PHOTON)}  # fmt: skip
    if m == 0 or p == 0:
        return out
    k = min(NEAREST, m)
    w = hits.flux.mean(axis=1)  # the rings' weights: the channels' mean flux
    # Per coordinate and per channel, contiguous (issue 33: the (C, M, 3) differences' norm and the rings'
    # (C, M, 3) flux gather, three times, were most of this function); the same operations per element in
    # the same order as np.linalg.norm's (x² + y²) + z²: the same distances.
    hx, hy, hz = (np.ascontiguousarray(hits.points[:, i]) for i in range(3))
    flux_c = [np.ascontiguousarray(hits.flux[:, c]) for c in range(3)]
    chunk = chunk or max(1, CHUNK_ELEMENTS // m)  # points a pass
    for a in range(0, p, chunk):
        b = min(p, a + chunk)
        dx, dy, dz = points[a:b, 0, None] - hx, points[a:b, 1, None] - hy, points[a:b, 2, None] - hz
        dist = np.sqrt(dx * dx + dy * dy + dz * dz)  # (C, M)
        del dx, dy, dz
        # The K nearest by a partial sort (O(M) a point), then sorted among themselves: the same K photons
        # in the same order as a full argsort's first K (up to ties at equal distances, which either takes
        # in any order). Issue 33: the full (C, M) argsort was ~85 % of this function, 4 s of the quick
        # caustics audit (M ≈ 14k photons at N = 16384).
        near = np.argpartition(dist, k - 1, axis=1)[:, :k] if m > k else np.tile(np.arange(m), (b - a, 1))
        dn = np.take_along_axis(dist, near, axis=1)
        by_distance = np.argsort(dn, axis=1)
        near, dn = np.take_along_axis(near, by_distance, axis=1), np.take_along_axis(dn, by_distance, axis=1)
        out["d"][a:b, :k], out["f"][a:b, :k] = dn, hits.flux[near]
        if m <= k:
            continue
        # Every other photon in its ring, in photon order: the K nearest go to a bin past the rings (slot
        # `size`, dropped), so no (C, M − K) gather of the far photons is made. (The sums run in photon
        # order, not distance order as before: the same values to ~10⁻¹⁵ relative.)
        edge = np.maximum(dn[:, -1:], 1e-12)
        ring = np.clip(np.floor(np.log(np.maximum(dist / edge, 1.0)) / math.log(RING_RATIO)), 0, RINGS - 1)
        slot = np.arange(b - a)[:, None] * RINGS + ring.astype(np.int64)
        size = (b - a) * RINGS
        np.put_along_axis(slot, near, size, axis=1)
        slot = slot.ravel()
        wsum, d2 = _ring_sums(slot, w, size), _ring_sums(slot, w * dist * dist, size)
        some = wsum > 0
        q = np.full(size, NO_PHOTON)
        q[some] = np.sqrt(d2[some] / wsum[some])
        out["q"][a:b] = q.reshape(-1, RINGS)
        for c in range(3):
            out["g"][a:b, :, c] = _ring_sums(slot, flux_c[c], size).reshape(-1, RINGS)
    return out


def _ring_sums(slot: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """Σ ``values`` over each of the ``size`` (point, ring) slots of `nearest_photons` (slot ``size``: the K
    nearest, dropped); ``values`` per photon (M,), the same for every point, or per (point, photon) (C, M)."""
    v = np.broadcast_to(values, (slot.size // values.shape[-1], values.shape[-1])).ravel()
    return np.bincount(slot, v, size + 1)[:size]


def _channel_inputs(reads: dict[str, np.ndarray]) -> tuple[dict, ...]:
    out = []
    for c in range(3):
        m: dict[str, Any] = {}
        for k in range(NEAREST):
            m[f"d{k + 1}"] = np.ascontiguousarray(reads["d"][:, k])
            m[f"f{k + 1}"] = np.ascontiguousarray(reads["f"][:, k, c])
        for j in range(RINGS):
            m[f"g{j + 1}"] = np.ascontiguousarray(reads["g"][:, j, c])
            m[f"q{j + 1}"] = np.ascontiguousarray(reads["q"][:, j])
        out.append(m)
    return tuple(out)


def energy_balance(setup: AuditSetup, shape, plugin: str, emitted, hits: cp.PhotonHits) -> dict | None:
    """Where the caster is a dielectric sphere and one rectangle receives: the flux (W, channels' mean) the
    traced photons put on the rectangle, its standard error (per-photon spread), and the closed-form ray
    optics' flux on it from the same emitted rays (`caustic_pass.sphere_flux`). None otherwise."""
    mi = setup.mi
    if plugin != "dielectric" or shape.shape_type() != mi.ShapeType.Sphere:
        return None
    rects = [s for s in setup.scene.shapes() if s is not shape and s.shape_type() == mi.ShapeType.Rectangle]
    if len(rects) != 1:
        return None
    params: Any = mi.traverse(shape.bsdf())
    eta = float(np.asarray(params["eta"]).ravel()[0])
    rect: Any = mi.traverse(rects[0])
    t = np.asarray(rect["to_world"].matrix, np.float64).reshape(4, 4, -1)[..., 0]
    q, hu, hv = t[:3, 3], t[:3, 0], t[:3, 1]
    centre, radius = _bounding_sphere(mi, shape)
    o, d, f = emitted
    analytic = cp.sphere_flux(o, d, f, centre, radius, eta, q, hu, hv)
    rel = hits.points - q
    n = np.cross(hu, hv)
    on = (np.abs(rel @ hu) <= hu @ hu * (1 + 1e-6)) & (np.abs(rel @ hv) <= hv @ hv * (1 + 1e-6))
    on &= np.abs(rel @ n) <= 1e-4 * float(np.linalg.norm(n)) * (1.0 + float(np.abs(q).max()))
    per = np.zeros(len(o))
    per[hits.index[on]] = hits.flux[on].mean(axis=1)
    traced = float(per.sum())
    stderr = float(np.sqrt(len(per)) * per.std(ddof=1)) if len(per) > 1 else 0.0
    return {"emitted_w": float(f.mean(axis=1).sum()), "traced_on_receiver_w": traced,
            "traced_stderr_w": stderr, "analytic_on_receiver_w": float(analytic.mean()), "eta": eta,
            "photons": len(o)}  # fmt: skip


def _rows(radius: float) -> tuple[dict[str, Method], dict]:
    return dict(METHODS), length_scaled_params(METHODS.values(), LENGTHS, radius)


def caustic_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case per delta light (module docstring)."""
    mi = setup.mi
    index, shape, plugin = _caster(setup, app)
    if plugin not in CASTERS:
        return []
    if setup.sensor.class_name() != "PerspectiveCamera":
        raise AuditError(
            f"caustics: the reference connects photons to a pinhole camera; the sensor is a "
            f"{setup.sensor.class_name()} (use a perspective sensor)"
        )
    centre, radius = _bounding_sphere(mi, shape)
    mask = _receivers(setup)
    if not mask.any():
        raise AuditError("caustics: the camera sees no diffuse receiver")
    pixels = np.flatnonzero(mask.ravel())
    points = setup.gbuffer.position[mask].astype(np.float64)
    cases = []
    for j, emitter in enumerate(setup.scene.emitters()):
        light = cp.light_of(mi, emitter, centre)
        if light is None:
            continue
        tag = f"caster{app.source}-light{j}"
        what = {"format": FORMAT, "quantity": "caustic-irradiance", "caster": index, "light": j,
                "pixels": array_digest(points), "per_sample": PHOTONS_PER_SAMPLE}  # fmt: skip
        per_sample = PHOTONS_PER_SAMPLE * len(pixels)
        far = 2.0 * _scene_size(setup)

        def render(spp: int, seed: int, light=light, per_sample=per_sample, far=far):
            return cp.caustic_pass(mi, setup.scene, setup.sensor, setup.gbuffer.view_dir, pixels, light,
                                   centre, radius, spp, per_sample, seed, far=far)  # fmt: skip

        pooled = pooled_passes(setup, what, render, (-1, 3), f"{tag}: caustic irradiance at {len(pixels)} px")
        ref = pooled.reference(
            mask,
            quantity="caustic irradiance at the visible receivers: light paths L S+ D (W/m², RGB)",
            integrator="light tracing from the delta light through the caster (Mitsuba intersection and BSDF "
            "sampling, importance transport), each stored photon connected to the pinhole (ptracer's "
            "estimator): Σ Φ/A per pixel footprint",
            integrator_reason="a delta light's caustic cannot be reached from the receiver (path tracing); "
            "light tracing is the exact counterpart of the seed's photons",
        )
        row_inputs: dict[str, tuple] = {}
        precompute: dict[str, Precompute] = {}
        energy = None
        channel_inputs: tuple = ()
        counts = {}
        for n in PHOTON_COUNTS:
            seed_n = sub_seed(setup.seed, "caustics", j, n)
            emitted, hits = photon_set(setup, light, centre, radius, n, seed_n)
            reads = nearest_photons(points, hits)
            inputs = _channel_inputs(reads)
            pre = _precompute(setup, light, centre, radius, n, seed_n, points)
            for m in METHODS.values():
                if m.fixed.get("photons") == n:
                    row_inputs[m.id] = inputs
                    precompute[m.id] = pre
            counts[n] = {
                "stored": len(hits.points),
                "median_d_nearest_m": float(np.median(reads["d"][:, -1])),
            }
            if n == max(PHOTON_COUNTS):
                energy = energy_balance(setup, shape, plugin, emitted, hits)
                channel_inputs = inputs
        methods, params = _rows(radius)
        kind = "directional" if light.position is None else "local"
        cases.append(
            FamilyCase(
                id=tag,
                label=f"{app.part}: caustic of light {j} ({kind})",
                reference=ref,
                channel_inputs=channel_inputs,
                parameters={
                    "caster": app.part,
                    "caster_bsdf": plugin,
                    "bounding_centre": [float(x) for x in centre],
                    "bounding_radius_m": radius,
                    "photon_sets": {str(k): v for k, v in counts.items()},
                    "photons_per_sample": per_sample,
                    "pixels": int(mask.sum()),
                    **({"energy": energy} if energy else {}),
                },
                units="W/m²",
                notes=(
                    f"rows at N = {', '.join(map(str, PHOTON_COUNTS))} photons (the seed's regular hit map "
                    f"of the light's view of the caster); each pixel reads its {NEAREST} nearest photons",
                    f"snippet width h in units of the caster's bounding radius {radius:.4g} m",
                    "the reference is the irradiance averaged over each pixel's footprint (ptracer's "
                    "estimator); the rows evaluate at the pixel centre",
                ),
                methods=methods,
                params=params,
                row_inputs=row_inputs,
                precompute=precompute,
            )
        )
    return cases


def _precompute(setup: AuditSetup, light, centre, radius: float, n: int, seed: int, points) -> Precompute:
    """The rows' per-frame precompute at N photons (one for the three forms): the photon set traced
    (`photon_set`) and gathered at the pixels (`nearest_photons`: what each pixel's snippet sum reads, the
    stand-in for splatting the N snippets into the receiver's atlas)."""

    def run():
        return nearest_photons(points, photon_set(setup, light, centre, radius, n, seed)[1])

    return Precompute(
        run=run,
        trigger="frame",
        what=f"{n} photons traced through the caster and gathered at the pixels (the snippets' splat)",
    )


FAMILY = AuditFamily(
    name="caustics",
    quantity="caustic_irradiance",
    cases=caustic_cases,
    describe=(
        "Per smooth glass or mirror caster and delta light (point, spot, directional): the caustic "
        "irradiance at the visible diffuse receivers (light paths L S+ D, W/m²) by light tracing through the "
        "caster with Mitsuba's intersection and BSDFs, connected to the camera like ptracer, in independent "
        "passes — against the seed's photon snippets splatted with a constant-width Gaussian (001:887-939, "
        "941-1606), density-adaptive snippets and the photon-map gather, each on "
        f"{', '.join(map(str, PHOTON_COUNTS))} photons traced from the seed's regular hit map (each pixel "
        f"reads its {NEAREST} nearest)."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "caustics",
            "caustic caster",
            ("reflective-shape", "light"),
            "{part} focuses {with_} into caustics on the diffuse surfaces: an engine splats photon hits into "
            "the receivers' texture",
            "the caustic irradiance at the visible receivers (W/m², RGB), per delta light",
            "light tracing from the light through the caster, connected to the camera (ptracer's estimator)",
            supplies=frozenset(i.name for i in CAUSTIC_INPUTS),
        ),
    ),
)


# ------------------------------------------------------------------------------------------------ study
def _energy_check(case) -> Check | None:
    e = case.parameters.get("energy")
    if not e:
        return None
    gap = e["traced_on_receiver_w"] - e["analytic_on_receiver_w"]
    tol = 4.0 * e["traced_stderr_w"] + 1e-6 * e["emitted_w"]
    return Check(
        name=f"{case.id}: energy — traced flux on the receiver = the sphere's ray optics (W)",
        value=e["traced_on_receiver_w"],
        expected=f"{e['analytic_on_receiver_w']:.5g} ± {tol:.2g} (4 s.e.)",
        passed=abs(gap) <= tol,
    )


def study(ctx: StudyContext) -> Study:
    """Cost beside error across the photon counts and filters: per case and row the RMSE over the noise
    floor, the fitted width, and the kernel's ns per pixel; the energy conservation check per case."""
    lines = [
        "| case | row | N | h or c | median d_32 (m) | RMSE / floor | rel. RMSE | kernel ns/px |",
        "|---|---|---|---|---|---|---|---|",
    ]
    checks, energy = [], []
    for result in ctx.audits:
        for case in result.cases:
            ref = case.reference.mean[case.mask]
            scale = float(np.sqrt(np.mean(ref**2))) or 1.0
            sets = case.parameters.get("photon_sets", {})
            for row_id, out in result.outcomes.get(case.id, {}).items():
                n = out.method.fixed.get("photons")
                if n is None or (out.method.params and not row_id.endswith("-fitted")):
                    continue
                rmse = out.metrics["rmse"]
                ratio = rmse.value / rmse.noise_floor if rmse.noise_floor else float("nan")
                cost = result.costs.get(out.method.id, {}).get("ns_per_pixel")
                par = f"{float(next(iter(out.parameters.values()))):.3g}" if out.parameters else "—"
                dk = sets.get(str(n), {}).get("median_d_nearest_m", float("nan"))
                ns = f"{cost:.3g}" if cost else "—"
                lines.append(f"| {case.id} | {row_id} | {n} | {par} | {dk:.3g} | {ratio:.3g} | "
                             f"{rmse.value / scale:.3g} | {ns} |")  # fmt: skip
            check = _energy_check(case)
            if check is not None:
                checks.append(check)
                e = case.parameters["energy"]
                energy.append(
                    f"| {case.id} | {e['emitted_w']:.5g} | {e['traced_on_receiver_w']:.5g} ± "
                    f"{e['traced_stderr_w']:.2g} | {e['analytic_on_receiver_w']:.5g} |"
                )
    text = (
        "Each row's error beside its photon count N (the seed's quality knob: N snippets blended into the "
        "atlas) and its fitted width (h in m for the constant snippets, c for the adaptive ones, h = c·r₈; "
        "d_32: the median distance to the 32nd nearest photon, read one by one, the rest in 40 rings); the "
        "kernel's measured ns per pixel (a sum over 32 photons and 40 rings, not the GPU's splat).\n\n"
        + "\n".join(lines)
    )
    sections = [Section("cost-photons", "Cost beside error across photon counts and filters", text)]
    if energy:
        sections.append(
            Section(
                "energy",
                "Energy conservation through the caster",
                "The flux the largest photon set puts on the receiver rectangle (Mitsuba's tracing) against "
                "closed-form ray optics of the glass sphere on the same emitted rays (reflection, TT, TRT, … "
                "to 8 internal paths; W, channels' mean):\n\n| case | emitted into the caster (W) | traced "
                "on the receiver (W) | ray optics on the receiver (W) |\n|---|---|---|---|\n"
                + "\n".join(energy),
            )
        )
    return Study(sections=tuple(sections), checks=tuple(checks))
