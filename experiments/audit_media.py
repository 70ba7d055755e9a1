r"""Shared by the audit families that read a scene's own media (height fog on Mitsuba media, aerial
perspective): which loaded Mitsuba medium an applicability names, each camera ray's first stretch inside it
(`medium_intervals`: walked as Mitsuba's volumetric path tracers walk it, `audit_fog_media`'s docstring),
its extinction at points, the scene's sun, and the radiance with that medium alone and with none.

Not a family module (it declares no `AuditFamily`): `audit_fog_media` and `audit_aerial_perspective` both
import it, never each other.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import drjit as dr
import numpy as np

from rtfit.realtime.methods import Param
from rtfit.reference.build import load_dict, mitsuba_scene_dict
from rtfit.reference.estimators import PassResult, radiance_pass
from rtfit.reference.medium_transmittance import VARIANCE_EXPONENT, variance_exponents

from .audit import Applicability, AuditError
from .audit_family import FamilyCase
from .audit_setup import AuditReference, AuditSetup, PooledPasses, pooled_passes

__all__ = [
    "MAX_SURFACES",
    "RADIANCE_INTEGRATOR",
    "TRANSMITTANCE_QUANTITY",
    "FoggedRadiance",
    "Medium",
    "MediumChannel",
    "box_interval",
    "density_params",
    "finite_stretch",
    "fogged_radiance_inputs",
    "medium_intervals",
    "medium_pointer",
    "opened_medium",
    "past_variance_target",
    "radiance_passes",
    "sigma_t_at",
    "sun_direction_of",
    "switched_off",
    "thick_rays_note",
    "transmittance_case",
    "transmittance_reference",
]

MAX_SURFACES = 32
"""Most surfaces a camera ray is walked through (null-BSDF shapes and medium boundaries)."""
RESTART = 2.0**-16
"""A walked ray restarts this far past a hit along itself, per unit of coordinate magnitude (≥ 250 float32
ulps: no hit of the same surface again; a surface closer than that behind it is skipped)."""
RADIANCE_INTEGRATOR = "volpathmis"
"""The integrator of the radiance passes: unbiased for the scene's media (all bounces)."""


@dataclass(frozen=True)
class Medium:
    """One audited medium: the loaded Mitsuba ``medium``, the Mitsuba ``scene`` whose shapes bound it, its
    pointer id in that scene's ``MediumPtr`` arrays (None: no shape refers to it), whether the camera starts
    inside it, the camera ``origin`` and the ``sensor`` the pixels are seen through."""

    medium: Any
    scene: Any
    ptr: int | None
    on_sensor: bool
    origin: np.ndarray
    sensor: Any = None
    media: tuple = ()
    """Every medium of ``scene`` (this one included): the radiance case renders this one alone."""


class MediumChannel:
    """A medium seen through one channel ``k`` of its extinction (the ratio tracker reads channel 0): the
    transmittance of that channel alone."""

    def __init__(self, medium, k: int):
        self.medium, self.k = medium, k

    def intersect_aabb(self, ray):
        return self.medium.intersect_aabb(ray)

    def get_majorant(self, mei, active=True):
        return (self.medium.get_majorant(mei, active)[self.k],)

    def get_scattering_coefficients(self, mei, active=True):
        s, n, t = self.medium.get_scattering_coefficients(mei, active)
        return s, n, (t[self.k],)


def medium_pointer(mi, scene, medium) -> int | None:
    """The id of ``medium`` in ``scene``'s ``MediumPtr`` arrays: that of the first shape holding it as its
    interior or exterior (None where no shape does)."""
    shapes = list(scene.shapes())
    for side in ("interior_medium", "exterior_medium"):
        ids = np.asarray(dr.reinterpret_array(mi.UInt32, getattr(scene.shapes_dr(), side)()))
        for k, s in enumerate(shapes):
            if getattr(s, side)() is medium:
                return int(ids[k])
    return None


def _held(scene, medium) -> bool:
    """Whether a shape of ``scene`` holds ``medium`` as its interior or exterior."""
    return any(medium is s.interior_medium() or medium is s.exterior_medium() for s in scene.shapes())


