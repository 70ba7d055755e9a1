"""The AOVs of a frame (``rtfit compare --aov depth=D.exr,normal=N.exr``): read before anything renders,
then compared with Mitsuba's first hits of the same pixel-centre rays, so that alignment is checked, not
assumed (`rtfit.experiments.compare`).

* **depth**: the distance along the ray or planar depth along the view axis, whichever the frame holds;
  the fraction of surface pixels off by more than `DEPTH_TOLERANCE`. Above `DEPTH_WARN` the depth is examined
  for a flipped or mirrored image, a half-pixel offset or another field of view, and refused naming the one
  that explains it; above `DEPTH_REFUSE` it is refused in any case.
* **albedo**: the BSDF reflectance at the first hit (`compare_albedo`: its alignment, and the split of a
  radiance frame's error into albedo and lighting).
* **normal**: unit normals, stored as they are or encoded as n/2 + ½; the convention they are in (world with
  the scene's axes, world with Y up, view space looking down −z or +z) is the one with the least median angle
  to Mitsuba's shading normals; refused when even that exceeds `NORMAL_REFUSE_DEG`, or when the image turned
  back (upside down, mirrored, rotated by 180°: `FLIPS`) matches far better (with only a normal AOV, the
  flips are told from the normals, as from the depth).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .audit import AuditError
from .compare_albedo import albedo_alignment
from .compare_frames import read_depth, read_frame

__all__ = [
    "AOVS",
    "DEPTH_TOLERANCE",
    "align_aovs",
    "depth_alignment",
    "normal_alignment",
    "parse_aovs",
    "read_aovs",
]

AOVS = ("depth", "normal", "albedo")
DEPTH_TOLERANCE = 0.02
"""A pixel's depth is misaligned when it differs from Mitsuba's first-hit distance by more than this
fraction."""
DEPTH_REFUSE = 0.5
"""Misaligned fraction above which the camera is refused (one line naming the likely cause)."""
DEPTH_WARN = 0.2
"""Misaligned fraction above which the depth is examined for a flip, a half-pixel offset or another field of
view (refused, naming it, when one of them explains the depth)."""
NORMAL_TOLERANCE_DEG = 10.0
NORMAL_REFUSE_DEG = 30.0
NORMAL_FLIP_MIN = 0.05
"""Fraction of surface pixels whose normal is off by more than `NORMAL_TOLERANCE_DEG` above which the normal
AOV is examined for a flipped image (refused, naming it, when the flip brings that fraction to a quarter)."""
FLIPS = (
    ("its image is upside down: a flipped up axis (Y-up against Z-up?) or image origin", np.s_[::-1, :]),
    ("its image is mirrored: the other handedness", np.s_[:, ::-1]),
    ("its image is rotated by 180°", np.s_[::-1, ::-1]),
)
"""The image flips an AOV is examined for (depth and normals): the words naming each, and its slice."""


def parse_aovs(values: Sequence[str] | str | None) -> dict[str, str]:
    """``--aov depth=D.exr[,normal=N.exr,albedo=A.exr]`` (repeatable) → {name: file}; `AuditError` on
    anything else."""
    if values is None:
        return {}
    items = [values] if isinstance(values, str) else list(values)
    out: dict[str, str] = {}
    for item in items:
        for part in str(item).split(","):
            name, eq, path = part.partition("=")
            name = name.strip()
            if not eq or not path.strip():
                raise AuditError(f"--aov {part!r}: expected NAME=FILE (e.g. depth=D.exr)")
            if name not in AOVS:
                raise AuditError(f"--aov {name}: not read yet (AOVs read: {', '.join(AOVS)})")
            out[name] = path.strip()
    return out


def read_aovs(aovs: Mapping[str, str], shape: tuple[int, int]) -> dict[str, Any]:
    """Each AOV of ``aovs`` (`parse_aovs`) read and checked to be of the frames' (H, W) ``shape``: depth →
    (array, channel), normal and albedo → (H, W, 3); `AuditError` (one line) otherwise."""
    out: dict[str, Any] = {}
    for name, text in aovs.items():
        data = read_depth(text) if name == "depth" else read_frame(text).image
        got = (data[0] if name == "depth" else data).shape[:2]
        if got != tuple(shape):
            raise AuditError(f"--aov {name} {text}: {got[1]}×{got[0]}, the frames are {shape[1]}×{shape[0]}")
        out[name] = data
    return out


def align_aovs(
    aovs: Mapping[str, str], data: Mapping[str, Any], gb, x_fov_deg, hits=None, names=None
) -> dict[str, dict]:
    """AOV name → its alignment with the scene's first hits (`depth_alignment`, `normal_alignment`,
    `compare_albedo.albedo_alignment` with the first-hit shape indices ``hits`` and their ``names``)."""
    out = {}
    if "depth" in data:
        out["depth"] = depth_alignment(data["depth"][0], gb, aovs["depth"], data["depth"][1], x_fov_deg)
    if "normal" in data:
        out["normal"] = normal_alignment(data["normal"], gb, aovs["normal"])
    if "albedo" in data:
        hits = np.full(gb.mask.shape, -1) if hits is None else hits
        out["albedo"] = albedo_alignment(data["albedo"], gb, hits, names or {}, aovs["albedo"])
    return out


def _camera_axes(gb) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward) unit vectors of the camera, from its pixel-centre view directions (image columns
    grow to the right, rows downwards)."""
    d = np.asarray(gb.view_dir, np.float64)
    fwd = d.reshape(-1, 3).sum(axis=0)
    fwd /= np.linalg.norm(fwd)
    right = (d[:, -1] - d[:, 0]).sum(axis=0)
    up = (d[0, :] - d[-1, :]).sum(axis=0)
    right -= fwd * (right @ fwd)
    up -= fwd * (up @ fwd) + right * (up @ right) / max(float(right @ right), 1e-30)
    return right / np.linalg.norm(right), up / np.linalg.norm(up), fwd


