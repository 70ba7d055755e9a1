"""Your own light probes: lat-long, cube-cross, mirror-ball and angular maps, resampled to rtfit's lat-long.

A probe is given as ``PATH[:MAPPING]`` (``rtfit run --probe PATH[:MAPPING]`` checks it; no experiment
takes probes since irradiance-bases runs on the audit engine). The file is read with Mitsuba's ``Bitmap``
(OpenEXR ``.exr``, Radiance ``.hdr``/``.pic``, ``.pfm``: linear radiance, W·m⁻²·sr⁻¹ per linear-sRGB
channel); it must be finite and
non-negative. ``MAPPING`` is one of `MAPPINGS`; without it the mapping is read off the aspect ratio
(`detect_mapping`): 2:1 lat-long, 3:4 vertical cross, 4:3 horizontal cross. A square image is a mirror ball
or an angular map, which the aspect cannot tell apart: name it.

**The probe frame F** (the file's): right-handed, **+Y up**, the frame of Debevec's light-probe gallery and
of Probulator. It becomes rtfit's world frame (+Z up) by the rotation of +90° about X,

    world = (F_x, −F_z, F_y),      F = (w_x, w_z, −w_y)                   (`file_to_world`).

Image coordinates (u, v) ∈ [0, 1]²: u to the right, v **down**, texel (i, j) centred at ((i + ½)/W,
(j + ½)/H). Every mapping is one pair of formulas, direction of (u, v) and (u, v) of a direction (F frame):

* ``latlong`` (equirectangular; Probulator's and Debevec's lat-long): θ = π(2u − 1), φ = πv,
  F = (sin φ sin θ, cos φ, −sin φ cos θ): the top row is the zenith +Y, u = ½ looks along −Z, u = ¾
  along +X. The inverse is `rtfit.reference.environments.probe_source_uv` (``"probulator"``), the
  convention of the measured probes in ``../shared/probes``.
* ``angular`` (Debevec's "light probe" angular map) and ``mirrorball`` (an orthographic photograph of a
  mirror sphere, the camera on +Z): a = 2u − 1 (right), b = 1 − 2v (up), r = √(a² + b²) ≤ 1;
  F = (sin α · a/r, sin α · b/r, cos α) with α the angle from +Z (the image centre; the rim is −Z):
  angular α = πr (radius linear in angle); mirror ball α = 2 asin r (the view ray (0, 0, −1)
  reflected about the sphere normal (a, b, √(1 − r²)) is (2a n_z, 2b n_z, 2n_z² − 1)).
  Texels outside the disc take the value of the rim texel on their radius (`fill_outside_disc`), so the
  bilinear lookup near the rim never reads the black corners.
* ``vcross`` (3 × 4 faces) and ``hcross`` (4 × 3): six square faces, each a view from the centre with
  forward f, right r and up u (r × u = −f); F = normalise(f + a r + b u) with (a, b) ∈ [−1, 1]² the
  face coordinates (a right, b up). Layout (`CROSSES`): the front −Z in the middle of the cross row,
  −X left of it, +X right of it, +Y above, −Y below; the back +Z below −Y, upside down (``vcross``),
  or right of +X (``hcross``). Lookups clamp to the face's own texels. Tools differ in which way is
  forward; a probe in another convention comes out turned (docs/irradiance-bases.md, orientation).

`resample_latlong` samples the probe at rtfit's lat-long nodes (H × 2H, `rtfit.reference.environments`):
each node's value is the solid-angle weighted mean of s × s bilinear lookups over the node's footprint
(Δu = 1/W, Δv = 1/(H − 1), clipped to the sphere at the poles; each sub-sample weighted by its sub-cell's
exact solid angle, ∝ cos θ_lo − cos θ_hi, and looked up at the sub-cell's centre), s chosen so the sub-samples
are no coarser than the source texels (at most 8). A constant probe stays exactly constant (E = π L at every
normal), and the integral of the map is the probe's own up to the O(h²) resampling error.

Published numbers: `RH2001_GRACE_L2` are Ramamoorthi & Hanrahan 2001's L2 coefficients of Grace
Cathedral (2 decimals) in their frame; `RH2001_FROM_WORLD` maps rtfit's world frame onto it
(`rtfit.experiments.irradiance_bases_study.rh2001_coefficients` projects a map in that frame).
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import environments as envs

__all__ = [
    "CROSSES",
    "EXTENSIONS",
    "MAPPINGS",
    "RH2001_FROM_WORLD",
    "RH2001_GRACE_L2",
    "RH2001_TOLERANCE",
    "ProbeSpec",
    "detect_mapping",
    "file_to_world",
    "fill_outside_disc",
    "mapping_direction",
    "mapping_uv",
    "parse_probe_spec",
    "probe_spec_problem",
    "read_probe",
    "resample_latlong",
    "user_probe_environment",
    "user_probe_ids",
    "world_to_file",
]

MAPPINGS = ("latlong", "vcross", "hcross", "mirrorball", "angular")
"""The mappings a probe file may have (``PATH:MAPPING``)."""
MAPPING_LABELS = {
    "latlong": "lat-long (equirectangular)",
    "vcross": "vertical cube cross",
    "hcross": "horizontal cube cross",
    "mirrorball": "mirror ball",
    "angular": "angular map (light probe)",
}
ASPECTS = {"latlong": (2, 1), "vcross": (3, 4), "hcross": (4, 3), "mirrorball": (1, 1), "angular": (1, 1)}
"""Width : height of each mapping's image."""
EXTENSIONS = (".exr", ".hdr", ".pic", ".pfm")
"""File types read (linear radiance); 8-bit images (PNG, JPEG) are display-encoded, not radiance."""
MIN_SIDE = 8  # pixels: a smaller image cannot hold a probe
MAX_HEIGHT = 2048  # rows of the resampled lat-long map at most (its default is the probe's own resolution)
MAX_SUPERSAMPLE = 8