def _xml_medium(setup: AuditSetup, app: Applicability, family: str) -> Medium:
    """The loaded medium of ``app.source`` (an index of `XmlScene.media`): the sensor's, or the k-th medium
    of its plugin among the shapes' interiors and exteriors (by its ``id`` where the file names it)."""
    mi, scene, xml = setup.mi, setup.scene, setup.info.xml
    index = app.source
    if xml is None or index is None or not 0 <= index < len(xml.media):
        raise AuditError(f"{family}: {app.part} is not a medium of the scene")
    if xml.camera is None:
        raise AuditError(f"{family}: {app.part}: the scene has no camera to look through it")
    want = xml.media[index]
    origin = np.asarray(xml.camera.origin, np.float64)
    found: list = []
    sensor_medium = setup.sensor.get_medium()
    if sensor_medium is not None:
        found.append(sensor_medium)
    for s in scene.shapes():
        for m in (s.interior_medium(), s.exterior_medium()):
            if m is not None and not any(m is f for f in found):
                found.append(m)
    if want.on_sensor and sensor_medium is not None:
        obj = sensor_medium
    else:
        kind = "Homogeneous" if want.type == "homogeneous" else "Heterogeneous"
        # (the sensor's medium is not one of the shapes' unless a shape names it too)
        held = [m for m in found if m is not sensor_medium or _held(scene, m)]
        same = [m for m in held if str(m).startswith(kind)]
        named = [m for m in same if want.id and m.id() == want.id]
        rank = sum(1 for m in xml.media[:index] if m.type == want.type and not m.on_sensor)
        obj = named[0] if named else (same[rank] if rank < len(same) else None)
    if obj is None:
        raise AuditError(f"{family}: {app.part}: the loaded scene has no such medium")
    on_sensor = obj is sensor_medium
    return Medium(obj, scene, medium_pointer(mi, scene, obj), on_sensor, origin, setup.sensor, tuple(found))


def _toml_medium(setup: AuditSetup, app: Applicability, family: str) -> Medium:
    """The TOML scene's medium ``app.source`` in a Mitsuba scene of its own (the surfaces and this medium)."""
    toml, mi = setup.source, setup.mi
    index = app.source
    if toml is None or index is None or not 0 <= index < len(toml.media):
        raise AuditError(f"{family}: {app.part} is not a medium of the scene")
    scene = load_dict(mi, mitsuba_scene_dict(mi, dataclasses.replace(toml, media=(toml.media[index],))))
    obj = next((s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None), None)
    if obj is None:
        raise AuditError(f"{family}: {app.part}: its boundary shape holds no medium")
    origin = np.asarray(toml.camera.origin, np.float64)
    return Medium(obj, scene, medium_pointer(mi, scene, obj), False, origin, scene.sensors()[0], (obj,))