def normal_alignment(normals: np.ndarray, gb, text: str) -> dict:
    """The normal AOV against Mitsuba's shading normals at the first hits (module docstring): the encoding,
    the convention, the median angle and the fraction of surface pixels beyond `NORMAL_TOLERANCE_DEG`.
    `AuditError` (one line) when they are not unit vectors, no convention brings the median angle under
    `NORMAL_REFUSE_DEG`, or more than `NORMAL_FLIP_MIN` are off and the image turned back (the best of
    `FLIPS`) has at most a quarter as many off: the flip is named."""
    raw = np.asarray(normals, np.float64)
    ok = gb.mask & np.all(np.isfinite(raw), axis=-1)
    candidates = {"stored as they are": raw}
    if float(np.min(raw[ok])) >= -1e-3 if ok.any() else False:
        candidates["encoded as n/2 + ½"] = 2.0 * raw - 1.0
    dev = {k: float(np.median(np.abs(np.linalg.norm(v[ok], axis=-1) - 1.0))) for k, v in candidates.items()}
    encoding = min(dev, key=lambda k: dev[k])
    if not ok.any() or dev[encoding] > 0.2:
        raise AuditError(
            f"--aov normal {text}: not unit normals on the scene's surface pixels (stored or n/2 + ½)"
        )
    n = candidates[encoding]
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    m = np.asarray(gb.normal, np.float64)
    right, up, fwd = _camera_axes(gb)
    conventions = {
        "world space with the scene's axes": m,
        "world space with Y up (the scene's z)": np.stack([m[..., 0], m[..., 2], -m[..., 1]], axis=-1),
        "view space looking down −z (OpenGL)": np.stack([m @ right, m @ up, -(m @ fwd)], axis=-1),
        "view space looking down +z (Direct3D)": np.stack([m @ right, m @ up, m @ fwd], axis=-1),
    }

    def matched(n: np.ndarray, ok: np.ndarray) -> tuple[float, float, str]:
        """(median angle, fraction beyond the tolerance, convention): the convention of least median."""
        best = (math.inf, 1.0, "")
        for name, x in conventions.items():
            a = np.degrees(np.arccos(np.clip(np.sum(n[ok] * x[ok], axis=-1), -1.0, 1.0)))
            best = min(best, (float(np.median(a)), float(np.mean(a > NORMAL_TOLERANCE_DEG)), name))
        return best

    median, frac, best = matched(n, ok)
    if frac > NORMAL_FLIP_MIN:  # flipped, mirrored or rotated: the normals match only with the image turned
        turned = [(*matched(n[flip], gb.mask & np.all(np.isfinite(raw[flip]), axis=-1))[:2], label)
                  for label, flip in FLIPS]  # fmt: skip
        f_median, f_frac, label = min(turned, key=lambda t: t[1])
        if f_frac <= frac / 4 and f_median <= NORMAL_REFUSE_DEG:
            raise AuditError(
                f"--aov normal {text}: the frame's camera does not match the scene's sensor: {label} "
                f"({frac:.0%} of surface pixels' normals off by more than {NORMAL_TOLERANCE_DEG:g}°, "
                f"{f_frac:.0%} with the image turned back)"
            )
    if median > NORMAL_REFUSE_DEG:
        raise AuditError(
            f"--aov normal {text}: the frame's normals do not match the scene's in any convention (world, "
            f"Y-up world, view space): median angle {median:.0f}° at best ({best}); the camera or the AOV "
            "differs"
        )
    words = (
        f"normals in {best}, {encoding}; median angle to Mitsuba's shading normals {median:.1f}°, "
        f"{frac:.1%} of surface pixels beyond {NORMAL_TOLERANCE_DEG:g}°."
    )
    return {"convention": best, "encoding": encoding, "median_angle_deg": median, "misaligned_fraction": frac,
            "text": words}  # fmt: skip


