"""The albedo AOV of a frame (``rtfit compare --aov albedo=A.exr``): checked against the scene's BSDF
reflectance at the first hits, then used to split a radiance frame's error into albedo and lighting
(`rtfit.experiments.compare`).

* **alignment** (`albedo_alignment`): the reference albedo is Mitsuba's
  ``BSDF.eval_diffuse_reflectance`` at each pixel-centre first hit (the G-buffer's ``albedo``: what Mitsuba's
  ``aov`` integrator writes as ``albedo``). A surface pixel is off when a channel differs by more than
  `ALBEDO_TOLERANCE` + `ALBEDO_RELATIVE` × the scene's value. Beyond `ALBEDO_REFUSE` of the surface pixels
  off, the AOV is refused in one line naming what explains it (an image upside down, mirrored or rotated;
  sRGB-encoded values instead of linear ones), else as not the scene's albedo. Below it, the shapes whose
  albedo is off are named (an engine's own wrong material: what the split then attributes).
* **split** (`albedo_split`): a radiance frame F with its albedo a_F, against the reference R with the scene's
  albedo a_R, per pixel where both albedos exceed `MIN_ALBEDO` in every channel:

      F − R = (F − F·a_R/a_F) + (F·a_R/a_F − R)
              └── albedo ──┘   └── lighting ──┘

  F·a_R/a_F is the frame's own lighting (its F/a_F) on the scene's albedo: for a diffuse surface
  L = a·E/π, so the first part is the error the wrong albedo makes and the second the error of the engine's
  lighting (its irradiance, shadows, probes). Each is reported as a bias relative to the reference's sum over
  those pixels, beside its uncertainty (the reference's σ scaled the same way), in all and per shape.
"""

from __future__ import annotations

import numpy as np

from .audit import AuditError
from .compare_frames import srgb_to_linear

__all__ = ["ALBEDO_REFUSE", "ALBEDO_TOLERANCE", "albedo_alignment", "albedo_split"]

ALBEDO_TOLERANCE = 0.02
"""Absolute part of a pixel's albedo tolerance (per channel)."""
ALBEDO_RELATIVE = 0.05
"""Relative part of a pixel's albedo tolerance (per channel, × the scene's albedo)."""
ALBEDO_REFUSE = 0.5
"""Fraction of surface pixels off above which the albedo AOV is refused."""
MIN_ALBEDO = 1e-3
"""Albedos at or below this (black, emitters, conductors) leave a pixel out of the split."""
SPLIT_SIGMAS = 3.0


