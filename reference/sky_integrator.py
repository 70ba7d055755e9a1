r"""rtfit's atmosphere path tracer (plugin ``rtfit_skypath``): tangent-exponential majorants with closed-form
free flight, spectral-MIS delta tracking, Poisson-corrected marched sun transmittance.

Why an integrator. Mitsuba 3.9.1 does not dispatch Python overrides of ``Medium.sample_interaction``
(`rtfit.reference.fog_integrator`), so inside ``volpathmis`` a Python medium can only choose one constant
majorant per tracking segment (session 4's per-segment majorant). This integrator traces the paths of
``volpathmis`` over the sky scene (planet + sun, `rtfit.reference.nishita_sky`) with the atmosphere held in
its own properties: no medium plugin and no null-BSDF shell sphere.

Atmosphere (km, km⁻¹; `rtfit.reference.nishita_sky`): with h(p) = |p| − R_g, ρ_R = e^{−max(h,0)/H_R},
ρ_M = e^{−max(h,0)/H_M}, per RGB channel c

    σ_t,c = β_R,c ρ_R + β_M^ext ρ_M,   σ_s,c = β_R,c ρ_R + β_M ρ_M,

inside the top sphere |p| < R_t (nothing above it). A scattering event scatters with the per-channel
mixture p_c = (β_R,c ρ_R P_R + β_M ρ_M P_M)/σ_s,c, P_R Rayleigh, P_M Henyey–Greenstein g: the phase plugin
``rtfit_rayleigh_mie`` of `rtfit.reference.nishita_sky` (exact per-channel value, sampled from the
channel-averaged mixture with that mixture's pdf), given to the integrator as its child ``phase``.

**Majorant (exact bound, closed-form free flight).** Along a ray p + s·d (|d| = 1) the altitude
h(s) = |p + s d| − R_g is convex in s, so it lies above its tangent at s = 0 on the whole line:
h(s) ≥ ℓ(s) = h(0) + h'(0)·s, h'(0) = p·d/|p|. Lowered by δ = 2⁻¹⁸(1 + |p| + s) km against float32
rounding (`MARGIN`, the per-segment majorant's δ of session 4), ℓ stays linear in s, and

    μ̄_X(s) = β̂_X exp(−ℓ(s)/H_X) ≥ β̂_X ρ_X(s) for every s ≥ 0,  X ∈ {R, M},  β̂_R = max_c β_R,c,  β̂_M = β_M^ext,

is a grey exponential in s: its optical depth has the closed form σ̂₀(1 − e^{−ks})/k (σ̂₀ = β̂ e^{−ℓ(0)/H},
k = ℓ'/H), so a candidate distance is drawn exactly by inversion, s = (τ*/σ̂₀)·G(kτ*/σ̂₀), τ* = −ln(1 − u),
G(z) = −ln(1 − z)/z (`rtfit.reference.fog_integrator.log1m_ratio`; no candidate when kτ*/σ̂₀ ≥ 1). The two
components are two independent Poisson processes of candidates; their superposition has rate
μ̄ = μ̄_R + μ̄_M and its first point is the smaller of the two draws. After every candidate (null or real)
the tracker restarts at the candidate with a new tangent (a majorant chosen from the path's past: exact,
as session 4's restarted segment majorant). The free flight uses the majorant × `FREE_FLIGHT_SCALE` (1.5:
less spectral-MIS variance), the Poisson-corrected marching none. The tangent error is second order,
h'' s²/2 with h'' ≤ 1/|p| ≈ 1/6400 km⁻¹: a candidate 30 km away (a blue mean free path at the ground)
overestimates ρ_R by 0.1 % and ρ_M by 6 %. At a candidate, σ_t,c/μ̄ ≤ 1 for every channel.

**Chromatic Rayleigh: spectral MIS (balance heuristic over the three channels).** The candidate process
is grey (β̂_R is the largest channel's), so every channel sees the same candidates, with null coefficient
μ̄ − σ_t,c ≥ 0. A path picks a hero channel k₀ uniformly and decides each candidate as k₀'s own delta
tracker would (null-scattering path integral, Miller et al. 2019): real with probability σ_t,k₀/μ̄. With
p_k the path pdf of technique k (hero k) and f_c the path contribution, the balance-heuristic one-sample
MIS estimator is F_c = f_c/((1/3)Σ_k p_k). The majorant's density and transmittance factors μ̄ e^{−∫μ̄}
are common to f and every p_k and cancel; per candidate the remaining factors (in units of μ̄) are

* null:  f_c ∝ v_c = 1 − σ_t,c/μ̄,  p_k ∝ v_k;
* real:  f_c ∝ σ_s,c/μ̄ (then the phase mixture p_c),  p_k ∝ v_k = σ_t,k/μ̄.

The integrator keeps w_k = p_k/mean_j p_j (mean 1) and the throughput F = f/mean_j p_j: at a candidate,
w ← w⊙v/mean(w⊙v) and F ← F⊙f/mean(w⊙v). Every weight is bounded (F_c ≤ 3·f_c/p_c), and there is no
division by a vanishing null probability (the hero's own factor cancels from the update). Phase sampling,
emitter sampling and Russian roulette are the same for the three techniques, so they multiply F as usual.

**Sun transmittance (next-event estimation): Poisson-corrected marching** (``sun_transmittance="march"``,
the default), after one ``scene.ray_test`` for the planet. τ_c = β_R,c X_R + β_M^ext X_M with X = ∫ρ ds
over the shell part of the sun ray. An unbiased estimate τ̂ of τ: the ray is cut at its closest approach
t* = clamp(−o·d, t_a, t_b) into two legs along which the altitude rises away from t*; on each leg and for
each component, `MARCH_NODES` stratified samples (one random shift) of the exponential of rate
κ = max(h'(t*), √(H/r*))/H truncated to the leg (√(rH) is the width of the density around a tangent point),
X̂ = mean ρ/pdf. Then, with ĉ one such estimate and τ̂₁, τ̂₂, … independent ones,

    T̂_c = exp(−ĉ_c) · Π_{i=1}^{K} (1 − (τ̂_i,c − ĉ_c)/λ),   K ~ Poisson(λ),

is unbiased: E[Π | ĉ] = Σ_k e^{−λ} λ^k/k! (1 − (τ_c − ĉ_c)/λ)^k = exp(−(τ_c − ĉ_c)) (the Poisson estimator of
exp(−x); Papaspiliopoulos 2011, as in Kettunen et al. 2021's unbiased ray marching), for any λ > 0 chosen
from ĉ alone: λ = max(0.1, 0.1·max_c ĉ_c) (`POISSON_MEAN`, `POISSON_SCALE`), at least the spread of τ̂
(3–10 % of τ on grazing sun rays), so the factors stay O(1). A sun ray at sun 10° costs ≈ 1.15 estimates
(16 density samples each): a fixed amount of work with no per-lane tracking loop, and a variance far below
the path's (measured on the quick sky at sun 10° and 2°: the per-sample variance of blue single
scattering 0.0035 and 0.0011, ratio tracking ×3: 0.0038 and 0.0013; with 2 nodes instead of 4 the grazing
rays of sun 2° raise blue's to 0.0035, with 1 node and λ fixed at 0.1 to 6.7). T̂ may be negative (rarely);
only its mean matters. Alternative (``"ratio"``): ratio tracking with the same
majorants ×`RATIO_TRACKING_SCALE`, T̂_c = Π_candidates (1 − σ_t,c/μ̄), unbiased (Cramer 1978/Novák et al.
2014), with a per-lane tracking loop (the variances above).
NEE is the only estimator of the sun's disc at a scattering vertex (medium or ground); a direction
sampled by the phase function or BSDF counts an emitter it hits only where the emitter cannot be
sampled (``pdf_emitter_direction`` = 0: nothing for rtfit's sun with zero sky), so the two are
complementary and need no MIS weights. A camera ray counts the directly seen disc with its tracked
weight F. With ``nee_only`` (the sky scene: the sun's ``sky`` radiance is 0, so every direction of nonzero
emitted radiance can be sampled by NEE) a sampled direction can never add anything, and a path ends at its
last vertex that still receives NEE (single scattering: at the scattering vertex, without tracing the
continuation ray that ``volpath`` traces only to look for emitter hits).

Depth, Russian roulette and the emitter conventions follow ``volpath``/`rtfit.reference.fog_integrator`:
``max_depth`` counts path segments (2: single scattering, −1: all orders), RR after ``rr_depth`` with
q = min(max F, 0.95).

Bounds: the path loop, the free-flight loop and the Poisson-correction (or ratio-tracking) loop each count
their iterations per lane in one `rtfit.reference.budget.LaneCounter` (lane index in ``ray.time``); a lane
past the cap stops and the pass fails with one line.
"""