def _resampled(depth: np.ndarray, k: float = 1.0, dx: float = 0.0, dy: float = 0.0) -> np.ndarray:
    """The frame's depth at each pixel's centre offset from the image centre scaled by ``k`` (a view ``k``×
    narrower) and moved by (``dx``, ``dy``) px, bilinear (NaN outside the frame or next to a pixel without
    depth): frame[y + dy, x + dx] for k = 1, as the registration offset reads."""
    h, w = depth.shape
    y = h / 2 + ((np.arange(h) + 0.5) - h / 2) * k + dy - 0.5
    x = w / 2 + ((np.arange(w) + 0.5) - w / 2) * k + dx - 0.5
    y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
    fy, fx = (y - y0)[:, None], (x - x0)[None, :]
    ok = ((y0 >= 0) & (y0 + 1 < h))[:, None] & ((x0 >= 0) & (x0 + 1 < w))[None, :]
    yy, xx = np.clip(y0, 0, h - 2)[:, None], np.clip(x0, 0, w - 2)[None, :]
    v = ((1 - fy) * (1 - fx) * depth[yy, xx] + (1 - fy) * fx * depth[yy, xx + 1]
         + fy * (1 - fx) * depth[yy + 1, xx] + fy * fx * depth[yy + 1, xx + 1])  # fmt: skip
    return np.where(ok, v, np.nan)


HALF_PIXELS = tuple((dx, dy) for dy in (-0.5, 0.0, 0.5) for dx in (-0.5, 0.0, 0.5) if (dx, dy) != (0.0, 0.0))
ZOOMS = np.geomspace(0.5, 2.0, 121)
"""The view-width ratios tried when the depth does not match: a field of view that differs."""