def _off(albedo: np.ndarray, ref: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(N,) bool over ``ok``'s pixels: some channel beyond the tolerance."""
    tol = ALBEDO_TOLERANCE + ALBEDO_RELATIVE * np.abs(ref[ok])
    return np.any(~(np.abs(albedo[ok] - ref[ok]) <= tol), axis=-1)


def albedo_alignment(albedo: np.ndarray, gb, hits: np.ndarray, names: dict[int, str], text: str) -> dict:
    """The albedo AOV against the scene's (module docstring): the fraction of surface pixels off, the shapes
    whose median albedo is off; `AuditError` (one line) when more than `ALBEDO_REFUSE` of the pixels are."""
    a = np.asarray(albedo, np.float64)
    ref = np.asarray(gb.albedo, np.float64)
    ok = np.asarray(gb.mask, bool) & ~np.asarray(gb.emitter, bool) & np.all(np.isfinite(a), axis=-1)
    if not ok.any():
        raise AuditError(f"--aov albedo {text}: no surface pixel (not an emitter) with a finite albedo")
    frac = float(np.mean(_off(a, ref, ok)))
    if frac > ALBEDO_REFUSE:
        good = min(0.2, frac / 2)
        for label, cand in (
            ("its image is upside down: a flipped up axis (Y-up against Z-up?) or image origin", a[::-1, :]),
            ("its image is mirrored: the other handedness", a[:, ::-1]),
            ("its image is rotated by 180°", a[::-1, ::-1]),
            ("it holds sRGB-encoded values: store linear albedo", srgb_to_linear(np.clip(a, 0.0, 1.0))),
        ):
            if float(np.mean(_off(cand, ref, ok))) <= good:
                raise AuditError(f"--aov albedo {text}: {label} ({frac:.0%} of surface pixels off as given)")
        raise AuditError(
            f"--aov albedo {text}: not the scene's BSDF reflectance at the first hits: {frac:.0%} of surface "
            f"pixels differ by more than {ALBEDO_TOLERANCE:g} + {ALBEDO_RELATIVE:.0%} (the camera, the "
            "materials or the AOV differ)"
        )
    shapes = {}
    for idx in np.unique(hits[ok]):
        m = ok & (hits == idx)
        fa, ra = np.median(a[m], axis=0), np.median(ref[m], axis=0)
        if np.any(np.abs(fa - ra) > ALBEDO_TOLERANCE + ALBEDO_RELATIVE * np.abs(ra)):
            shapes[names.get(int(idx), str(idx))] = (fa.tolist(), ra.tolist())
    words = "; ".join(
        f"{n}: {_rgb(f)} in the frame against the scene's {_rgb(r)}" for n, (f, r) in shapes.items()
    )
    text_out = (
        f"{frac:.1%} of surface pixels differ from the scene's BSDF reflectance by more than "
        f"{ALBEDO_TOLERANCE:g} + {ALBEDO_RELATIVE:.0%}"
        + (f"; albedo off on {words}" if shapes else "; every shape's albedo matches")
        + "."
    )
    return {"misaligned_fraction": frac, "shapes_off": shapes, "text": text_out}


def _rgb(v) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"


def albedo_split(frame, ref, sigma, albedo, ref_albedo, mask, hits, names) -> dict:
    """The albedo/lighting split of ``frame``'s error (module docstring): totals and per shape, each part a
    bias relative to the reference's sum with its uncertainty, and a sentence (``text``)."""
    a = np.asarray(albedo, np.float64)
    ar = np.asarray(ref_albedo, np.float64)
    ok = mask & np.all(a > MIN_ALBEDO, axis=-1) & np.all(ar > MIN_ALBEDO, axis=-1)
    if not ok.any():
        return {"pixels": 0, "text": "no pixel with a non-zero albedo in both: no albedo/lighting split."}
    relit = np.where(ok[..., None], frame * ar / np.where(a > MIN_ALBEDO, a, 1.0), 0.0)

    def part(m):
        total = float(np.sum(ref[m]))
        if total <= 0:
            return None
        u = float(np.sqrt(np.sum(sigma[m] ** 2))) / total
        u_light = float(np.sqrt(np.sum((sigma[m] * ar[m] / a[m]) ** 2))) / total
        return {
            "pixels": int(m.sum()),
            "error": float(np.sum(frame[m] - ref[m])) / total,
            "albedo": float(np.sum(frame[m] - relit[m])) / total,
            "lighting": float(np.sum(relit[m] - ref[m])) / total,
            "uncertainty": u,
            "lighting_uncertainty": u_light,
        }

    out = part(ok) or {"pixels": int(ok.sum())}
    per_shape = {}
    for idx in np.unique(hits[ok]):
        p = part(ok & (hits == idx))
        if p is not None:
            per_shape[names.get(int(idx), str(idx))] = p
    out["shapes"] = per_shape

    def words(p) -> str:
        light = p["lighting"]
        lit = (
            "within noise"
            if abs(light) <= SPLIT_SIGMAS * p["lighting_uncertainty"]
            else f"{light:+.1%} ± {p['lighting_uncertainty']:.1%}"
        )
        return f"albedo {p['albedo']:+.1%}, lighting {lit}"

    if "error" in out:
        by_shape = "; ".join(f"{n}: {words(p)}" for n, p in per_shape.items())
        out["text"] = (
            f"error {out['error']:+.1%} of the reference on {out['pixels']} pixels: {words(out)} "
            f"(by shape: {by_shape})."
        )
    else:
        out["text"] = "the reference is zero on the pixels with an albedo: no albedo/lighting split."
    return out
