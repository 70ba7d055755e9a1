"""The Nishita-sky family's own study for ``rtfit run nishita-sky`` (issue 30 §1): what only this family has.

The engine (`rtfit.experiments.engine_run`) audits the shipped sky files (`audit_nishita_sky.SCENES`: one
per sun elevation, the azimuth × elevation panorama of the upper hemisphere, viewer 10 m) exactly as ``rtfit
audit`` audits a user's sky file: the multiple-scattering reference (``rtfit_skypath``, all orders, ground
albedo 0.1), every RGB method (seed, fine, fitted: the artist parameters fitted through the one kernel
text), metrics beside the noise floor, costs, figures per case and the fitted file. This study reads those
audits (their directions, masks, references, row images and fits) and adds (docs/nishita-sky.md):

* **the single-scattering reference** (max_depth 2, the same directions and samples: it isolates the
  texture's numerical error from its physical one) and the rows against it, with the **independent float64
  quadrature** (`rtfit.reference.nishita_sky.single_scattering_quadrature`; the sun's disc up to
  `DISC_MAX_DEG`) as its check: z of the sums, Σ ratio, the robust per-pixel z spread;
* the sun's **disc as its own term** (sun ≤ 2°), the **viewer above the ground** (5000 m, 30000 m),
  the **spectral reference** (Mitsuba's spectral variant against the spectral quadrature, white-balanced
  like `spectral_to_srgb`) and the spectral Nishita sky, **Mitsuba's sunsky** scaled against the
  multiple-scattering sky, the **horizontal irradiance** ratios that explain twilight beside the fits;
* the **layer / texture / table sweep** against the quadrature (noise-free) with measured build times, the
  per-pixel lookup and build costs of each setting and, in full runs, the build's NumPy time and the
  reference estimators side by side (`bench_media`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rtfit.fitting import compute_metrics, robust_spread, tone_map
from rtfit.realtime.arrays import backend_float, backend_type
from rtfit.realtime.nishita_sky import (
    FINE_SETTING,
    METHODS,
    SEED_SETTING,
    build_sky,
    shade_sky,
    spectral_to_srgb,
)
from rtfit.reference.nishita_sky import (
    CIE_Y_NORMALIZATION,
    bench_media,
    cached_quadrature,
    film_srgb,
    hemisphere_directions,
    library_atmosphere,
    render_sky,
    solar_spectrum,
    sunsky_radiance,
)
from rtfit.reference.variants import backend_of

from . import nishita_sky_report as R
from .audit_nishita_sky import atmosphere_params_of
from .case_inputs import masked_image
from .cost import time_drjit, time_numpy
from .records import Check, Headline
from .shipped import Study, StudyContext
from .sky_rows import near_sun

__all__ = [
    "BENCH_SETTINGS",
    "Sky",
    "bench",
    "config",
    "quadrature_check",
    "skies",
    "spectral_white_balance",
    "study",
]

SPECTRAL = "nishita-spectral"
RGB = ("nishita-seed", "nishita-fine")
METRICS = ("rmse", "rel_mse", "mae", "max_abs", "psnr", "smape")
TONE_MAP_EXPOSURE = 10.0


def config(quick: bool) -> dict:
    """The study's settings (the experiment's before the engine)."""
    return {
        "pass_spp": 128 if quick else 1024,
        "quadrature_stride": (4, 2) if quick else (8, 4),
        "quadrature_steps": 400 if quick else 1500,
        "altitude_cases": [(10.0, 5000.0)] if quick else [(10.0, 5000.0), (10.0, 30000.0)],
        "spectral_min_elevation_deg": 10.0 if quick else -90.0,
        "spectral_resolution": (16, 8) if quick else (64, 32),
        "spectral_spp": 1024 if quick else 4096,
        "spectral_pass_spp": 256 if quick else 1024,
        "spectral_stride": (2, 1) if quick else (4, 2),
        "sweep_elevations_deg": (10.0, -4.0),
        "sweep_layers": [4, 16, 32, 128] if quick else [4, 8, 16, 32, 64, 128],
        "sweep_textures": [(32, 16), (128, 64), (256, 128)]
        if quick
        else [(32, 16), (64, 32), (128, 64), (256, 128), (512, 256)],
        "sweep_tables": [16, 128] if quick else [16, 32, 64, 128, 256],
        "sweep_fine": not quick,
        "cost_elements": 1 << (18 if quick else 22),
    }


# ============================================================================================ the skies
@dataclasses.dataclass
class Sky:
    """One audited sky file: its sun elevation, atmosphere, the panorama's unit directions (H, W, 3), the
    case's mask (sun ±1° out), the multiple- (engine) and single-scattering (study) references, the rows'
    images and the fitted row's fit."""

    elev: float
    spec: object
    dirs: np.ndarray
    mask: np.ndarray
    ms: tuple[np.ndarray, np.ndarray]
    ss: tuple[np.ndarray, np.ndarray]
    spp: int
    images: dict
    fit: dict | None
    case: str