_X, _Y, _Z = np.eye(3)
CROSSES = {
    # (column, row, forward, right, up) per face: the face seen from the centre of the cube
    "vcross": (
        (3, 4),
        (
            (1, 0, _Y, _X, _Z),
            (0, 1, -_X, -_Z, _Y),
            (1, 1, -_Z, _X, _Y),
            (2, 1, _X, _Z, _Y),
            (1, 2, -_Y, _X, -_Z),
            (1, 3, _Z, _X, -_Y),  # the back face, upside down below −Y
        ),
    ),
    "hcross": (
        (4, 3),
        (
            (1, 0, _Y, _X, _Z),
            (0, 1, -_X, -_Z, _Y),
            (1, 1, -_Z, _X, _Y),
            (2, 1, _X, _Z, _Y),
            (3, 1, _Z, -_X, _Y),
            (1, 2, -_Y, _X, -_Z),
        ),
    ),
}
"""Cube-cross layouts: (columns, rows) of face tiles, then each face's tile and frame (in F)."""


# ============================================================================================ frames
def file_to_world(f) -> np.ndarray:
    """Probe frame F (+Y up) → rtfit's world (+Z up): (F_x, −F_z, F_y) (rotation of +90° about X)."""
    f = np.asarray(f, np.float64)
    return np.stack([f[..., 0], -f[..., 2], f[..., 1]], axis=-1)


def world_to_file(w) -> np.ndarray:
    """Inverse of `file_to_world`: (w_x, w_z, −w_y)."""
    w = np.asarray(w, np.float64)
    return np.stack([w[..., 0], w[..., 2], -w[..., 1]], axis=-1)


# ========================================================================================== mappings
def _disc_alpha(mapping: str, r):
    """Angle from +Z of disc radius r: angular πr, mirror ball 2 asin r."""
    return np.pi * r if mapping == "angular" else 2.0 * np.arcsin(np.clip(r, 0.0, 1.0))


def _disc_radius(mapping: str, alpha):
    """Inverse of `_disc_alpha`: angular α/π, mirror ball sin(α/2)."""
    return alpha / np.pi if mapping == "angular" else np.sin(0.5 * alpha)