def _camera_mismatch(depth, frac: float, misaligned, x_fov_deg) -> str | None:
    """Which simple change of the camera makes the frame's depth match (misaligned at most `DEPTH_WARN` and
    half of ``frac``): a flip, a half-pixel offset or another field of view; None when none does."""
    good = min(DEPTH_WARN, frac / 2)
    for label, flip in FLIPS:
        if misaligned(depth[flip])[0] <= good:
            return label
    shifts = [
        (misaligned(_resampled(depth, 1.0, dx, dy), coverage=False)[0], (dx, dy)) for dx, dy in HALF_PIXELS
    ]
    best, (dx, dy) = min(shifts)
    if best <= good:
        return (
            f"its pixel centres are offset by half a pixel (its depth matches at ({dx:+.1f}, {dy:+.1f}) px)"
        )
    zooms = [(misaligned(_resampled(depth, k), coverage=False)[0], k) for k in ZOOMS]
    best, k = min(zooms)
    if best <= good and abs(k - 1.0) > 0.02:
        fov = ""
        if x_fov_deg:
            f = np.degrees(2 * np.arctan(np.tan(np.radians(x_fov_deg) / 2) / k))
            fov = f" (x fov ≈ {f:.0f}° against the scene's {x_fov_deg:.0f}°)"
        return f"its field of view differs: the frame's view is {1 / k:.2f}× the scene's width{fov}"
    return None


def depth_alignment(depth: np.ndarray, gb, text: str, channel: str, x_fov_deg: float | None = None) -> dict:
    """The depth AOV against Mitsuba's first hits of the same pixel-centre rays: which convention it holds
    (the distance along the ray, or planar depth along the view axis), the fraction of pixels misaligned by
    more than `DEPTH_TOLERANCE` and the median relative difference. `AuditError` (one line, naming the likely
    cause) when more than `DEPTH_REFUSE` of them are, or more than `DEPTH_WARN` and a flip, a half-pixel
    offset or another field of view explains them: the camera does not match the scene's."""
    t = np.asarray(gb.depth, np.float64)
    dirs = np.asarray(gb.view_dir, np.float64)
    fwd = dirs.reshape(-1, 3).sum(axis=0)
    fwd /= np.linalg.norm(fwd)
    conventions = {"ray distance": t, "planar depth": t * np.abs(dirs @ fwd)}

    def misaligned(d: np.ndarray, coverage: bool = True) -> tuple[float, str, float, int]:
        best = (2.0, "", float("nan"), 0)
        for name, x in conventions.items():
            ok = gb.mask & np.isfinite(d) & np.isfinite(x)
            if not ok.any():
                continue
            rel = np.abs(d[ok] - x[ok]) / x[ok]
            frac = float(np.mean(rel > DEPTH_TOLERANCE))
            both = int(ok.sum())
            covered = both / max(int(gb.mask.sum()), 1)
            if coverage:  # a surface pixel without the frame's depth is misaligned too
                frac = 1.0 - (1.0 - frac) * covered
            elif covered < 0.5:
                continue
            if frac < best[0]:
                best = (frac, name, float(np.median(rel)), both)
        return best

    frac, name, median, n = misaligned(depth)
    if n == 0:
        raise AuditError(
            f"--aov depth {text}: no pixel where both the frame's depth and the scene have a surface"
        )
    if frac > DEPTH_WARN:
        why = _camera_mismatch(depth, frac, misaligned, x_fov_deg)
        if why is not None or frac > DEPTH_REFUSE:
            why = why or "its field of view, position, aspect or a half-pixel offset differ"
            raise AuditError(
                f"--aov depth {text}: the frame's camera does not match the scene's sensor: {why} "
                f"({frac:.0%} of pixels' depth off by more than {DEPTH_TOLERANCE:.0%})"
            )
    return {
        "convention": name,
        "channel": channel,
        "misaligned_fraction": frac,
        "median_rel_diff": median,
        "pixels": n,
        "text": f"channel {channel!r} holds the {name}; {frac:.1%} of surface pixels differ from "
        f"Mitsuba's first hit by more than {DEPTH_TOLERANCE:.0%} (median {median:.2%}).",
    }