from __future__ import annotations

import drjit as dr

from .budget import LaneCounter
from .fog_integrator import log1m_ratio, medium_vertex

PLUGIN = "rtfit_skypath"
ESTIMATOR = (
    "rtfit_skypath/2: tangent-exponential majorants, spectral-MIS delta tracking, "
    "Poisson-corrected marched sun transmittance (Python integrator)"
)
"""The estimator's identity: part of the reference cache key."""
MARGIN = 2.0**-18
"""δ per km of |p| + s subtracted from the tangent altitude (float32 rounding of |p| near 6400 km)."""
GROUND_LIFT = 2.0**-10
"""km: scattering vertices are kept at least this far above the ground sphere (`above_ground`)."""
FREE_FLIGHT_SCALE = 1.5
"""The free flight's candidates come at this multiple of the tangent majorant (still a bound: exact): the
channels' null factors 1 − σ_t,c/μ̄ then differ less, so the spectral-MIS weights spread less. Measured on
the quick sky at sun 10° (4 interleaved passes, load ≈ 1): × 1.5 cuts the per-sample variance of red /
green by 20 / 11 % (single) and 22 / 17 % (all orders) for 4–6 % more time; × 2 gains no more."""
RATIO_TRACKING_SCALE = 3.0
"""``sun_transmittance="ratio"``: the ratio tracker's candidates come at this multiple of the majorant (more,
smaller factors, lower variance; measured on the quick sky at sun 10°: × 3 cuts the blue variance of single
scattering by 40 % for 11 % more time; the free flight keeps × 1)."""
MARCH_NODES = 4
"""Stratified samples per leg and component of one optical-depth estimate (`marched_transmittance`)."""
BELOW_ONE = 1.0 - 2.0**-24
"""The largest float32 below 1: a stratified fraction (j + ξ)/N is capped there (`leg_depth`)."""
POISSON_MEAN = 0.1
POISSON_SCALE = 0.1
"""λ = max(`POISSON_MEAN`, `POISSON_SCALE`·max_c ĉ_c) of the Poisson-corrected transmittance: the expected
number of extra optical-depth estimates, at least the measured spread of τ̂ (relative std 3–10 % on grazing
sun rays with `MARCH_NODES` = 4, 2.5 % at sun 10°), so the correction factors 1 − (τ̂ − ĉ)/λ stay O(1)."""
SUN_TRANSMITTANCE = ("march", "ratio")
"""The NEE transmittance estimators: Poisson-corrected marching (default) or ratio tracking."""
_registered: set[str] = set()