def medium_intervals(mi, scene, origin, dirs, ptr: int | None, on_sensor: bool) -> tuple[np.ndarray, ...]:
    """The first stretch [t_in, t_out] (scene units from ``origin``; NaN where the ray never enters, t_out
    = +inf where it leaves the scene inside) each ray from ``origin`` along unit ``dirs`` (N, 3) spends in
    the medium whose scene pointer id is ``ptr``, walked as the module docstring says (at most
    `MAX_SURFACES` surfaces; a ray still walking then ends there). A ray that runs exactly along a mesh edge
    may slip between its triangles (as Mitsuba's own rays do there: keep the camera off such symmetries)."""
    n = len(dirs)
    d64 = np.asarray(dirs, np.float64)
    inside = np.full(n, bool(on_sensor))
    t_in = np.where(inside, 0.0, np.nan)
    t_out = np.full(n, np.nan)
    done = np.zeros(n, bool)
    t_at = np.zeros(n)
    d = mi.Vector3f(d64.T.astype(np.float32))
    ray = mi.Ray3f(mi.Point3f(*[float(x) for x in origin]), d)
    null = int(mi.BSDFFlags.Null)
    scale = float(np.max(np.abs(origin)))
    for _ in range(MAX_SURFACES):
        si = scene.ray_intersect(ray, mi.Bool(~done))
        fields = (si.is_valid(), si.p, si.shape.is_medium_transition(), si.bsdf().flags(),
                  dr.reinterpret_array(mi.UInt32, si.target_medium(ray.d)))  # fmt: skip
        dr.eval(*fields)  # one launch: each conversion below would trace the rays again
        hit = np.asarray(fields[0], bool) & ~done
        t_hit = np.where(hit, np.sum((np.asarray(fields[1], np.float64).T - origin) * d64, axis=1), np.inf)
        transition = np.asarray(fields[2], bool) & hit
        only_null = (np.asarray(fields[3], np.int64) == null) & hit
        target = np.asarray(fields[4], np.int64)
        enters = transition & (ptr is not None) & (target == (ptr if ptr is not None else -1))
        miss = ~hit & ~done
        t_out = np.where(miss & inside, np.inf, t_out)
        stop = hit & ~transition & ~only_null
        leave = hit & inside & ((transition & ~enters) | stop)
        t_out = np.where(leave, t_hit, t_out)
        start = hit & ~inside & enters
        t_in = np.where(start, t_hit, t_in)
        inside = (inside | start) & ~leave
        done |= miss | leave | stop
        t_at = np.where(hit, t_hit, t_at)
        if done.all():
            break
        # the next ray starts on the camera ray itself, just past the hit: Mitsuba's spawn_ray offsets the
        # origin along the normal by ~(1 + |p|)·9e-5, off the line, which moved a grazing exit through a
        # sphere by 1.1e-4 (measured); on the line the hits are exact to float32
        start_at = t_at + RESTART * (1.0 + scale + t_at)
        ray = mi.Ray3f(mi.Point3f((origin + start_at[:, None] * d64).T.astype(np.float32)), d)
    t_out = np.where(~done & inside, t_at, t_out)  # walked MAX_SURFACES surfaces: end at the last one
    return t_in, t_out