def _ss_render(ctx, spec, dirs, mask, spp, pass_spp) -> tuple[np.ndarray, np.ndarray]:
    ref = render_sky(spec, dirs[mask], spp, min(pass_spp, spp), ctx.seed, ctx.variant, 2, ctx.cache_dir)
    return masked_image(mask, ref["mean"]), masked_image(mask, ref["stderr"])


def skies(ctx: StudyContext, cfg: dict) -> list[Sky]:
    """Each audit's sky case, with its single-scattering reference rendered on the same directions."""
    out = []
    for r in ctx.audits:
        for c in r.cases:
            e, alt = float(c.parameters["sun_elevation_deg"]), float(c.parameters["viewer_altitude_m"])
            dirs = np.asarray(r.gbuffer.view_dir, np.float64)
            dirs = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
            spec = library_atmosphere(sun_elevation_deg=e, viewer_altitude_m=alt)
            spp = int(c.reference.spp)
            rows = r.outcomes[c.id]
            # the shipped rows (the fitted row under its method's id, as in the report's tables)
            fitted = next((o for o in rows.values() if o.fit is not None and not o.user), None)
            images = {o.method.id: o.image for o in rows.values() if not o.user and o.fit is None}
            if fitted is not None:
                images[fitted.method.id] = fitted.image
            fit = fitted.fit if fitted is not None else None
            ms = (c.reference.mean, c.reference.stderr)
            ss = _ss_render(ctx, spec, dirs, c.mask, spp, cfg["pass_spp"])
            out.append(Sky(e, spec, dirs, c.mask, ms, ss, spp, images, fit, c.id))
    return out


def _radiance(method_id, sky_or_e, dirs, backend, alt=10.0, atm=None) -> np.ndarray:
    """A method's sky image along ``dirs`` through its setting's texture (the realtime module's text)."""
    e = sky_or_e.elev if isinstance(sky_or_e, Sky) else float(sky_or_e)
    atm = atm or atmosphere_params_of(library_atmosphere())
    return METHODS[method_id].fixed["setting"].radiance(atm, e, dirs, altitude_m=alt, backend=backend)


# ============================================================================================== metrics
def _rel_mae(x, r, s, m) -> dict:
    """Σ|x − r| / Σ|r| over the mask, with its noise floor √(2/π) Σσ / Σ|r|."""
    den = max(float(np.sum(np.abs(r[m]))), 1e-30)
    v = float(np.sum(np.abs(x[m] - r[m]))) / den
    fl = math.sqrt(2 / math.pi) * float(np.sum(s[m])) / den
    return {"value": v, "noise_floor": fl, "resolved": bool(v > 2 * fl)}


def _tm_rmse(x, r, s, m, seed=0) -> dict:
    """RMSE of tone-mapped images t(10x) = 10x/(1 + |10x|) (Bruneton 2017-style), with its MC noise floor."""

    def tm(a):
        return tone_map(TONE_MAP_EXPOSURE * a)

    v = float(np.sqrt(np.mean((tm(x[m]) - tm(r[m])) ** 2)))
    noisy = r[m] + s[m] * np.random.default_rng(seed).standard_normal(r[m].shape)
    fl = float(np.sqrt(np.mean((tm(noisy) - tm(r[m])) ** 2)))
    return {"value": v, "noise_floor": fl, "resolved": bool(v > 2 * fl)}