def mapping_direction(mapping: str, u, v) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (…, 3) in the probe frame F of image coordinates (u, v) (u right, v down, both in
    [0, 1]), and where the image holds the sphere (False outside a disc, or off the faces of a cross)."""
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    if mapping == "latlong":
        th, ph = np.pi * (2.0 * u - 1.0), np.pi * v
        d = np.stack([np.sin(ph) * np.sin(th), np.cos(ph), -np.sin(ph) * np.cos(th)], axis=-1)
        return d, np.ones(u.shape, bool)
    if mapping in ("angular", "mirrorball"):
        a, b = 2.0 * u - 1.0, 1.0 - 2.0 * v
        r = np.hypot(a, b)
        al = _disc_alpha(mapping, np.minimum(r, 1.0))
        s = np.where(r > 0, np.sin(al) / np.where(r > 0, r, 1.0), 0.0)
        return np.stack([s * a, s * b, np.cos(al)], axis=-1), r <= 1.0
    if mapping in CROSSES:
        (cols, rows), faces = CROSSES[mapping]
        cu, rv = u * cols, v * rows
        col = np.clip(np.floor(cu), 0, cols - 1)
        row = np.clip(np.floor(rv), 0, rows - 1)
        a, b = 2.0 * (cu - col) - 1.0, 1.0 - 2.0 * (rv - row)
        d = np.zeros((*u.shape, 3))
        valid = np.zeros(u.shape, bool)
        for c, r_, f, rt, up in faces:
            m = (col == c) & (row == r_)
            d[m] = f + a[m, None] * rt + b[m, None] * up
            valid |= m
        n = np.linalg.norm(d, axis=-1, keepdims=True)
        d = np.where(n > 0, d / np.where(n > 0, n, 1.0), 0.0)
        return d, valid
    raise ValueError(f"unknown probe mapping {mapping!r} (known: {', '.join(MAPPINGS)})")


def mapping_uv(mapping: str, d) -> tuple[np.ndarray, np.ndarray]:
    """Image coordinates (u, v) of unit direction(s) ``d`` (…, 3) in the probe frame F: the inverse of
    `mapping_direction` (for a cross: on the face whose forward axis is nearest ``d``)."""
    d = np.asarray(d, np.float64)
    if mapping == "latlong":
        return envs.probe_source_uv("probulator", file_to_world(d))
    if mapping in ("angular", "mirrorball"):
        al = np.arccos(np.clip(d[..., 2], -1.0, 1.0))
        r = _disc_radius(mapping, al)
        h = np.hypot(d[..., 0], d[..., 1])
        k = np.where(h > 0, r / np.where(h > 0, h, 1.0), 0.0)
        a, b = (
            np.where(h > 0, k * d[..., 0], r),
            k * d[..., 1],
        )  # on the axis: (r, 0) (the −Z pole is the rim)
        return 0.5 * (a + 1.0), 0.5 * (1.0 - b)
    if mapping in CROSSES:
        (cols, rows), faces = CROSSES[mapping]
        dots = np.stack([d @ f for _, _, f, _, _ in faces], axis=-1)
        k = np.argmax(dots, axis=-1)
        fwd = np.take_along_axis(dots, k[..., None], -1)[..., 0]
        rt = np.stack([rt for _, _, _, rt, _ in faces])[k]
        up = np.stack([up for _, _, _, _, up in faces])[k]
        a = np.sum(d * rt, axis=-1) / fwd
        b = np.sum(d * up, axis=-1) / fwd
        col = np.array([c for c, _, _, _, _ in faces], np.float64)[k]
        row = np.array([r_ for _, r_, _, _, _ in faces], np.float64)[k]
        eps = 1e-12  # a direction on a cube edge stays on the face chosen (not the tile beside it)
        s_, t_ = np.clip(0.5 * (a + 1.0), eps, 1 - eps), np.clip(0.5 * (1.0 - b), eps, 1 - eps)
        return (col + s_) / cols, (row + t_) / rows
    raise ValueError(f"unknown probe mapping {mapping!r} (known: {', '.join(MAPPINGS)})")


def _face_of(mapping: str, u, v) -> np.ndarray:
    """Index of the cross face holding (u, v) (−1 off the faces)."""
    (cols, rows), faces = CROSSES[mapping]
    col = np.clip(np.floor(np.asarray(u) * cols), 0, cols - 1)
    row = np.clip(np.floor(np.asarray(v) * rows), 0, rows - 1)
    out = np.full(np.shape(u), -1, np.int64)
    for i, (c, r_, _, _, _) in enumerate(faces):
        out[(col == c) & (row == r_)] = i
    return out


def fill_outside_disc(img: np.ndarray) -> np.ndarray:
    """A square disc image (mirror ball, angular) with every texel whose centre is outside the unit disc
    replaced by the texel on the same radius just inside the rim (so bilinear lookups at the rim never mix
    in the corners)."""
    n = img.shape[0]
    c = (np.arange(n) + 0.5) / n
    uu, vv = np.meshgrid(c, c)
    a, b = 2 * uu - 1, 1 - 2 * vv
    r = np.hypot(a, b)
    out = img.copy()
    far = r > 1.0
    if np.any(far):
        k = (1.0 - 1.0 / n) / r[far]
        i = np.clip(np.floor((a[far] * k + 1) * 0.5 * n), 0, n - 1).astype(np.int64)
        j = np.clip(np.floor((1 - b[far] * k) * 0.5 * n), 0, n - 1).astype(np.int64)
        out[far] = img[j, i]
    return out


def lookup(mapping: str, src: np.ndarray, d_world) -> np.ndarray:
    """Bilinear radiance of the probe image ``src`` (in ``mapping``) in world directions (…, 3)."""
    u, v = mapping_uv(mapping, world_to_file(d_world))
    if mapping == "latlong":
        return envs.source_lookup(src, u, v)
    if mapping in ("angular", "mirrorball"):
        return envs.source_lookup(src, u, v, periodic_u=False)
    (cols, rows), faces = CROSSES[mapping]
    n = src.shape[0] // rows
    face = _face_of(mapping, u, v)
    out = np.zeros((*np.shape(u), 3))
    for i, (c, r_, _, _, _) in enumerate(faces):
        m = face == i
        if np.any(m):
            tile = src[r_ * n : (r_ + 1) * n, c * n : (c + 1) * n]
            out[m] = envs.source_lookup(tile, u[m] * cols - c, v[m] * rows - r_, periodic_u=False)
    return out


# ============================================================================================= reading
@dataclass(frozen=True)
class ProbeSpec:
    """A user probe: the file and its mapping (None: from the aspect ratio)."""

    path: str
    mapping: str | None = None


def parse_probe_spec(text: str) -> ProbeSpec:
    """``PATH[:MAPPING]`` → `ProbeSpec` (a ``:`` suffix is a mapping only when it names one of `MAPPINGS`,
    so paths with colons still work)."""
    head, sep, tail = str(text).rpartition(":")
    if sep and tail in MAPPINGS and head:
        return ProbeSpec(head, tail)
    return ProbeSpec(str(text), None)


def detect_mapping(width: int, height: int) -> str:
    """The mapping of a ``width`` × ``height`` image from its aspect ratio; a ValueError if it has none or
    is square (mirror ball or angular: ambiguous)."""
    if width == height:
        raise ValueError(
            f"a square image ({width}×{height}) is a mirror ball or an angular map: name it, "
            "PATH:mirrorball or PATH:angular"
        )
    for m in ("latlong", "vcross", "hcross"):
        aw, ah = ASPECTS[m]
        if width * ah == height * aw:
            return m
    raise ValueError(
        f"image {width}×{height} has no probe aspect ratio (2:1 lat-long, 3:4 vertical cross, "
        "4:3 horizontal cross, 1:1 mirror ball or angular map)"
    )


def _check_image(img: np.ndarray, mapping: str | None) -> str:
    h, w = img.shape[:2]
    if min(h, w) < MIN_SIDE:
        raise ValueError(f"image {w}×{h} is too small for a probe (at least {MIN_SIDE} pixels a side)")
    if mapping is None:
        mapping = detect_mapping(w, h)
    aw, ah = ASPECTS[mapping]
    if w * ah != h * aw:
        raise ValueError(f"image {w}×{h} does not have the {aw}:{ah} aspect of a {MAPPING_LABELS[mapping]}")
    bad = ~np.isfinite(img)
    if np.any(bad):
        j, i = np.argwhere(bad.any(axis=-1))[0]
        raise ValueError(f"{int(bad.any(axis=-1).sum())} pixels are NaN or infinite (first at x={i}, y={j})")
    neg = img < 0
    if np.any(neg):
        j, i = np.argwhere(neg.any(axis=-1))[0]
        raise ValueError(
            f"{int(neg.any(axis=-1).sum())} pixels are negative (first at x={i}, y={j}, "
            f"{float(img[j, i].min()):.3g}); radiance must be ≥ 0"
        )
    return mapping


def read_probe(spec: ProbeSpec | str) -> tuple[np.ndarray, str]:
    """The probe's pixels (H, W, 3) float64 and its mapping, or a one-line ValueError (missing file,
    a file type that is not linear radiance, a file that does not read, a wrong aspect, NaN/Inf or
    negative pixels)."""
    spec = parse_probe_spec(spec) if isinstance(spec, str) else spec
    path = Path(spec.path)
    if not path.is_file():
        raise ValueError(f"probe file not found: {path}")
    if path.suffix.lower() not in EXTENSIONS:
        raise ValueError(
            f"probe file {path}: {path.suffix or 'no extension'} is not a radiance image "
            f"({', '.join(EXTENSIONS)})"
        )
    try:
        img = envs.read_image(path).astype(np.float64)
    except Exception as e:  # any failure to read is the user's bad file
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ValueError(f"probe file {path} does not read ({first})") from None
    try:
        mapping = _check_image(img, spec.mapping)
    except ValueError as e:
        raise ValueError(f"probe file {path}: {e}") from None
    return img, mapping


def probe_spec_problem(text: str) -> str | None:
    """What is wrong with a probe ``PATH[:MAPPING]`` (None: it reads), checked before anything runs; the
    file is read once per size and modification time."""
    spec = parse_probe_spec(text)
    path = Path(spec.path)
    if not path.is_file():
        return f"probe file not found: {path}"
    st = path.stat()
    return _spec_problem(str(path.resolve()), spec.mapping, st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=32)
def _spec_problem(path: str, mapping: str | None, _size: int, _mtime: int) -> str | None:
    try:
        read_probe(ProbeSpec(path, mapping))
    except ValueError as e:
        return str(e)
    return None


# ========================================================================================== resampling
def _native_height(img: np.ndarray, mapping: str) -> int:
    """Rows of the lat-long map with about the probe's own angular resolution."""
    h, w = img.shape[:2]
    if mapping == "latlong":
        n = h
    elif mapping in CROSSES:
        n = 2 * (h // CROSSES[mapping][0][1])  # 90° per face of N texels ↔ 180° per 2N rows
    else:
        n = w // 2
    return int(min(max(n, 4), MAX_HEIGHT))


def _source_spacing(img: np.ndarray, mapping: str) -> float:
    """The source's angular texel spacing (radians) at its coarsest sampled place we rely on."""
    h, w = img.shape[:2]
    if mapping == "latlong":
        return math.pi / h
    if mapping in CROSSES:
        return (math.pi / 2) / (h // CROSSES[mapping][0][1])
    return 2 * math.pi / w if mapping == "angular" else 4.0 / w  # mirror ball: dα/dr = 2 at the centre


def resample_latlong(img: np.ndarray, mapping: str, height: int | None = None) -> np.ndarray:
    """The probe as rtfit's lat-long map of ``height`` × 2·``height`` nodes (default: about the probe's own
    resolution), each node the solid-angle weighted mean of s × s bilinear lookups over its footprint (see
    the module docstring). float64 (H, W, 3)."""
    src = fill_outside_disc(img) if mapping in ("angular", "mirrorball") else np.asarray(img, np.float64)
    h = int(height or _native_height(img, mapping))
    w = 2 * h
    step = math.pi / (h - 1)
    s = int(min(MAX_SUPERSAMPLE, max(1, math.ceil(step / _source_spacing(img, mapping)))))
    off = ((np.arange(s) + 0.5) / s - 0.5)[None, :]
    half = 0.5 / ((h - 1) * s)  # half a sub-cell in v
    u_nodes = (np.arange(w) + 0.5) / w
    out = np.zeros((h, w, 3))
    rows_per = max(1, (1 << 20) // (w * s * s))
    for j0 in range(0, h, rows_per):
        js = np.arange(j0, min(h, j0 + rows_per))
        vs = (js[:, None] / (h - 1) + off / (h - 1)).reshape(-1)  # (rows·s,)
        us = (u_nodes[:, None] + off / w).reshape(-1)  # (w·s,)
        uu, vv = np.meshgrid(us, vs)  # (rows·s, w·s)
        lo, hi = np.clip(vv - half, 0.0, 1.0), np.clip(vv + half, 0.0, 1.0)
        wt = np.cos(np.pi * lo) - np.cos(np.pi * hi)  # the sub-cell's solid angle / Δφ (0 off the sphere)
        L = lookup(mapping, src, envs.uv_to_direction(uu, 0.5 * (lo + hi)))
        n = len(js)
        wt = wt.reshape(n, s, w, s)
        L = L.reshape(n, s, w, s, 3)
        num = np.einsum("asbt,asbtc->abc", wt, L)
        den = wt.sum(axis=(1, 3))[..., None]
        out[js] = num / np.maximum(den, 1e-300)
    return out


def user_probe_ids(specs) -> list[str]:
    """Environment ids of the user's probes, in order: ``probe-file-<file stem>`` (letters, digits, '-',
    '_'; a repeated stem gets ``-2``, ``-3``, …)."""
    out: list[str] = []
    for text in specs or ():
        stem = re.sub(r"[^A-Za-z0-9_-]+", "-", Path(parse_probe_spec(text).path).stem).strip("-") or "probe"
        base = f"probe-file-{stem}"
        name, k = base, 2
        while name in out:
            name, k = f"{base}-{k}", k + 1
        out.append(name)
    return out


def user_probe_environment(name: str, text: str, height: int | None = None) -> envs.Environment:
    """The user's probe ``text`` (``PATH[:MAPPING]``) as an `Environment` named ``name``, its lat-long map
    resampled by `resample_latlong` with ``height`` rows (None: the probe's own resolution)."""
    img, mapping = read_probe(text)
    path = Path(parse_probe_spec(text).path)
    lat = resample_latlong(img, mapping, height)
    return envs.map_environment(
        name,
        f"your probe: {path.name} ({MAPPING_LABELS[mapping]})",
        "probe",
        np.maximum(lat, 0.0),
        file=str(path),
        mapping=mapping,
        mapping_detected=parse_probe_spec(text).mapping is None,
        source_shape=list(img.shape[:2]),
    )


# ===================================================================================== published data
RH2001_GRACE_L2 = np.array(
    [
        [0.79, 0.44, 0.54],  # L00
        [0.39, 0.35, 0.60],  # L1,-1
        [-0.34, -0.18, -0.27],  # L10
        [-0.29, -0.06, 0.01],  # L11
        [-0.11, -0.05, -0.12],  # L2,-2
        [-0.26, -0.22, -0.47],  # L2,-1
        [-0.16, -0.09, -0.15],  # L20
        [0.56, 0.21, 0.14],  # L21
        [0.21, -0.05, -0.30],  # L22
    ]
)
"""Ramamoorthi & Hanrahan 2001 ("An efficient representation for irradiance environment maps", SIGGRAPH),
the table of lighting coefficients L_lm (RGB) for Grace Cathedral, 2 decimals, index l(l + 1) + m, real SH
without the Condon–Shortley phase; in their frame (`rh2001_frame`)."""


RH2001_FROM_WORLD = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
"""R&H's (x, y, z) of rtfit's world direction w of ``probe-grace`` (pbrt-v2's EXR of the same capture):
(x, y, z)_RH = (w_y, w_z, −w_x). A signed permutation of determinant −1 (a mirror: R&H's ``prefilter.c``
builds its frame from image rows and columns of the angular map), found as the one of the 48 signed
permutations that matches all nine RGB coefficients (every other one misses by ≥ 0.39 with its own fitted
exposure); R&H's frame is
+Y up like the world's +Z."""
RH2001_TOLERANCE = 0.01
"""|L_lm − table| allowed after the fitted exposure: the table's rounding (0.005) plus 0.005 for the EXR's
half floats and the resampling. Measured: 0.0068 (L20, green) at the file's 512 rows, 0.0058 at 64 rows."""
