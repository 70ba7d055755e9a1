r"""rtfit's height-fog path tracer: closed-form free flight and transmittance (plugin ``rtfit_fogpath``).

Why an integrator. Mitsuba 3.9.1's ``Medium.sample_interaction`` and ``transmittance_eval_pdf`` are not
dispatched to Python overrides: a probe subclass overriding them (the C++ ``volpath``/``volpathmis`` loops
call the non-virtual C++ methods) saw 0 calls while ``intersect_aabb``/``get_majorant``/
``get_scattering_coefficients`` were called (docs/height-fog.md, "Closed-form free flight"). A medium
plugin can therefore only choose the majorant (`rtfit.reference.height_fog`); the free-flight distance is
always drawn as t₀ − ln(1 − u)/m̄ and thinned. This module replaces the integrator instead: a Python
``mi.SamplingIntegrator`` (compiled by Dr.Jit into one megakernel, like Mitsuba's ``prbvolpath``) that
traces the same light paths as ``volpathmis`` over the same scene, with the fog handled analytically.

Scene. The Mitsuba scene holds only the opaque surfaces and the emitters: no medium plugin and no null-BSDF
boundary shape (`scene_dict`). The fog lives in the integrator's properties (the `ExponentialFog` of
``height_fog.medium_dict``): σt(p) = b·exp(−c·h(p)), h(p) = (p − p₀)·ĝ (scene units), grey extinction,
σs = albedo·σt (RGB albedo), phase ``hg``(g) or ``isotropic``, region = the box ``to_world``·[−1, 1]³ (or its
inscribed ellipsoid). Along a ray o + t·d (|d| = 1) the height is linear, h(t) = h_a + r·(t − t_a) with
r = d·ĝ, so on a segment [t_a, t_b] of the region

    τ(t_a, t_a + s) = σ_a·s·E(k·s),   σ_a = b·e^{−c·h_a},  k = c·r,  E(x) = (1 − e^{−x})/x  (E(0) = 1).

E is evaluated as a 5-term series for |x| < 0.05 (truncation ≤ x⁵/720 < 5e-10) and in closed form above
(float32 cancellation ≤ 2⁻²⁴/0.05 ≈ 1.2e-6 relative); x → 0 (level rays, r = 0) is the linear limit τ = σ_a·s.

Free flight (closed form). A path segment from o towards the first surface at t_s has the region part
[t_a, t_b] = region ∩ [0, t_s]. Draw τ* = −ln(1 − u); if τ* ≥ τ(t_a, t_b) the segment is crossed (no
collision), else the collision is at t_a + s with τ(t_a, t_a + s) = τ*:

    s = (τ*/σ_a)·G(z),   z = k·τ*/σ_a (< 1 on this branch when k > 0),  G(z) = −ln(1 − z)/z  (G(0) = 1),

G again as a series (1 + z/2 + z²/3 + z³/4 + z⁴/5, |z| < 0.05, truncation < z⁵/6 ≈ 5e-8) or closed form.
Both are evaluated from ln σ (never under- or overflowing): τ of a segment from its densest end,
σ_max·s·E(|k|·s) with E ≤ 1, and a descending ray's inverse as ln(1 + w)/κ, w = κτ*/σ_a, κ = −k, with
ln w = ln(κτ*) − ln σ_a where σ_a leaves float32's range (regions of any number of scale heights;
`FogPath.free_flight`). This samples t with the exact density p(t) = σt(t)·T(t) and P(no collision) =
T(t_a, t_b). The path weights
are then exactly those of an analog (no-null-collision) tracker on a grey medium:

* collision: σs(t)·T(t)/p(t) = albedo (per channel), then phase sampling as ``volpathmis`` does;
* crossing: T/P(crossing) = 1.

This is the limit of ``volpathmis``'s delta tracking with the majorant m̄ = σt (σn = 0, no null collisions):
the same paths in distribution, so the same expectation; only the number of loop iterations changes.
For a non-grey (RGB-extinction) fog this would not be exact without spectral MIS over the channel's pdf;
rtfit's fog has grey extinction (RGB albedo only), which is all this integrator accepts.

Shadow rays (next-event estimation at every scattering vertex, medium and surface, MIS with the phase
function / BSDF exactly as ``volpathmis``): visibility by one ``scene.ray_test`` against the opaque
surfaces and the transmittance T = exp(−τ) in closed form — a zero-variance transmittance estimate where
``volpathmis`` used ratio tracking with null collisions.

Depth, Russian roulette, MIS and the emitter conventions follow Mitsuba's ``volpath``/``prbvolpath``:
``max_depth`` counts path segments (2: single scattering / direct light; −1: unbounded), RR after
``rr_depth`` with q = min(max(throughput), 0.95), emitters hit by a sampled direction are weighted by the
power heuristic against ``scene.pdf_emitter_direction``, directly seen emitters fully.

Bounds: each lane counts its loop iterations in a `rtfit.reference.budget.LaneCounter` (lane index in
``ray.time``, as rtfit's media do); a lane past the cap is stopped and the pass fails with one line.
"""

