"""The normal-to-light angle breakdown of ``rtfit compare`` (`rtfit.experiments.compare`): each frame's error
per band of n·l, the cosine between the surface normal at the pixel's first hit and the direction to the
scene's main light, beside the breakdowns per shape, BSDF and distance (`compare_checks.shape_errors`).

* **The main light** (`main_light`): the emitter with the largest unshadowed irradiance summed over the
  visible points: per emitter, `SAMPLES` of Mitsuba's own emitter sampling per point
  (``Emitter.sample_direction``: weight w = L/pdf), Ê(x) = mean of lum(w)·max(n·ω, 0) (no shadow ray: the
  light the point faces, lit or shadowed).
* **The direction to it** l(x): the mean of the sampled directions ω weighted by lum(w) (no cosine: also
  where the surface faces away) — exact for a point, spot or directional light, the radiance-weighted
  centre for an area light or an environment.
* **Bands** (`nl_bands`): n·l ≤ 0 (facing away: only indirect light), and (0, 0.25], (0.25, 0.5],
  (0.5, 0.75], (0.75, 1] named by their angles (90°–75.5°, …). A shadow-map bias, a wrap or terminator term,
  a normal-map error or a light's falloff shows as error concentrated in a band.
"""

from __future__ import annotations

import drjit as dr
import numpy as np

from rtfit.reference.estimators import gbuffer_points, sub_seed

__all__ = ["NL_EDGES", "SAMPLES", "MainLight", "main_light", "nl_bands"]

SAMPLES = 16
"""Emitter samples per visible point to find the main light and the direction to it."""
NL_EDGES = (0.0, 0.25, 0.5, 0.75)
"""Upper edges of the n·l bands below 1 (the first band is n·l ≤ 0)."""
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


class MainLight:
    """The scene's main light: its ``name``, ``index`` in ``scene.emitters()``, the share of the summed
    unshadowed irradiance it gives (``share``) and per pixel the unit direction to it (``direction`` (H, W,
    3), zero where no surface) and n·l (``nl`` (H, W), NaN where no surface)."""

    def __init__(self, name: str, index: int, share: float, direction: np.ndarray, nl: np.ndarray):
        self.name, self.index, self.share, self.direction, self.nl = name, index, share, direction, nl


def _emitter_name(em, names) -> str:
    eid = str(em.id())
    if eid in names:
        return names[eid]
    cls = str(em.class_name()) if hasattr(em, "class_name") else type(em).__name__
    shape = em.get_shape() if hasattr(em, "get_shape") else None
    if shape is not None:
        sid = str(shape.id())
        return f"{cls} on {sid if sid and not sid.startswith('_unnamed') else 'a shape'}"
    return f"{cls} {eid}" if eid and not eid.startswith("_unnamed") else cls


def main_light(mi, mi_scene, gb, seed: int = 0, names=None) -> MainLight | None:
    """The main light and the direction to it at each surface pixel (module docstring); None without an
    emitter or a surface pixel. ``names``: an emitter's Mitsuba id → the name the report gives it."""
    emitters = list(mi_scene.emitters())
    mask = np.asarray(gb.mask, bool) & ~np.asarray(gb.emitter, bool)
    if not emitters or not mask.any():
        return None
    points, normals = gbuffer_points(gb, mask)
    n_pts = len(points)
    lanes = n_pts * SAMPLES
    idx = np.repeat(np.arange(n_pts), SAMPLES)
    it = dr.zeros(mi.SurfaceInteraction3f, lanes)
    it.p = mi.Point3f(points[idx].T.astype(np.float32))
    it.n = mi.Normal3f(normals[idx].T.astype(np.float32))
    it.sh_frame = mi.Frame3f(it.n)
    totals, directions = [], []
    for k, em in enumerate(emitters):
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(sub_seed(seed, "main-light", k), lanes)
        ds, w = em.sample_direction(it, sampler.next_2d())
        lum = np.asarray(w, np.float64).T @ LUMINANCE
        d = np.asarray(ds.d, np.float64).T
        ok = np.isfinite(lum) & np.all(np.isfinite(d), axis=1)
        lum, d = np.where(ok, np.maximum(lum, 0.0), 0.0), np.where(ok[:, None], d, 0.0)
        totals.append(float(np.sum(lum * np.maximum(np.sum(d * normals[idx], axis=1), 0.0))))
        mean_dir = np.zeros((n_pts, 3))
        np.add.at(mean_dir, idx, lum[:, None] * d)
        directions.append(mean_dir)
    k = int(np.argmax(totals))
    total, mean_dir = totals[k], directions[k]
    length = np.linalg.norm(mean_dir, axis=1, keepdims=True)
    unit = np.where(length > 0, mean_dir / np.maximum(length, 1e-300), 0.0)
    h, w_ = mask.shape
    direction = np.zeros((h, w_, 3))
    direction[mask] = unit
    nl = np.full((h, w_), np.nan)
    nl[mask] = np.where(length[:, 0] > 0, np.sum(unit * normals, axis=1), np.nan)
    share = total / sum(totals) if sum(totals) > 0 else 0.0
    return MainLight(_emitter_name(emitters[k], names or {}), k, share, direction, nl)


def nl_bands(nl: np.ndarray) -> tuple[np.ndarray, dict[int, str]]:
    """(labels (H, W), names): the n·l bands (module docstring); −1 where n·l is NaN (no surface, or no
    direction to the light)."""
    labels = np.full(nl.shape, -1, np.int32)
    ok = np.isfinite(nl)
    labels[ok] = np.searchsorted(np.asarray(NL_EDGES), nl[ok], side="left")
    names = {0: "n·l ≤ 0 (facing away)"}
    edges = (*NL_EDGES, 1.0)
    for i in range(1, len(edges)):
        lo, hi = edges[i - 1], edges[i]
        a_hi, a_lo = np.degrees(np.arccos(lo)), np.degrees(np.arccos(hi))
        names[i] = f"n·l {lo:g}–{hi:g} ({a_hi:.0f}°–{a_lo:.0f}°)"
    return labels, names