def finite_stretch(t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """Where [t0, t1] is a finite, non-empty stretch."""
    return np.isfinite(t0) & np.isfinite(t1) & (t1 > t0)


def box_interval(to_world: np.ndarray, origin, dirs, t_in, t_out) -> tuple[np.ndarray, np.ndarray]:
    """[t_in, t_out] clipped to the box ``to_world``·[0, 1]³ (slab test in its unit frame; world units)."""
    inv = np.linalg.inv(to_world)
    o = inv[:3, :3] @ np.asarray(origin, np.float64) + inv[:3, 3]
    d = np.asarray(dirs, np.float64) @ inv[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (0.0 - o) / d, (1.0 - o) / d
    lo = np.where(d == 0.0, np.where((o >= 0) & (o <= 1), -np.inf, np.inf), np.minimum(a, b))
    hi = np.where(d == 0.0, np.where((o >= 0) & (o <= 1), np.inf, -np.inf), np.maximum(a, b))
    return np.maximum(t_in, lo.max(axis=1)), np.minimum(t_out, hi.min(axis=1))


def sigma_t_at(mi, medium, points: np.ndarray) -> np.ndarray:
    """The medium's extinction (RGB, 1/scene unit) at ``points`` (N, 3)."""
    mei = dr.zeros(mi.MediumInteraction3f, len(points))
    mei.p = mi.Point3f(np.asarray(points, np.float32).T)
    return np.asarray(medium.get_scattering_coefficients(mei)[2], np.float64).T


def sun_direction_of(setup: AuditSetup) -> np.ndarray | None:
    """The unit direction towards the scene's sun (a ``sunsky``), or None."""
    xml, toml = setup.info.xml, setup.source
    if xml is not None:
        sun = next((e.direction for e in xml.emitters if e.kind == "sunsky" and e.direction), None)
    else:
        env = toml.environment() if toml is not None and hasattr(toml, "environment") else None
        sun = getattr(env, "sun_direction", None)
    return None if sun is None else np.asarray(sun, np.float64) / np.linalg.norm(sun)


@contextlib.contextmanager
def switched_off(mi, media):
    """The ``media`` switched off (their ``scale`` 0) inside the block, then put back as they were."""
    saved = []
    try:
        for m in media:
            params = mi.traverse(m)
            saved.append((params, float(params["scale"])))
            params["scale"] = 0.0
            params.update()
        yield
    finally:
        for params, value in saved:
            params["scale"] = value
            params.update()


def opened_medium(setup: AuditSetup, app: Applicability, family: str = "height-fog"):
    """The medium ``app.source`` names (an index of `XmlScene.media`, or of a TOML scene's ``media``: that
    medium in a Mitsuba scene of its own), the pixel rays (flat, row-major) and their stretches [t_in, t_out]
    inside it (`medium_intervals`); ``family`` names the caller in its errors."""
    xml = setup.info.xml is not None
    med = _xml_medium(setup, app, family) if xml else _toml_medium(setup, app, family)
    dirs = np.asarray(setup.gbuffer.view_dir, np.float64).reshape(-1, 3)
    t_in, t_out = medium_intervals(setup.mi, med.scene, med.origin, dirs, med.ptr, med.on_sensor)
    return med, dirs, t_in, t_out


def density_params(b: float, c: float, span: float) -> dict[str, Param]:
    """Given values and fit bounds of (b, c): b within 10⁻³…10³ × its value; c within the same factors of
    a fitted falloff, or ±10/``span`` (span: the largest segment length) around c = 0 for constant fog."""
    bp = Param(b, 1e-3 * b, 1e3 * b, unit="1/scene unit", description="density b: extinction at height 0")
    width = 10.0 / max(span, 1e-12)
    cp = (
        Param(c, 1e-3 * c, 1e3 * c, unit="1/scene unit", description="falloff c: the scale height is 1/c")
        if c > 0.0
        else Param(0.0, -width, width, unit="1/scene unit", description="falloff c (0: constant fog)")
    )
    return {"b": bp, "c": cp}


def radiance_passes(setup: AuditSetup, med: Medium, ok: np.ndarray, what: dict, tag: str):
    """(fogged, clear): the radiance at the camera on the pixels ``ok`` (flat, row-major) with this medium
    alone (the scene's other media switched off) and with every medium switched off (the fog-free image L₀),
    each path traced with `RADIANCE_INTEGRATOR` through ``med.sensor`` in passes through the pass cache
    (`pooled_passes`; ``what``: the caller's part of the key, to which the quantity is added). The same
    ``what`` gives the same passes to every family that asks (rendered once)."""
    mi = setup.mi
    integrator = mi.load_dict({"type": RADIANCE_INTEGRATOR})
    others = tuple(m for m in med.media if m is not med.medium)

    def passes(off, quantity: str, label: str):
        def render(spp: int, seed: int):
            with switched_off(mi, off):
                r = radiance_pass(mi, med.scene, spp, seed, integrator=integrator, sensor=med.sensor)
            return PassResult(r.mean.reshape(-1, 3)[ok], r.var.reshape(-1, 3)[ok], r.spp, r.seed, r.seconds)

        return pooled_passes(setup, {**what, "quantity": quantity}, render, (-1, 3), label)

    fogged = passes(others, "medium-radiance-alone", f"{tag}: radiance with the medium")
    clear = passes(med.media, "medium-radiance-clear", f"{tag}: fog-free radiance L0")
    return fogged, clear


class FoggedRadiance(NamedTuple):
    """`fogged_radiance_inputs`: the case's ``reference``, its rows' ``inputs``, the cache key of the
    fog-free image L₀ and the ``sun`` direction (None: no sun; ``cos_sun`` is then 0)."""

    reference: AuditReference
    inputs: dict
    l0_cache_key: str
    sun: np.ndarray | None


FOGGED_RADIANCE_QUANTITY = "radiance at the camera with this medium alone (W/m²/sr, RGB)"
"""The words of a fog family's fogged-radiance reference (`fogged_radiance_inputs`)."""


def fogged_radiance_inputs(
    setup: AuditSetup,
    med,
    ok,
    mask,
    common: dict,
    what: dict,
    tag: str,
    quantity: str = FOGGED_RADIANCE_QUANTITY,
) -> FoggedRadiance:
    """The reference of a fogged-radiance case and its rows' inputs: the radiance at the camera with this
    medium alone (`radiance_passes`: the scene's other media switched off), path traced with
    `RADIANCE_INTEGRATOR` through the run's sensor, as an `AuditReference` on ``mask`` (its ``quantity`` in
    the report's words); and ``common`` (the rays' inputs, with ``dx``, ``dy``, ``dz``) with ``cos_sun``
    (each ray's direction · the sun's; 0 without a sun) and the fog-free image L₀ (``l0_r``, ``l0_g``,
    ``l0_b``: every medium switched off, same integrator, spp and seed)."""
    fogged, clear = radiance_passes(setup, med, ok, what, tag)
    sun = sun_direction_of(setup)
    d = np.stack([common["dx"], common["dy"], common["dz"]], axis=1)
    inputs = {
        **common,
        "cos_sun": d @ sun if sun is not None else np.zeros(len(d)),
        **{f"l0_{ch}": clear.mean[:, k] for k, ch in enumerate("rgb")},
    }
    ref = fogged.reference(
        mask,
        quantity=quantity,
        integrator=RADIANCE_INTEGRATOR,
        integrator_reason="unbiased for the scene's media (Mitsuba's volumetric path tracer, all bounces)",
        extra_seconds=clear.seconds,
    )
    return FoggedRadiance(ref, inputs, clear.entry.key, sun)


TRANSMITTANCE_QUANTITY = "transmittance T of the medium along the camera's rays (1, grey)"
"""The words of a fog family's transmittance reference (`transmittance_reference`)."""


def transmittance_reference(
    pooled: PooledPasses, mask: np.ndarray, integrator: str, unchecked: np.ndarray | None = None
) -> AuditReference:
    """A fog family's transmittance reference on the camera rays of ``mask``: the ratio tracker's ``pooled``
    passes (`audit_setup.PooledPasses.reference`), ``integrator`` the tracker's words; ``unchecked``: per ray,
    True where the tracker ran past its variance target (`thick_rays_note`)."""
    return pooled.reference(
        mask,
        quantity=TRANSMITTANCE_QUANTITY,
        integrator=integrator,
        integrator_reason="unbiased estimate of exp(−∫σt ds) with the medium plugin's own density",
        unchecked=unchecked,
    )


def past_variance_target(mi, tracked, origin, dirs, far, near) -> np.ndarray:
    """Per ray (`transmittance_pass`'s arguments), True where the ratio tracker runs past its variance target
    (`rtfit.reference.medium_transmittance.variance_exponents`): the rays a transmittance reference's
    ``unchecked`` names (`transmittance_reference`, `thick_rays_note`)."""
    bound = variance_exponents(mi, tracked, origin, dirs, far, min_distance=near)
    return bound > VARIANCE_EXPONENT * (1.0 + 1e-6)


def thick_rays_note(thick: int, rays: int) -> str:
    """The case note of a transmittance reference with ``thick`` of its ``rays`` past the ratio tracker's
    variance target (`rtfit.reference.medium_transmittance.variance_exponents`)."""
    return (
        f"{thick} of {rays} rays cross more than 16 of the medium's majorant optical depths (m·L; in a "
        "homogeneous medium T < 1.2e-7): there the ratio tracker, at its cost cap, runs past its variance "
        "target, its weights are heavy-tailed and a pass's sample variance does not measure its error, so "
        "the exact row's z-checks leave those rays out (they are compared and shown as the others)"
    )


def transmittance_case(
    tag: str,
    label: str,
    reference: AuditReference,
    common: Mapping[str, Any],
    parameters: Mapping[str, Any],
    **rows: Any,
) -> FamilyCase:
    """A fog family's transmittance case of one medium (`transmittance_reference`) on the pixels its
    ``reference`` was made for: id ``<tag>-transmittance``, label ``<label>, transmittance``, the per-pixel
    inputs ``common`` for the three channels (T is grey), ``parameters`` with its quantity, units 1, quantity
    ``fog_transmittance``; ``rows``: the case's ``notes``, ``methods`` and ``params`` (`FamilyCase`). Where
    the reference leaves rays out of the checks (``unchecked``), the notes count them (`thick_rays_note`)."""
    notes = tuple(rows.pop("notes", ()))
    flags = reference.unchecked
    if flags is not None and flags.any():
        rays = int(reference.mask.sum()) if reference.mask is not None else int(flags.size)
        notes = (*notes, thick_rays_note(int(flags.sum()), rays))
    return FamilyCase(
        id=f"{tag}-transmittance",
        label=f"{label}, transmittance",
        reference=reference,
        channel_inputs=(common, common, common),
        parameters={**parameters, "quantity": "transmittance"},
        units="1",
        quantity="fog_transmittance",
        notes=notes,
        **rows,
    )