def _row(img, ref, mask) -> dict:
    """The old experiment's row metrics: `compute_metrics` plus rel_mae and tonemapped_rmse."""
    mean, se = ref
    md = compute_metrics(img, mean, se, mask, names=METRICS).to_dict()
    return {**md, "rel_mae": _rel_mae(img, mean, se, mask), "tonemapped_rmse": _tm_rmse(img, mean, se, mask)}


def _rel_diff(x, r) -> list[float]:
    """Per channel Σ|x − r| / Σ|r| and over all channels (noise-free comparisons): [R, G, B, all]."""
    x, r = np.asarray(x, np.float64).reshape(-1, 3), np.asarray(r, np.float64).reshape(-1, 3)
    per = np.sum(np.abs(x - r), axis=0) / np.maximum(np.sum(np.abs(r), axis=0), 1e-30)
    return [float(v) for v in per] + [float(np.sum(np.abs(x - r)) / max(float(np.sum(np.abs(r))), 1e-30))]


def _irradiance(img, dirs) -> np.ndarray:
    """Horizontal irradiance ∫ L sin(el) cos(el) dEl dAz over the panorama (midpoint rule)."""
    H, W = dirs.shape[:2]
    el = np.arcsin(np.clip(dirs[..., 2], -1, 1))
    w = np.sin(el) * np.cos(el) * (math.pi / 2 / H) * (2 * math.pi / W)
    return np.tensordot(w, img, axes=([0, 1], [0, 1]))