from __future__ import annotations

import drjit as dr
import numpy as np

from .budget import LaneCounter
from .height_fog import read_fog_properties, region_matrix

PLUGIN = "rtfit_fogpath"
ESTIMATOR = "rtfit_fogpath/3: closed-form free flight and transmittance (exponential fog, Python integrator)"
"""The estimator's identity: part of the reference cache key."""
SERIES_CUTOFF = 0.05
"""|x| below which E(x) and G(z) use their series (module docstring)."""
EXP_CLAMP = 85.0
"""Exponents of e^{−c·h} are clamped to ≤ 85 (float32 range), as in the medium plugin."""
_registered: set[str] = set()


def expm1_ratio(dr_, x):
    """E(x) = (1 − e^{−x})/x, E(0) = 1 (Dr.Jit or NumPy through ``dr_``-style ``select``/``exp``)."""
    series = 1.0 + x * (-1.0 / 2.0 + x * (1.0 / 6.0 + x * (-1.0 / 24.0 + x * (1.0 / 120.0))))
    safe = dr_.select(dr_.abs(x) < SERIES_CUTOFF, 1.0, x)
    return dr_.select(dr_.abs(x) < SERIES_CUTOFF, series, (1.0 - dr_.exp(-safe)) / safe)


def log1m_ratio(dr_, z):
    """G(z) = −ln(1 − z)/z for z < 1, G(0) = 1."""
    series = 1.0 + z * (1.0 / 2.0 + z * (1.0 / 3.0 + z * (1.0 / 4.0 + z * (1.0 / 5.0))))
    safe = dr_.select(dr_.abs(z) < SERIES_CUTOFF, 0.5, z)
    return dr_.select(dr_.abs(z) < SERIES_CUTOFF, series, -dr_.log(1.0 - safe) / safe)


def medium_vertex(mi, ray, t, p):
    """(``MediumInteraction3f``, ``Interaction3f``) of a scattering vertex at distance ``t`` along ``ray``, at
    position ``p`` (normally ray(t)): the view the phase function evaluates (incoming direction −ray.d and its
    shading frame) and the view the emitter sampler starts from (point, distance, time, wavelengths)."""
    mei = dr.zeros(mi.MediumInteraction3f)
    mei.t = t
    mei.p = p
    mei.wi = -ray.d
    mei.sh_frame = mi.Frame3f(mei.wi)
    mei.time = ray.time
    mei.wavelengths = ray.wavelengths
    it = dr.zeros(mi.Interaction3f)
    it.p = p
    it.t = t
    it.time = ray.time
    it.wavelengths = ray.wavelengths
    return mei, it


class _NumpyOps:
    """The two Dr.Jit functions the closed forms use, for float64 NumPy checks."""

    select = staticmethod(np.where)
    abs = staticmethod(np.abs)
    exp = staticmethod(np.exp)
    log = staticmethod(np.log)


NUMPY_OPS = _NumpyOps()


def integrator_dict(mi, medium, max_depth: int = -1, rr_depth: int = 5) -> dict:
    """``mi.load_dict`` entry of the integrator for a scene `ExponentialFog` (grey extinction)."""
    m = region_matrix(medium.boundary)
    return {
        "type": PLUGIN,
        "max_depth": int(max_depth),
        "rr_depth": int(rr_depth),
        "density": float(medium.density),
        "falloff": float(medium.falloff),
        "gradient": mi.ScalarVector3f(*[float(x) for x in medium.gradient]),
        "gradient_origin": mi.ScalarVector3f(*[float(x) for x in medium.gradient_origin]),
        "to_world": mi.ScalarTransform4f(m.tolist()),
        "ellipsoid": bool(medium.ellipsoid),
        "albedo": mi.ScalarVector3f(*[float(x) for x in medium.albedo]),
        "g": float(medium.g),
    }