def integrator_dict(
    profile: dict,
    top_radius_km: float,
    max_depth: int,
    phase: dict,
    nee_only: bool = False,
    sun_transmittance: str = "march",
    rr_depth: int = 5,
) -> dict:
    """``mi.load_dict`` entry of the integrator: ``profile`` is the atmosphere's property dict
    (`rtfit.reference.nishita_sky` ``_profile_props``: planet_radius, rayleigh_height, mie_height,
    rayleigh_beta, mie_beta, mie_extinction, g; km and km⁻¹), ``phase`` the dict of its per-channel
    Rayleigh + Mie phase mixture (``rtfit_rayleigh_mie``). ``nee_only``: the scene's emitters are
    entirely sampled by NEE (every direction of nonzero radiance has ``pdf_emitter_direction`` > 0, as
    rtfit's sun disc with zero sky), so a path ends at its last vertex that can still receive NEE (with
    ``max_depth`` 2: at the scattering vertex; the continuation could only hit an emitter, which counts
    nothing: module docstring). ``sun_transmittance``: one of `SUN_TRANSMITTANCE`."""
    return {
        "type": PLUGIN,
        "sun_transmittance": str(sun_transmittance),
        "max_depth": int(max_depth),
        "rr_depth": int(rr_depth),
        "nee_only": bool(nee_only),
        "top_radius": float(top_radius_km),
        **profile,
        "phase": phase,
    }