def _subset(stride) -> tuple[slice, slice]:
    """The quadrature's pixel subset: every ``stride`` = (x, y) pixel, starting half a stride in."""
    return slice(stride[1] // 2, None, stride[1]), slice(stride[0] // 2, None, stride[0])


def quadrature_check(q, mean, stderr, what) -> tuple[dict, np.ndarray, np.ndarray, Check]:
    """An independent quadrature ``q`` (n, 3) against Mitsuba's ``mean`` ± ``stderr`` on the same pixels: its
    metrics, per-pixel z (for the robust spread), the z of the per-channel sums and the check (|z| ≤ 4)."""
    met = compute_metrics(q, mean, stderr, names=("rmse", "mae", "max_abs")).to_dict()
    ok = stderr > 0
    z = ((q - mean)[ok] / stderr[ok]).ravel()
    zsum = (q.sum(axis=0) - mean.sum(axis=0)) / np.sqrt((stderr**2).sum(axis=0))
    check = Check(
        name=f"{what}, z of the sum over {len(q)} pixels (R, G, B)",
        value=", ".join(f"{v:.2f}" for v in zsum),
        expected="|z| ≤ 4 per channel",
        passed=bool(np.all(np.abs(zsum) <= 4)),
    )
    return met, z, zsum, check


def _spread_check(z, what, quick) -> tuple[float, Check]:
    spread = robust_spread(z)
    return spread, Check(
        name=f"{what}: robust z spread ({z.size} values)",
        value=spread,
        expected="1 ± 0.25" if not quick else "≈ 1 (informative in quick runs)",
        passed=bool(abs(spread - 1) <= 0.25) or quick,
    )


# ========================================================================================= the parts
def ss_part(ctx, cfg, sks, backend) -> dict:
    """Per sky: the rows vs single and multiple scattering (the spectral sky and sunsky too), the quadrature
    check, the sun's disc, the irradiance ratios."""
    rows, checks, zs, quads, irr, disc_lines = [], [], [], {}, [], []
    sl = _subset(cfg["quadrature_stride"])
    for s in sks:
        s.images[SPECTRAL] = np.where(s.mask[..., None], _radiance(SPECTRAL, s, s.dirs, backend), 0.0)
        if s.elev > 0:
            ss_img = sunsky_radiance(s.elev, s.dirs, ctx.variant)["sky"]
            m = s.mask
            k = float(np.sum(ss_img[m] * s.ms[0][m]) / max(np.sum(ss_img[m] ** 2), 1e-30))
            s.images["sunsky"] = np.where(m[..., None], ss_img * k, 0.0)
            rows.append({"sun": s.elev, "row": "sunsky", "scale": k})
        for row, img in s.images.items():
            entry = {"sun": s.elev, "row": row, "ms": _row(img, s.ms, s.mask)}
            if row in (*RGB, SPECTRAL):
                entry["ss"] = _row(img, s.ss, s.mask)
            rows.append(entry)
        keep = s.mask[sl]
        quad = quads[s.elev] = cached_quadrature(s.spec, s.dirs[sl], cfg["quadrature_steps"], ctx.cache_dir)
        q = quad["value"] if quad["disc"] is None else quad["disc"]  # the sun the Mitsuba reference renders
        sun = "point sun" if quad["disc"] is None else "disc sun"
        sub_m, sub_s = s.ss[0][sl][keep], s.ss[1][sl][keep]
        met, z, _, check = quadrature_check(
            q[keep], sub_m, sub_s, f"sun {s.elev:g}°: independent SS quadrature ({sun}) vs Mitsuba SS"
        )
        zs.append(z)
        ratio = q[keep].sum(axis=0) / np.maximum(sub_m.sum(axis=0), 1e-30)
        rows.append({"sun": s.elev, "row": "quadrature", "ss": met, "seconds": quad["seconds"]})
        checks += [
            check,
            Check(
                name=f"sun {s.elev:g}°: Σ quadrature / Σ Mitsuba SS (G)",
                value=float(ratio[1]),
                expected="1 within 4 σ of the sum (previous check)",
                passed=True,
            ),
        ]
        e_ss, e_ms = _irradiance(s.ss[0], s.dirs), _irradiance(s.ms[0], s.dirs)
        e_seed = _irradiance(s.images["nishita-seed"], s.dirs)
        irr.append({"sun": s.elev, "ss": e_ss.tolist(), "ms": e_ms.tolist(), "seed": e_seed.tolist()})
        if quad["disc"] is not None:
            disc_lines.append(_disc_line(s, quad, keep, sl, checks))
    return {"rows": rows, "checks": checks, "z": zs, "quads": quads, "irradiance": irr, "disc": disc_lines}


def _disc_line(s: Sky, quad, keep, sl, checks) -> list[str]:
    """The sun's disc vs a point sun on the quadrature's pixels (noise-free), and whether this run's
    single-scattering reference resolves it (G sum in σ of the reference's sum; ≥ 4 σ resolves it)."""
    qp, qd, sub = quad["value"][keep], quad["disc"][keep], s.dirs[sl][keep]
    low = (sub[:, 2] < math.sin(math.radians(15.0))) & (sub[:, 0] < 0)  # low anti-solar sky
    term = _rel_diff(qp, qd)
    low_t = _rel_diff(qp[low], qd[low]) if low.any() else [float("nan")] * 4
    sigma = float(np.sqrt(np.sum(s.ss[1][sl][keep][:, 1] ** 2)))
    effect = float(abs(np.sum(qp[:, 1] - qd[:, 1]))) / max(sigma, 1e-300)
    need = math.ceil(s.spp * (4.0 / effect) ** 2) if effect > 0 else None
    errs = []
    for m in RGB:
        err = _rel_diff(s.images[m][sl][keep], qd)[3]
        errs.append(f"{METHODS[m].label} {err:.3g} (disc share {term[3] / max(err, 1e-300):.2g})")
    checks.append(
        Check(
            name=f"sun {s.elev:g}°: the sun's disc vs a point sun in the SS quadrature (G)",
            value=f"Σ|point − disc| / Σ disc = {term[1]:.3g}, low anti-solar sky {low_t[1]:.3g}; "
            f"{effect:.2g} σ of this run's SS reference sum",
            expected="informative: the cross-check above uses the disc; ≥ 4 σ resolves the disc",
            passed=True,
        )
    )
    res = "resolved" if effect >= 4 else f"needs ≈ {need} spp" if need else "—"
    return [f"{s.elev:g}°", f"{term[1]:.3g}", f"{low_t[1]:.3g}", "; ".join(errs), f"{effect:.2g} σ ({res})"]


def altitude_part(ctx, cfg, sks, backend) -> dict:
    """Viewer above the ground: single scattering at the altitude vs the RGB textures built for it, and the
    quadrature as the reference's check."""
    rows, checks, zs = [], [], []
    sl = _subset(cfg["quadrature_stride"])
    for e, alt in cfg["altitude_cases"]:
        s = next((s for s in sks if s.elev == e), None)
        if s is None:
            continue
        spec = library_atmosphere(sun_elevation_deg=e, viewer_altitude_m=alt)
        ss = _ss_render(ctx, spec, s.dirs, s.mask, s.spp, cfg["pass_spp"])
        for m in RGB:
            img = np.where(s.mask[..., None], _radiance(m, e, s.dirs, backend, alt=alt), 0.0)
            rows.append({"sun": e, "altitude_m": alt, "row": m, "ss": _row(img, ss, s.mask)})
        keep = s.mask[sl]
        q = cached_quadrature(spec, s.dirs[sl], cfg["quadrature_steps"], ctx.cache_dir)["value"][keep]
        what = f"viewer at {alt:g} m, sun {e:g}°: independent SS quadrature vs Mitsuba SS"
        met, z, _, check = quadrature_check(q, ss[0][sl][keep], ss[1][sl][keep], what)
        rows.append({"sun": e, "altitude_m": alt, "row": "quadrature", "ss": met})
        checks.append(check)
        zs.append(z)
    return {"rows": rows, "checks": checks, "z": zs}


def spectral_white_balance(lam16) -> dict:
    """The von Kries factors k = E₀ / film_srgb(E₀(λ)) that put a Mitsuba film sRGB value in the real-time
    spectral sky's convention (`spectral_to_srgb` with white = the solar spectrum, white_rgb = E₀)."""
    e0 = np.asarray(atmosphere_params_of(library_atmosphere()).solar_irradiance, np.float64)
    lam = np.arange(360.0, 830.5, 1.0)
    white = film_srgb(solar_spectrum(lam, e0[1]), lam)
    rt = spectral_to_srgb(solar_spectrum(lam16, e0[1]), lam16) * CIE_Y_NORMALIZATION
    return {
        "E0_rgb": e0.tolist(),
        "mitsuba_film_srgb_of_sun": white.tolist(),
        "realtime_over_mitsuba_unbalanced": (rt / white).tolist(),
        "von_kries_factors": (e0 / white).tolist(),
    }


def spectral_part(ctx, cfg, sks, backend) -> dict | None:
    """Mitsuba's spectral single scattering (white-balanced) vs the spectral and RGB Nishita skies, checked by
    the spectral quadrature; noise-free decompositions on the quadrature's pixels."""
    import mitsuba  # mitsuba: lazy (heavy); lists the installed variants only

    sv = {"cuda": "cuda_ad_spectral", "llvm": "llvm_ad_spectral"}.get(ctx.variant.split("_", 1)[0])
    elevs = [s.elev for s in sks if s.elev >= cfg["spectral_min_elevation_deg"]]
    if sv not in mitsuba.variants() or not elevs:
        return None
    SW, SH = cfg["spectral_resolution"]
    d = hemisphere_directions(SW, SH)[0]
    sl = _subset(cfg["spectral_stride"])
    lam16 = METHODS[SPECTRAL].fixed["setting"].spectral_wavelengths()
    wb = spectral_white_balance(lam16)
    k, e0 = np.asarray(wb["von_kries_factors"]), np.asarray(wb["E0_rgb"])
    rows, checks, zs = [], [], []
    for e in elevs:
        spec = library_atmosphere(sun_elevation_deg=e, viewer_altitude_m=10.0)
        ref = render_sky(
            spec, d, cfg["spectral_spp"], cfg["spectral_pass_spp"], ctx.seed, sv, 2, ctx.cache_dir
        )
        mean, se, m = ref["mean"] * k, ref["stderr"] * k, ~near_sun(d, e)
        spec_img = _radiance(SPECTRAL, e, d, backend)
        rgb_img = np.where(m[..., None], _radiance("nishita-seed", e, d, backend), 0.0)
        qd = cached_quadrature(spec, d[sl], cfg["quadrature_steps"], ctx.cache_dir, spectral=True)
        q = qd["srgb"] * k
        what = f"sun {e:g}°: independent spectral SS quadrature vs Mitsuba spectral SS"
        qm, z, zsum, check = quadrature_check(
            q.reshape(-1, 3), mean[sl].reshape(-1, 3), se[sl].reshape(-1, 3), what
        )
        checks.append(check)
        zs.append(z)
        lam = np.asarray(qd["wavelengths_nm"])
        spectra = np.asarray(qd["spectra"]).reshape(-1, lam.size)
        at16 = np.stack([np.interp(lam16, lam, sp) for sp in spectra]).reshape(*q.shape[:-1], lam16.size)
        conv = spectral_to_srgb(at16, lam16, white=solar_spectrum(lam16, e0[1]), white_rgb=e0)
        ms = m[sl]
        spec_sub = _radiance(SPECTRAL, e, d[sl], backend)[ms]
        rgb_sub = _radiance("nishita-seed", e, d[sl], backend)[ms]
        rows.append(
            {
                "sun": e,
                "zsum_quadrature_vs_reference": [float(v) for v in zsum],
                "quadrature": qm,
                "spectral_vs_reference": _row(spec_img, (mean, se), m),
                "rgb_vs_reference": _row(rgb_img, (mean, se), m),
                "nishita_spectral_vs_quadrature": _rel_diff(spec_sub, q[ms]),
                "conversion_16_lambda_vs_film": _rel_diff(conv[ms], q[ms]),
                "nishita_rgb_vs_rgb_quadrature": _rel_diff(rgb_sub, qd["rgb"][ms]),
                "rgb_model_vs_spectral_model": _rel_diff(qd["rgb"][ms], q[ms]),
                "rgb_over_spectral_sum": (np.sum(qd["rgb"][ms], axis=0) / np.sum(q[ms], axis=0)).tolist(),
                "nishita_rgb_vs_nishita_spectral_image": _rel_diff(rgb_img[m], spec_img[m]),
            }
        )
    spread, c = _spread_check(
        np.concatenate(zs), "independent spectral SS quadrature vs Mitsuba spectral SS", ctx.quick
    )
    atm = atmosphere_params_of(library_atmosphere())
    dev = float(
        np.max(np.abs(np.asarray(atm.spectral(lam16).solar_irradiance) / solar_spectrum(lam16, e0[1]) - 1))
    )
    checks += [
        c,
        Check.below(
            "solar spectrum: reference (re-derived) vs the real-time spectral variant's, max "
            "relative difference",
            dev,
            "1e-12",
        ),
    ]
    return {"rows": rows, "checks": checks, "white_balance": wb, "robust_z_spread": spread, "size": (SW, SH)}


BUILD_REPEATS = 3
"""Timed builds of a texture after its warm-up (`_timed_build`) in a full run; a quick run times one: each
build is traced again (~0.1–0.3 s of Python around a few ms of kernels on 2 cores), and the quick suite's
sweep and cost tables spent ~2.6 s in them (issue 33, session 24)."""


def sweep_part(cfg, sks, quads, backend, build_repeats: int = BUILD_REPEATS) -> list[dict]:
    """Layers / texture / table / horizon mapping against the point-sun quadrature (noise-free) on its
    pixel subset, with the measured whole-texture build time (`_timed_build`, ``build_repeats``)."""
    seed = SEED_SETTING.build_keywords()
    confs = [dict(seed, layers=n) for n in cfg["sweep_layers"]]
    for w, h in cfg["sweep_textures"]:
        confs += [dict(seed, width=w, height=h), dict(seed, width=w, height=h, mapping="sqrt")]
    confs += [dict(seed, table_size=m) for m in cfg["sweep_tables"]]
    confs += [FINE_SETTING.build_keywords()] if cfg["sweep_fine"] else []
    p, out = atmosphere_params_of(library_atmosphere()), []
    sl = _subset(cfg["quadrature_stride"])
    for s in sks:
        if s.elev not in cfg["sweep_elevations_deg"]:
            continue
        q, sub = quads[s.elev]["value"], s.dirs[sl]
        for c in {tuple(sorted(c.items())): c for c in confs}.values():
            sky, t = _timed_build(p, s.elev, c, backend, build_repeats)
            L = shade_sky(sky, sub)
            rel = float(np.sum(np.abs(L - q)) / max(float(np.sum(np.abs(q))), 1e-30))
            out.append(
                {
                    **c,
                    "sun_elevation_deg": s.elev,
                    "rel_mae": rel,
                    "build_ms": t.seconds * 1e3,
                    "seed": c == seed,
                }
            )
    return out


def _builder(p, e, c, backend, built: list | None = None):
    """The whole texture's build (sun ``e``°, viewer 10 m, setting keywords ``c``) as `time_drjit` times it;
    the first texture built is appended to ``built`` where given."""

    def fn():
        sky = build_sky(p, e, 10.0, backend=backend, **c)
        if built is not None and not built:
            built.append(sky)
        return sky.rayleigh + sky.mie

    return fn


def _timed_build(p, e, c, backend, repeats: int = BUILD_REPEATS):
    """(the texture, the `time_drjit` timing of its whole build, the median of ``repeats`` builds after the
    warm-up): the texture is the one the timing's warm-up call built (the same inputs, so the same texture;
    `build_sky` evaluates it), not built once more before the timing as it was (a fine texture: 0.7 CPU s;
    issue 33)."""
    built: list = []
    t = time_drjit(
        _builder(p, e, c, backend, built), (), c["width"] * c["height"], repeats=repeats,
        min_seconds=0.05 if repeats > 1 else 0.0,  # (one build: the one, however short)
    )  # fmt: skip
    return built[0], t


def cost_part(ctx, cfg, backend) -> list[dict]:
    """Per RGB setting: the per-pixel lookup (texture + phase + sun disc) and the whole texture's build, as
    an engine runs them (the engine's cost of a row times the method's kernel, which rebuilds the texture
    per call); full runs: the build's NumPy time beside Dr.Jit's."""
    p, n = atmosphere_params_of(library_atmosphere()), int(cfg["cost_elements"])
    v = np.random.default_rng(1).normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    Float = backend_float(backend)
    dirs = backend_type("Array3f", backend)(Float(v[:, 0]), Float(v[:, 1]), Float(v[:, 2]))
    rows = []
    for m in RGB:
        c = METHODS[m].fixed["setting"].build_keywords()
        sky, tb = _timed_build(p, 10.0, c, backend, 1 if ctx.quick else BUILD_REPEATS)
        t = time_drjit(lambda d, sky=sky: shade_sky(sky, d), (dirs,), n)
        row = {"method": m, "lookup_ns_per_pixel": t.seconds * 1e9 / n, "build_ms": tb.seconds * 1e3}
        if not ctx.quick:
            fn = lambda c=c: build_sky(p, 10.0, 10.0, backend="numpy", **c)  # noqa: E731
            row["numpy_build_ms"] = (
                time_numpy(fn, (), c["width"] * c["height"], repeats=1, min_seconds=0.0).seconds * 1e3
            )
        rows.append(row)
    return rows


# ============================================================================================== bench
BENCH_SETTINGS = (
    *(dataclasses.replace(SEED_SETTING, layers=n) for n in (8, 32, 128)),
    dataclasses.replace(SEED_SETTING, width=512, height=256),
    FINE_SETTING,
)
"""The texture builds `bench` times (the old experiment's: the seed at 8, 32, 128 layers, at 512×256, the
fine setting)."""


def bench(ctx) -> list[dict]:
    """``rtfit bench nishita-sky`` beyond the engine's rows (`Family.bench`): the whole texture's build per
    `BENCH_SETTINGS` (``--quick``: the first two), Dr.Jit (this backend) vs the NumPy loop, and the reference
    estimators side by side (`bench_media`, sun 10°: 32×16 at 128 spp with ``--quick``, else 128×64 at 1024
    spp)."""
    backend = backend_of(ctx.variant)
    p = atmosphere_params_of(library_atmosphere())
    rows = []
    for setting in BENCH_SETTINGS[:2] if ctx.quick else BENCH_SETTINGS:  # (NumPy's fine build: ~1 min)
        c = setting.build_keywords()
        texels = c["width"] * c["height"]
        t_dr = time_drjit(_builder(p, 10.0, c, backend), (), texels, repeats=5)
        fn = lambda c=c: build_sky(p, 10.0, 10.0, backend="numpy", **c)  # noqa: E731
        t_np = time_numpy(fn, (), texels, repeats=1 if ctx.quick else 3, min_seconds=0.0)
        rows.append({
            "what": f"texture build n={c['layers']} {c['width']}×{c['height']} table {c['table_size']}",
            "backend": backend,
            "elements": texels,
            "drjit_ms": t_dr.seconds * 1e3,
            "numpy_ms": t_np.seconds * 1e3,
            "drjit/numpy": t_np.seconds / t_dr.seconds,
            "seed_2006_s": 15.0,
        })  # fmt: skip
    res, spp = ((32, 16), 128) if ctx.quick else ((128, 64), 1024)
    return rows + bench_media(ctx.variant, library_atmosphere(sun_elevation_deg=10.0), res=res, spp=spp)


# ============================================================================================== study
def study(ctx: StudyContext) -> Study:
    """The study of ``rtfit run nishita-sky`` (module docstring), beside the engine's audits."""
    cfg = config(ctx.quick)
    backend = backend_of(ctx.variant)
    sks = sorted(skies(ctx, cfg), key=lambda s: -s.elev)
    main = ss_part(ctx, cfg, sks, backend)
    alt = altitude_part(ctx, cfg, sks, backend)
    spectral = spectral_part(ctx, cfg, sks, backend)
    sweep = sweep_part(cfg, sks, main["quads"], backend, 1 if ctx.quick else BUILD_REPEATS)
    costs = cost_part(ctx, cfg, backend)
    sun10 = library_atmosphere(sun_elevation_deg=10.0)
    bench = [] if ctx.quick else bench_media(ctx.variant, sun10, res=(128, 64), spp=1024)  # the old bench's
    z = np.concatenate(main["z"])  # the viewer-altitude cases have their own z check
    spread, spread_check = _spread_check(z, "independent SS quadrature vs Mitsuba SS", ctx.quick)
    finite = all(np.isfinite(i).all() and (i >= 0).all() for s in sks for i in s.images.values())
    checks = [
        *main["checks"],
        *alt["checks"],
        *(spectral["checks"] if spectral else []),
        spread_check,
        Check.holds("all approximation images finite and non-negative", finite),
    ]
    parts = dict(main=main, alt=alt, spectral=spectral, sweep=sweep, costs=costs, bench=bench, spread=spread)
    bound = [
        f"{s.elev:g}° ({', '.join(k for k, p in s.fit['parameters'].items() if p['at_bound'])})"
        for s in sks
        if s.fit and any(p["at_bound"] for p in s.fit["parameters"].values())
    ]
    seed_ss = {r["sun"]: r["ss"]["rel_mae"]["value"] for r in main["rows"] if r["row"] == "nishita-seed"}
    extra = {
        "rows": main["rows"],
        "altitude": alt["rows"],
        "irradiance": main["irradiance"],
        "sweep": sweep,
        "costs_by_setting": costs,
        "bench_media": bench,
        "spectral": spectral and {k: v for k, v in spectral.items() if k != "checks"},
        "robust_z_spread": spread,
    }
    return Study(
        sections=tuple(R.sections(cfg, sks, parts)),
        figures=tuple(R.figures(ctx, sks, main["irradiance"], sweep)),
        checks=tuple(checks),
        notes=(
            "Pixels within 1° of the sun are left out of every comparison (the sun disc is a separate term).",
            "Artist fits with a parameter on a bound: " + ", ".join(bound)
            if bound
            else "No artist fit ended on a parameter bound.",
        ),
        headline=tuple(Headline(f"seed vs SS at {e:g}° (rel. MAE)", v) for e, v in seed_ss.items()),
        extra={"nishita_study": extra},
    )