def applies(scene, integrator: dict) -> bool:
    """Whether ``scene``'s reference (``integrator``: its Mitsuba integrator dict) is rendered by this
    integrator: one exponential fog and no other medium, under ``volpath``/``volpathmis``."""
    return (
        len(scene.media) == 1
        and scene.media[0].kind == "exponential_fog"
        and integrator.get("type") in ("volpath", "volpathmis")
    )


def scene_dict(mi, scene, base: dict, max_depth: int) -> dict:
    """``base`` (`rtfit.reference.build.mitsuba_scene_dict` of ``scene``, one exponential fog) without its
    medium, boundary shapes and sensor medium, with this integrator (``max_depth`` as the reference's)."""
    if len(scene.media) != 1 or scene.media[0].kind != "exponential_fog":
        raise ValueError("rtfit_fogpath renders scenes with exactly one exponential fog")
    d = {k: v for k, v in base.items() if not k.startswith("medium0")}
    d["sensor"] = {k: v for k, v in base["sensor"].items() if k != "medium"}
    d["integrator"] = integrator_dict(mi, scene.media[0], max_depth=max_depth)
    return d


def register(mi) -> None:
    """Register ``rtfit_fogpath`` for the active variant (once per variant)."""
    variant = mi.variant()
    if variant in _registered:
        return

    class FogPath(mi.SamplingIntegrator):
        def __init__(self, props):
            super().__init__(props)
            self.max_depth = int(props.get("max_depth", -1))
            self.rr_depth = int(props.get("rr_depth", 5))
            read_fog_properties(mi, props, self)
            self.log_b = float(np.log(self.b)) if self.b > 0.0 else -1e30
            gg = float(props.get("g", 0.0))
            self.phase = mi.load_dict({"type": "isotropic"} if gg == 0.0 else {"type": "hg", "g": gg})
            self.lane_counter = LaneCounter()

        # -------------------------------------------------------------------- fog along a ray
        def region(self, o, d, maxt):
            """[t_a, t_b] of the ray o + t·d, t ∈ [0, maxt], inside the region (t_b ≤ t_a: none)."""
            lo = self.inv_lin @ mi.Vector3f(o) + self.inv_t
            ld = self.inv_lin @ mi.Vector3f(d)
            if self.ellipsoid:
                a = dr.squared_norm(ld)
                bq = 2.0 * dr.dot(lo, ld)
                cq = dr.squared_norm(lo) - 1.0
                hit, mint, maxt_r = mi.math.solve_quadratic(a, bq, cq)
            else:
                hit, mint, maxt_r = self.unit_box.ray_intersect(mi.Ray3f(mi.Point3f(lo), ld))
            ta = dr.maximum(mint, 0.0)
            tb = dr.minimum(maxt_r, maxt)
            tb = dr.select(hit & dr.isfinite(ta), tb, 0.0)
            ta = dr.select(hit & dr.isfinite(ta), ta, 0.0)
            return ta, dr.maximum(tb, ta)

        def start(self, o, d, ta):
            """(ln σ_a, k): the log-density at o + t_a·d (ln(1/scene unit), never under- or overflows) and
            k = c·(d·ĝ) (1/scene unit)."""
            rate = dr.dot(mi.Vector3f(d), self.grad)
            h_a = dr.dot(mi.Vector3f(o), self.grad) - self.h_offset + ta * rate
            return self.log_b - self.c * h_a, self.c * rate

        @staticmethod
        def segment_depth(log_sigma_a, k, s):
            """τ over [t_a, t_a + s] from the segment's densest end: σ_max·s·E(|k|·s), E ≤ 1, so a segment
            spanning any number of scale heights neither overflows E nor underflows σ_a into 0·∞."""
            log_max = log_sigma_a + dr.maximum(-k * s, 0.0)
            sigma_max = dr.exp(dr.minimum(log_max, EXP_CLAMP))
            return dr.select(s > 0.0, sigma_max * s * expm1_ratio(dr, dr.abs(k) * s), 0.0)

        def optical_depth(self, o, d, maxt):
            """τ of the fog along o + t·d over [0, maxt] (closed form)."""
            ta, tb = self.region(o, d, maxt)
            log_sigma_a, k = self.start(o, d, ta)
            return self.segment_depth(log_sigma_a, k, tb - ta)

        def free_flight(self, o, d, maxt, u):
            """(collided, t): closed-form free-flight sample along o + t·d up to maxt (surface or inf).

            Climbing or level (k ≥ 0): s = (τ*/σ_a)·G(k·τ*/σ_a). Descending (κ = −k > 0):
            τ(s) = σ_a·(e^{κs} − 1)/κ, so s = ln(1 + w)/κ with w = κ·τ*/σ_a, evaluated as w·G(−w)/κ for
            w < 0.05, ln(1 + w)/κ above, and ln(w)/κ for ln w > 15 (relative error < 1e-7), with
            ln w = ln(κτ*) − ln σ_a: no overflow where σ_a underflows at the top of a tall region."""
            ta, tb = self.region(o, d, maxt)
            log_sigma_a, k = self.start(o, d, ta)
            s_max = tb - ta
            tau = -dr.log(1.0 - u)
            collided = tau < self.segment_depth(log_sigma_a, k, s_max)
            sigma_a = dr.exp(dr.minimum(log_sigma_a, EXP_CLAMP))
            # climbing / level
            sa = dr.select(collided & (sigma_a > 0.0), sigma_a, 1.0)
            z = dr.minimum(dr.maximum(k, 0.0) * tau / sa, 1.0 - 2.0**-23)
            s_up = tau / sa * log1m_ratio(dr, z)
            # descending
            kappa = dr.maximum(-k, 1e-30)
            lw = dr.log(dr.maximum(kappa * tau, 1e-38)) - log_sigma_a
            direct = collided & (sigma_a > 1e-30)  # w = κτ*/σ_a directly where σ_a is a normal float
            w = dr.select(direct, kappa * tau / sa, dr.exp(dr.minimum(lw, 80.0)))
            s_down = (
                dr.select(
                    lw > 15.0,
                    lw,
                    dr.select(
                        w < SERIES_CUTOFF, w * log1m_ratio(dr, -dr.minimum(w, SERIES_CUTOFF)), dr.log(1.0 + w)
                    ),
                )
                / kappa
            )
            s = dr.minimum(dr.select(k < 0.0, s_down, s_up), s_max)
            return collided, ta + s

        # -------------------------------------------------------------------- emitters
        def nee(self, scene, sampler, it, active):
            """(emitted weight incl. transmittance and visibility, ds) of one emitter sample from ``it``."""
            ds, em_w = scene.sample_emitter_direction(it, sampler.next_2d(active), False, active)
            active = active & (ds.pdf != 0.0)
            shadow = it.spawn_ray_to(ds.p)
            occluded = scene.ray_test(shadow, active)
            # an emitter at infinity is placed on the scene's bounding sphere, which need not enclose the
            # fog (a scene of fog and sun only has an empty bbox): its fog reaches to t = ∞
            far = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.Infinite)
            tr = dr.exp(-self.optical_depth(shadow.o, shadow.d, dr.select(far, dr.inf, shadow.maxt)))
            return dr.select(active & ~occluded, em_w * tr, 0.0), ds

        @staticmethod
        def mis(a, b):
            a2 = dr.square(a)
            return dr.detach(dr.select(a2 > 0.0, a2 / (a2 + dr.square(b)), 0.0))

        @dr.syntax
        def sample(self, scene, sampler, ray, medium=None, active=True):
            import mitsuba as mi

            ray = mi.Ray3f(ray)
            lane_time = mi.Float(ray.time)
            L = mi.Spectrum(0.0)
            throughput = mi.Spectrum(1.0)
            active = mi.Bool(active)
            depth = mi.UInt32(0)
            eta = mi.Float(1.0)
            valid_ray = mi.Bool(False)
            specular_chain = mi.Bool(True)
            prev = dr.zeros(mi.Interaction3f)
            prev_pdf = mi.Float(1.0)
            max_depth = mi.UInt32(0xFFFFFFFF if self.max_depth < 0 else self.max_depth)

            while active:
                active &= self.lane_counter.within(lane_time)
                active &= dr.max(throughput) != 0.0
                q = dr.minimum(dr.max(throughput) * dr.square(eta), 0.95)
                perform_rr = depth > self.rr_depth
                active &= (sampler.next_1d(active) < q) | ~perform_rr
                throughput[perform_rr & active] = throughput * dr.rcp(q)

                si = scene.ray_intersect(ray, active)
                collided, t_c = self.free_flight(ray.o, ray.d, si.t, sampler.next_1d(active))
                act_medium = active & collided
                depth[act_medium] += 1
                active &= depth < max_depth
                act_medium &= active
                act_surface = active & ~collided

                # ---------------------------------------------------------- emitter hit (escape / surface)
                emitter = si.emitter(scene)
                act_e = act_surface & (emitter != None)  # noqa: E711 (Dr.Jit pointer comparison)
                ds_e = mi.DirectionSample3f(scene, si, prev)
                em_pdf = scene.pdf_emitter_direction(prev, ds_e, act_e & ~specular_chain)
                count_direct = (depth == 0) | specular_chain
                w_e = dr.select(count_direct, 1.0, self.mis(prev_pdf, em_pdf))
                L[act_e] += throughput * emitter.eval(si, act_e) * w_e
                act_surface &= si.is_valid()

                # ---------------------------------------------------------- the scattering vertex
                mei, it_m = medium_vertex(mi, ray, t_c, ray(t_c))
                throughput[act_medium] *= self.albedo
                bsdf = si.bsdf(ray)
                ctx = mi.BSDFContext()
                pctx = mi.PhaseFunctionContext(sampler)
                nee_surface = (
                    act_surface & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth) & (depth + 1 < max_depth)
                )
                # one emitter sample and one shadow ray per lane, from its medium or surface vertex
                ref = dr.zeros(mi.Interaction3f)
                ref[act_medium] = it_m
                ref[act_surface] = si
                em, ds = self.nee(scene, sampler, ref, act_medium | nee_surface)
                ph_val, ph_pdf = self.phase.eval_pdf(pctx, mei, ds.d, act_medium)
                b_val, b_pdf = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), nee_surface)
                f_val = dr.select(act_medium, mi.Spectrum(ph_val), b_val)
                f_pdf = dr.select(act_medium, ph_pdf, b_pdf)
                w = self.mis(ds.pdf, dr.select(ds.delta, 0.0, f_pdf))
                L[act_medium | nee_surface] += throughput * f_val * w * em

                # ---------------------------------------------------------- the next direction
                u1 = sampler.next_1d(act_medium | act_surface)
                u2 = sampler.next_2d(act_medium | act_surface)
                wo, ph_w, ph_spdf = self.phase.sample(pctx, mei, u1, u2, act_medium)
                act_medium &= ph_spdf > 0.0
                throughput[act_medium] *= ph_w
                valid_ray |= act_medium
                specular_chain &= ~act_medium
                bs, b_w = bsdf.sample(ctx, si, u1, u2, act_surface)
                act_surface &= bs.pdf > 0.0
                throughput[act_surface] *= b_w
                eta[act_surface] *= bs.eta
                non_null = act_surface & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
                depth[non_null] += 1
                valid_ray |= non_null
                specular_chain |= non_null & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
                specular_chain &= ~(act_surface & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Smooth))

                # ---------------------------------------------------------- next segment
                ray[act_medium] = mei.spawn_ray(wo)
                ray[act_surface] = si.spawn_ray(si.to_world(bs.wo))
                prev[act_medium] = it_m
                prev_pdf[act_medium] = ph_spdf
                prev[non_null] = si
                prev_pdf[non_null] = bs.pdf
                active = act_medium | act_surface

            return L, valid_ray, []

        def aov_names(self):
            return []

        def to_string(self):
            return f"FogPath[b={self.b}, c={self.c}, max_depth={self.max_depth}]"

    mi.register_integrator(PLUGIN, lambda props: FogPath(props))
    _registered.add(variant)