def register(mi) -> None:
    """Register ``rtfit_skypath`` for the active variant (RGB variants only; once per variant)."""
    variant = mi.variant()
    if variant in _registered:
        return
    if mi.is_spectral:
        raise ValueError(f"{PLUGIN} renders RGB variants only (got {variant!r})")

    def _vec(props, name):
        v = props.get(name)
        return [float(v[0]), float(v[1]), float(v[2])]

    class SkyPath(mi.SamplingIntegrator):
        def __init__(self, props):
            super().__init__(props)
            self.max_depth = int(props.get("max_depth", -1))
            self.rr_depth = int(props.get("rr_depth", 5))
            self.nee_only = bool(props.get("nee_only", False))
            self.free_flight_scale = float(props.get("free_flight_scale", FREE_FLIGHT_SCALE))
            self.sun_transmittance = str(props.get("sun_transmittance", "march"))
            if self.sun_transmittance not in SUN_TRANSMITTANCE:
                raise ValueError(f"{PLUGIN}: sun_transmittance must be one of {SUN_TRANSMITTANCE}")
            self.rg = float(props.get("planet_radius"))
            self.rt = float(props.get("top_radius"))
            self.hr = float(props.get("rayleigh_height"))
            self.hm = float(props.get("mie_height"))
            br = _vec(props, "rayleigh_beta")
            bm = _vec(props, "mie_beta")
            bme = _vec(props, "mie_extinction")
            if not (bm[0] == bm[1] == bm[2] and bme[0] == bme[1] == bme[2]):
                raise ValueError(f"{PLUGIN}: Mie coefficients must be grey (got {bm}, {bme})")
            if not (0.0 < self.rg < self.rt) or min(br) <= 0.0 or bme[0] <= 0.0:
                raise ValueError(f"{PLUGIN}: need 0 < planet_radius < top_radius and β_R, β_M^ext > 0")
            self.br_max = max(br)
            self.br = mi.Color3f(*br)
            self.bm = bm[0]
            self.bme = bme[0]
            self.g = float(props.get("g"))  # the Mie asymmetry: the phase's (read to mark it used)
            self.phase = props.get("phase")  # the per-channel Rayleigh + Mie mixture (module docstring)
            self.lane_counter = LaneCounter()

        # ------------------------------------------------------------------ geometry and majorants
        def shell(self, o, d, maxt):
            """[t_a, t_b]: the part of o + t·d (|d| = 1), t ∈ [0, maxt], inside the top sphere."""
            r = dr.norm(o)
            b = dr.dot(o, d)
            c = (r - self.rt) * (r + self.rt)
            hit, t0, t1 = mi.math.solve_quadratic(1.0, 2.0 * b, c)
            ta = dr.maximum(t0, 0.0)
            tb = dr.minimum(t1, maxt)
            ok = hit & (tb > ta)
            return dr.select(ok, ta, 0.0), dr.select(ok, tb, 0.0)

        def tangent(self, p, d):
            """(ℓ(0), ℓ'): the lowered tangent altitude ℓ(s) = ℓ(0) + ℓ'·s ≤ h(p + s d) (km)."""
            r = dr.norm(p)
            return r - self.rg - MARGIN * (1.0 + r), dr.dot(p, d) / r - MARGIN

        @staticmethod
        def flight(l0, slope, height, beta_hat, tau):
            """Closed-form candidate distance of the process of rate β̂·exp(−(l0 + slope·s)/height):
            (τ*/σ̂₀)·G(kτ*/σ̂₀), +inf when the process has no further point (kτ*/σ̂₀ ≥ 1)."""
            x = tau * dr.exp(dr.minimum(l0 / height, 80.0)) / beta_hat  # τ*/σ̂₀
            z = (slope / height) * x
            s = x * log1m_ratio(dr, dr.minimum(z, 0.5))
            s = dr.select(z < 0.5, s, -dr.log(dr.maximum(1.0 - z, 1e-30)) * (height / slope))
            return dr.select(z < 1.0, s, dr.inf)

        def candidate(self, o, d, t, tb, sampler, active, scale=1.0):
            """The next candidate after o + t·d before t_b: (found, t_new, ρ_R/μ̄, ρ_M/μ̄) with μ̄ =
            μ̄_R + μ̄_M the majorant there (km⁻¹; module docstring)."""
            p = o + t * d
            l0, slope = self.tangent(p, d)
            s_r = self.flight(l0, slope, self.hr, scale * self.br_max, -dr.log(1.0 - sampler.next_1d(active)))
            s_m = self.flight(l0, slope, self.hm, scale * self.bme, -dr.log(1.0 - sampler.next_1d(active)))
            s = dr.minimum(s_r, s_m)
            found = active & (s < tb - t)
            s = dr.select(found, s, 0.0)
            h = dr.maximum(dr.norm(p + s * d) - self.rg, 0.0)
            ell = l0 + slope * s
            mu = self.br_max * dr.exp(dr.minimum(-ell / self.hr, 80.0))
            mu += self.bme * dr.exp(dr.minimum(-ell / self.hm, 80.0))
            inv = dr.rcp(dr.maximum(scale * mu, 1e-30))
            return found, t + s, dr.exp(-h / self.hr) * inv, dr.exp(-h / self.hm) * inv

        def coefficients(self, rr, rm):
            """(σ_t/μ̄, σ_s/μ̄) per channel at a candidate from `candidate`'s ρ/μ̄ (σ_t/μ̄ ≤ 1)."""
            sigma_t = dr.minimum(self.br * rr + self.bme * rm, 1.0)
            return sigma_t, self.br * rr + self.bm * rm

        def above_ground(self, p):
            """``p`` moved radially to at least R_g + `GROUND_LIFT`. A collision before the ground hit is
            above the ground in exact arithmetic, but its float32 position can fall inside the planet sphere,
            and a ray spawned there would hit the sphere's far side from inside and track through the planet,
            where the tangent majorant grows without bound (a lane stuck at sub-ulp steps: found by the lane
            cap on a twilight all-orders reference). The move is ≤ 1 m, on points within float32 rounding of
            the ground."""
            r = dr.norm(p)
            return p * dr.maximum(1.0, (self.rg + GROUND_LIFT) / dr.maximum(r, 1e-30))

        # ------------------------------------------------------------------ tracking
        @dr.syntax
        def free_flight(self, o, d, maxt, hero, F, w, sampler, lane_time, active):
            """Spectral-MIS delta tracking along o + t·d up to maxt: (collided, t, F, w)."""
            import mitsuba as mi  # dr.syntax re-executes the function without its closure

            ta, tb = self.shell(o, d, maxt)
            t = mi.Float(ta)
            collided = mi.Bool(False)
            go = mi.Bool(active) & (tb > ta)
            while go:
                go &= self.lane_counter.within(lane_time)
                found, t_new, rr, rm = self.candidate(o, d, t, tb, sampler, go, self.free_flight_scale)
                sigma_t, sigma_s = self.coefficients(rr, rm)
                p_real = dr.select(hero == 0, sigma_t.x, dr.select(hero == 1, sigma_t.y, sigma_t.z))
                real = found & (sampler.next_1d(found) < p_real)
                v = dr.select(real, sigma_t, 1.0 - sigma_t)  # p_k factors (units of μ̄)
                fv = dr.select(real, sigma_s, 1.0 - sigma_t)  # f_c factors
                wv = w * v
                norm = dr.maximum(dr.mean(wv), 1e-30)
                F[found] = F * fv / norm
                w[found] = wv / norm
                t[found] = t_new
                collided |= real
                go &= found & ~real
            return collided, t, F, w

        @dr.syntax
        def ratio_tracking(self, o, d, maxt, sampler, lane_time, active):
            """Unbiased per-channel transmittance along o + t·d over [0, maxt] (module docstring)."""
            import mitsuba as mi  # dr.syntax re-executes the function without its closure

            ta, tb = self.shell(o, d, maxt)
            t = mi.Float(ta)
            tr = mi.Spectrum(1.0)
            go = mi.Bool(active) & (tb > ta)
            while go:
                go &= self.lane_counter.within(lane_time)
                found, t_new, rr, rm = self.candidate(o, d, t, tb, sampler, go, RATIO_TRACKING_SCALE)
                tr[found] = tr * (1.0 - self.coefficients(rr, rm)[0])
                t[found] = t_new
                go &= found & (dr.max(tr) > 0.0)
            return dr.select(active, tr, 0.0)

        # ------------------------------------------------------------------ Poisson-corrected marching
        def leg_depth(self, q0, d, length, height, beta, sampler, active):
            """β·∫₀^length ρ(h(q0 + u·d)) du by `MARCH_NODES` stratified samples (one random shift) of the
            truncated exponential of rate κ = max(h'(q0), √(H/|q0|))/H: an unbiased estimate."""
            r0 = dr.norm(q0)
            kappa = dr.maximum(dr.dot(q0, d) / r0, dr.sqrt(height / r0)) / height
            x = kappa * length
            mass = dr.select(x < 1e-2, x * (1.0 - x * (0.5 - x / 6.0)), 1.0 - dr.exp(-x))  # 1 − e^{−κL}
            xi = sampler.next_1d(active)
            acc = mi.Float(0.0)
            for j in range(MARCH_NODES):
                # (j + ξ)/N rounds to 1 in float32 for the last node when ξ ≥ 1 − 2⁻²³ (3 + ξ → 4.0); with
                # mass = 1 (κL ≳ 17) that put the node at u = ∞, pdf = 0: 0/0 = NaN in one sample of ~10⁷
                # (the H200's first all-orders sky run; LLVM reproduces it). Capped at the largest float32
                # below 1: u ≤ 16.6/κ stays finite, only ξ within 2⁻²³ of 1 moves (within its own stratum's
                # tail), and no other node changes.
                wj = dr.minimum((j + xi) / MARCH_NODES, BELOW_ONE) * mass
                u = -dr.log(1.0 - wj) / kappa
                pdf = kappa * (1.0 - wj) / mass  # κ e^{−κu}/(1 − e^{−κL})
                h = dr.maximum(dr.norm(q0 + u * d) - self.rg, 0.0)
                acc += dr.exp(-h / height) / pdf
            return dr.select(active & (length > 0.0), beta * acc / MARCH_NODES, 0.0)

        def depth_estimate(self, o, d, ta, tb, sampler, active):
            """An unbiased estimate of τ_c over [t_a, t_b] of o + t·d (Spectrum): the two legs on either side
            of the closest approach t* = clamp(−o·d, t_a, t_b), each from its low end."""
            t_star = dr.clip(-dr.dot(o, d), ta, tb)
            q0 = o + t_star * d
            tau = mi.Spectrum(0.0)
            for sign, length in ((1.0, tb - t_star), (-1.0, t_star - ta)):
                dd = sign * d
                xr = self.leg_depth(q0, dd, length, self.hr, 1.0, sampler, active)
                xm = self.leg_depth(q0, dd, length, self.hm, self.bme, sampler, active)
                tau += self.br * xr + xm
            return tau

        @dr.syntax
        def marched_transmittance(self, o, d, maxt, sampler, lane_time, active):
            """exp(−ĉ)·Π_{i≤K}(1 − (τ̂_i − ĉ)/λ), K ~ Poisson(λ): unbiased (module docstring)."""
            import mitsuba as mi  # dr.syntax re-executes the function without its closure

            ta, tb = self.shell(o, d, maxt)
            go = mi.Bool(active) & (tb > ta)
            c = self.depth_estimate(o, d, ta, tb, sampler, go)
            lam = dr.maximum(POISSON_MEAN, POISSON_SCALE * dr.max(c))  # λ(ĉ): a function of ĉ only
            prod = mi.Spectrum(1.0)
            u = sampler.next_1d(go)
            term = mi.Float(dr.exp(-lam))
            cdf = mi.Float(term)
            k = mi.UInt32(0)
            go &= u > cdf
            while go:
                go &= self.lane_counter.within(lane_time)
                tau_i = self.depth_estimate(o, d, ta, tb, sampler, go)
                prod[go] = prod * (1.0 - (tau_i - c) / lam)
                k[go] += 1
                term[go] = term * lam / mi.Float(k)
                # The float32 sum of the Poisson pmf levels off below 1 (at 1 − 1.8e-7 … 1 − 7.7e-7 for
                # some λ in [0.1, 50]), under the largest sample 1 − 2⁻²³: such a u never stopped the loop
                # and the lane ran to its cap (2 of 192 sun rays with u = 1 − 2⁻²³, a test). The draw now
                # stops where the cdf stops rising: the tail left is below float32 resolution.
                rising = cdf + term > cdf
                cdf[go] = cdf + term
                go &= (u > cdf) & rising
            return dr.select(active, dr.exp(-c) * prod, 0.0)

        # ------------------------------------------------------------------ emitters
        def nee(self, scene, sampler, it, lane_time, active):
            """(emitted weight × ratio-tracked transmittance × visibility, ds) of one emitter sample."""
            emitters = scene.emitters()
            if len(emitters) == 1:  # the sky's sun: called directly (no virtual call; pmf 1)
                ds, em_w = emitters[0].sample_direction(it, sampler.next_2d(active), active)
                far = mi.has_flag(emitters[0].flags(), mi.EmitterFlags.Infinite)
            else:
                ds, em_w = scene.sample_emitter_direction(it, sampler.next_2d(active), False, active)
                far = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.Infinite)
            active = active & (ds.pdf != 0.0)
            occluded = scene.ray_test(it.spawn_ray_to(ds.p), active)
            active &= ~occluded
            estimator = (
                self.ratio_tracking if self.sun_transmittance == "ratio" else self.marched_transmittance
            )
            tr = estimator(it.p, ds.d, dr.select(far, dr.inf, ds.dist), sampler, lane_time, active)
            return dr.select(active, em_w * tr, 0.0), ds

        @dr.syntax
        def sample(self, scene, sampler, ray, medium=None, active=True):
            import mitsuba as mi  # dr.syntax re-executes the function without its closure

            ray = mi.Ray3f(ray)
            ray.d = dr.normalize(ray.d)
            lane_time = mi.Float(ray.time)
            L = mi.Spectrum(0.0)
            F = mi.Spectrum(1.0)  # f / mean_k p_k
            w = mi.Spectrum(1.0)  # p_k / mean_j p_j
            hero = mi.UInt32(dr.minimum(mi.UInt32(sampler.next_1d(active) * 3.0), 2))
            active = mi.Bool(active)
            depth = mi.UInt32(0)
            valid_ray = mi.Bool(False)
            specular_chain = mi.Bool(True)
            prev = dr.zeros(mi.Interaction3f)
            max_depth = mi.UInt32(0xFFFFFFFF if self.max_depth < 0 else self.max_depth)

            while active:
                active &= self.lane_counter.within(lane_time)
                active &= dr.max(F) != 0.0
                q = dr.minimum(dr.max(F), 0.95)
                perform_rr = depth > self.rr_depth
                active &= (sampler.next_1d(active) < q) | ~perform_rr
                F[perform_rr & active] = F * dr.rcp(q)

                si = scene.ray_intersect(ray, active)
                collided, t_c, F2, w2 = self.free_flight(
                    ray.o, ray.d, si.t, hero, F, w, sampler, lane_time, active
                )
                F[active] = F2
                w[active] = w2
                act_medium = active & collided
                depth[act_medium] += 1
                active &= depth < max_depth
                act_medium &= active
                act_surface = active & ~collided

                # ------------------------------------------------------ emitter hit (escape / surface)
                emitter = si.emitter(scene)
                act_e = act_surface & (emitter != None)  # noqa: E711 (Dr.Jit pointer comparison)
                count = (depth == 0) | specular_chain
                if not self.nee_only:  # hits that NEE could not have sampled count too
                    ds_e = mi.DirectionSample3f(scene, si, prev)
                    count |= scene.pdf_emitter_direction(prev, ds_e, act_e & ~specular_chain) == 0.0
                act_e &= count
                L[act_e] += F * emitter.eval(si, act_e)
                act_surface &= si.is_valid()

                # ------------------------------------------------------ the scattering vertex
                mei, it_m = medium_vertex(mi, ray, t_c, self.above_ground(ray(t_c)))
                bsdf = si.bsdf(ray)
                ctx = mi.BSDFContext()
                pctx = mi.PhaseFunctionContext(sampler)
                nee_surface = (
                    act_surface & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth) & (depth + 1 < max_depth)
                )
                ref = dr.zeros(mi.Interaction3f)
                ref[act_medium] = it_m
                ref[act_surface] = si
                em, ds = self.nee(scene, sampler, ref, lane_time, act_medium | nee_surface)
                ph_val = mi.Spectrum(self.phase.eval_pdf(pctx, mei, ds.d, act_medium)[0])
                b_val = bsdf.eval(ctx, si, si.to_local(ds.d), nee_surface)
                f_val = dr.select(act_medium, ph_val, b_val)
                L[act_medium | nee_surface] += F * f_val * em

                # ------------------------------------------------------ the next direction
                if self.nee_only:  # no direction after the last vertex that can receive NEE
                    act_medium &= depth + 1 < max_depth
                    act_surface &= depth + 2 < max_depth
                u1 = sampler.next_1d(act_medium | act_surface)
                u2 = sampler.next_2d(act_medium | act_surface)
                wo, ph_w, ph_pdf = self.phase.sample(pctx, mei, u1, u2, act_medium)
                act_medium &= ph_pdf > 0.0
                F[act_medium] *= ph_w
                valid_ray |= act_medium
                specular_chain &= ~act_medium
                bs, b_w = bsdf.sample(ctx, si, u1, u2, act_surface)
                act_surface &= bs.pdf > 0.0
                F[act_surface] *= b_w
                non_null = act_surface & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
                depth[non_null] += 1
                valid_ray |= non_null
                specular_chain |= non_null & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
                specular_chain &= ~(act_surface & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Smooth))

                # ------------------------------------------------------ next segment
                ray[act_medium] = mei.spawn_ray(wo)
                ray[act_surface] = si.spawn_ray(si.to_world(bs.wo))
                prev[act_medium] = it_m
                prev[non_null] = si
                active = act_medium | act_surface

            return L, valid_ray, []

        def aov_names(self):
            return []

        def to_string(self):
            return f"SkyPath[max_depth={self.max_depth}]"

    mi.register_integrator(PLUGIN, lambda props: SkyPath(props))
    _registered.add(variant)
