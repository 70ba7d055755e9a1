"""Monte Carlo estimators run through Mitsuba, one pass at a time, with their own variance.

Convention (the one every comparison in rtfit uses): **point sampling at pixel centres**. A pixel's
reference value is the radiance along the single camera ray through the pixel centre
((i + 0.5)/W, (j + 0.5)/H), estimated with ``spp`` independent samples of the scene's integrator;
the G-buffer an approximation is evaluated on is the first hit of that same ray. Mitsuba's
``mi.render`` would instead average each pixel's footprint (its reconstruction filter), which
differs from a point-sampled G-buffer evaluation wherever the image has gradients (terminators,
silhouettes; see the Mitsuba/Dr.Jit facts note §13). With one ray per pixel both sides measure the
same thing, so an exact approximation leaves only the reference's noise (unit-spread z-scores).

Every pass returns, per element, the sample mean and the unbiased sample variance of its ``spp``
iid samples (Mitsuba's ``independent`` sampler: stratified samplers would bias that variance).
Sums are taken in float64 on the device, so millions of samples never lose precision in a float32
accumulator (mitsuba2 #82, mitsuba3 #1335); they are reduced inside the kernel that draws the samples
and stay on the device until the pass is done (`PassMoments`: the mean and variance are computed there
and read back in one copy per pass), so a pass costs what ``mi.render`` costs for the same integrator.

Irradiance probes estimate E(x, n) = ∫_Ω L_i(x, ω) max(n·ω, 0) dω at given points and normals
with Mitsuba's own emitter sampling and ray tracing: emitter sampling and cosine-weighted
direction sampling combined by multiple importance sampling (power heuristic), as Mitsuba's
``direct`` integrator does for a white Lambertian receiver; ``transport="global"`` instead takes
the full path-traced radiance along cosine-sampled directions (E = π · E_cos[L_path]).

This module holds the passes (`radiance_pass`, `irradiance_pass`, their lanes, chunks and seeds,
`PassMoments`); the G-buffer (pixel-centre rays and their first hits: `rtfit.reference.first_hits`), the
probes' device arrays (`rtfit.reference.device_arrays`) and the irradiance pass's per-lane estimators
(`rtfit.reference.irradiance_integrands`) have rooms of their own; the first two's names are re-exported
here (`__all__`).
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import drjit as dr
import numpy as np
from numpy.typing import DTypeLike

from .budget import ArmedMedia, counters
from .device_arrays import DeviceProbes, as_device_probes, device_components, device_probes, device_vectors
from .first_hits import (
    MAX_PASS_THROUGH,
    GBuffer,
    first_hit_shapes,
    first_surface,
    gbuffer,
    gbuffer_points,
    is_pass_through,
    pixel_rays,
    shape_has_uv,
    uv_tangents,
)
from .irradiance_integrands import bounce_irradiance, direct_irradiance, global_irradiance
from .variants import backend_of

__all__ = [
    "MAX_LANES",
    "MAX_LANES_CUDA",
    "MAX_PASS_THROUGH",
    "DeviceProbes",
    "GBuffer",
    "PassMoments",
    "PassResult",
    "as_device_probes",
    "channel_moments",
    "check_spp",
    "chunk_ranges",
    "default_reduction",
    "device_components",
    "device_probes",
    "device_vectors",
    "first_hit_shapes",
    "first_surface",
    "gbuffer",
    "gbuffer_points",
    "irradiance_pass",
    "is_pass_through",
    "launch_identity",
    "mean_var",
    "moments",
    "pass_max_lanes",
    "point_chunks",
    "radiance_pass",
    "shape_has_uv",
    "sub_seed",
    "uv_tangents",
]

# Lanes per kernel launch: bounded so memory stays small and far from the 2^32 lane limit.
MAX_LANES = 1 << 24
MAX_LANES_CUDA = 1 << 26
"""Lanes per launch of the radiance and per-point passes on the GPU: a 1024² × 64 spp pass in one launch, as
``mi.render`` draws it (each further launch drains and refills the GPU: 4 chunks cost ≈ 0.045 of
``mi.render``'s rate there, docs/benchmarks.md). Its stored samples (`PassMoments`, ``"stored"``) take
2^26 · 4 B = 256 MiB per channel. The CPU keeps `MAX_LANES` (its launches cost nothing comparable)."""


@dataclass(frozen=True)
class PassResult:
    """One independent pass: per-element mean and unbiased sample variance of ``spp`` samples."""

    mean: np.ndarray  # float64 (float32 where the pass was asked to round to it), (H, W, 3) or (N, 3)
    var: np.ndarray  # the same dtype and shape
    spp: int
    seed: int
    seconds: float


def sub_seed(seed: int, *labels) -> int:
    """A 32-bit seed derived from ``seed`` and labels (pass index, chunk index): independent streams."""
    h = hashlib.sha256(repr((int(seed), *labels)).encode()).digest()
    return int.from_bytes(h[:4], "little")


def pass_max_lanes(mi) -> int:
    """Lanes per launch of a radiance or per-point pass on ``mi``'s backend: `MAX_LANES_CUDA` on the GPU,
    `MAX_LANES` on the CPU (the chunks, and with them the sampler streams, depend on it)."""
    return MAX_LANES_CUDA if dr.backend_v(mi.Float) == dr.JitBackend.CUDA else MAX_LANES


def launch_identity(variant: str) -> dict:
    """What a pass cache's key needs of the launch layout for ``variant``: the GPU's passes are cut at
    `MAX_LANES_CUDA` lanes (its chunks seed the sampler streams, so another layout draws other samples); the
    CPU's layout (`MAX_LANES`) is the one its keys have always implied, so it adds nothing (its keys stay)."""
    return {"launch_lanes": MAX_LANES_CUDA} if backend_of(variant) == "cuda" else {}


def chunk_ranges(n_elements: int, spp: int, max_lanes: int | None = None):
    """[start, end) element ranges of at most ``max_lanes`` (default `MAX_LANES`) // ``spp`` elements."""
    per = max(1, (MAX_LANES if max_lanes is None else max_lanes) // spp)
    for start in range(0, n_elements, per):
        yield start, min(n_elements, start + per)


def point_chunks(mi, spp: int, seed: int, columns):
    """The chunks (`chunk_ranges`) of a per-point pass of ``spp`` lanes per point: per chunk, ``(a,
    sampler, gathered)`` — ``a`` its first point, ``sampler`` an ``independent`` sampler seeded with
    ``sub_seed(seed, "chunk", k)`` for the chunk's lanes, ``gathered`` each of ``columns`` (pairs of a Mitsuba
    type and an (N, 3) array, e.g. ``(mi.Point3f, points)``, or an array already of that type on the device)
    gathered per lane. The columns go to the device once per pass (or once per reference, `DeviceProbes`) and
    are gathered at an opaque chunk offset, so every chunk after the first reuses the first one's kernel
    (issue 21 §3)."""
    on_device = [(t, arr if isinstance(arr, t) else device_vectors(mi, t, arr)) for t, arr in columns]
    n_points = dr.width(on_device[0][1])
    sampler = mi.load_dict({"type": "independent"})
    for k, (a, b) in enumerate(chunk_ranges(n_points, spp, pass_max_lanes(mi))):
        sampler.seed(sub_seed(seed, "chunk", k), (b - a) * spp)
        idx = dr.arange(mi.UInt32, (b - a) * spp) // spp + dr.opaque(mi.UInt32, a)
        yield a, sampler, [dr.gather(t, v, idx) for t, v in on_device]


class PassMoments:
    """Per-element float64 sums Σ v and Σ v² of ``channels`` per-lane values, accumulated **on the device**
    over every chunk of a pass, then turned into the pass's mean and unbiased variance on the device and
    read back to the host once (`result`).

    Layout: two float64 arrays ``s`` and ``q`` of elements × channels values, element-major (slot
    e·channels + c holds element e's channel c). Chunk k of a pass draws ``spp`` samples for each of its
    elements [a, b): lanes [i·spp, (i + 1)·spp) are element a + i's samples. `add` sums them in one of two
    ways (``reduction``; default `default_reduction` of the backend):

    * ``"atomic"`` (CPU): inside the kernel that computes them, per lane and channel a float64 atomic add of
      v and of v² into the element's slots (``dr.scatter_reduce``, ``ReduceMode.Local``: the lanes of a SIMD
      packet that share an element are summed first, then one atomic per packet). One kernel per chunk.
    * ``"stored"`` (GPU): the sampling kernel only stores its float32 samples (12 B per lane for RGB), then a
      reduction kernel of G = min(32, spp) lanes per element sums them: lane t of element e adds samples
      t, t + G, t + 2G, … of e in float64 (adjacent lanes read adjacent samples: coalesced), the G lanes
      of a warp are reduced in registers and one atomic per warp, element and channel lands in ``s`` and
      ``q``. Measured on an H200 (1024² × 64 spp, `direct`): the sampling kernel's 6 float64 atomics per
      lane cost ≈ 1.1 ms of its 10.7 ms (the sampling kernel alone 9.3 ms, ``mi.render`` 9.65 ms), the
      reduction ≈ 0.3 ms (docs/benchmarks.md). Two kernels per chunk.

    The chunk's first element is an opaque device value, not a literal of the kernel text, so every chunk of
    every pass with one ``spp`` and channel count is the same kernel(s), found in Dr.Jit's kernel cache.
    Per pass: one clear of each array, the chunk kernels (no per-chunk sums or copies to the host, and on
    the CPU no per-thread copies to clear and reduce), then one kernel that computes every element's mean
    and variance (`result`) and one device→host copy. No per-element work happens on the host (issue 21 §3).

    Precision: float64 per sample (the squares of float32 samples are exact in float64); the sums are
    float64 additions of the same values in an order set by the reduction (per-lane partial sums, the
    packet/warp pre-reduction, the atomics' arrival: threads or warps whose lanes share an element land in
    an unspecified order), so a re-render can differ by ~1 ulp of float64 (1e-16 relative; a pass loaded
    from the cache is bit-identical); any order is within Higham's bound (spp − 1)·u·Σ|v| of the exact sum,
    which tests/test_pass_moments.py checks against NumPy's pairwise sums and two-pass variance of the same
    samples, for both reductions. mean = Σv/n and var = max(Σv² − Σv·mean, 0)/(n − 1) are the operations
    NumPy does (`mean_var`; the divisors are opaque, since Dr.Jit turns a division by a literal into a
    multiplication by its reciprocal): bit-identical on the CPU (tested); a GPU compiler that fuses Σv·mean
    into the subtraction (an FMA) changes var by at most 1 ulp of Σv², within the bound the reordered sums
    already carry (docs/benchmarks.md).

    ``dtype`` of `result`: float64 (default), or float32 — the mean and variance rounded to float32 on the
    device (round to nearest even, as NumPy's ``astype``) before the copy, halving the bytes copied to the
    host; the EXR pass cache stores float32 (`rtfit.reference.cache`), so for its passes the values are
    bit-identical either way."""

    REDUCE_MODE = dr.ReduceMode.Local
    """Packet/warp pre-reduction, then atomics. On the CPU, Dr.Jit's default for targets of ≤ 2^20 slots
    (``Expand``) gives every worker thread its own copy of the target: with per-chunk sums that was 6
    memsets and 6 reductions per chunk, 1–2 % of a 1024² × 64 spp pass on 2 cores (docs/benchmarks.md)."""

    REDUCTIONS = ("atomic", "stored")
    WARP = 32
    """Lanes per element of the ``"stored"`` reduction (at most; ``spp`` when smaller): one CUDA warp."""

    def __init__(self, mi, n_elements: int, channels: int, spp: int, reduction: str | None = None):
        self.mi, self.n, self.channels, self.spp = mi, int(n_elements), int(channels), int(spp)
        self.reduction = default_reduction(mi) if reduction is None else reduction
        if self.reduction not in self.REDUCTIONS:
            raise ValueError(f"reduction must be one of {self.REDUCTIONS} (got {reduction!r})")
        self.s = dr.zeros(mi.Float64, self.n * self.channels)
        self.q = dr.zeros(mi.Float64, self.n * self.channels)

    def add(self, first: int, values) -> None:
        """Add one chunk: ``values`` (one per-lane Float array per channel) are the samples of elements
        [first, first + lanes/spp), all ``spp`` of them (chunks partition the elements: each element's
        samples are added once). Launches the kernel(s) that compute and sum them."""
        if len(values) != self.channels:
            raise ValueError(f"expected {self.channels} channels (got {len(values)})")
        lanes = dr.width(values[0])
        m = lanes // self.spp
        if lanes % self.spp or first < 0 or first + m > self.n:
            raise ValueError(f"a chunk of {lanes} lanes at element {first} overruns {self.n} × {self.spp}")
        if self.reduction == "atomic":
            self._add_atomic(first, lanes, values)
        else:
            self._add_stored(first, m, values)

    def _accumulate(self, element, sums, squares, mode) -> None:
        """Scatter-add per-lane float64 partial sums of each channel into the elements' slots."""
        slot = element * self.channels
        for c, (sv, qv) in enumerate(zip(sums, squares, strict=True)):
            dr.scatter_reduce(dr.ReduceOp.Add, self.s, sv, slot + c, mode=mode)
            dr.scatter_reduce(dr.ReduceOp.Add, self.q, qv, slot + c, mode=mode)

    def _add_atomic(self, first: int, lanes: int, values) -> None:
        mi = self.mi
        element = dr.arange(mi.UInt32, lanes) // self.spp + dr.opaque(mi.UInt32, first)
        v64 = [mi.Float64(v) for v in values]
        self._accumulate(element, v64, [v * v for v in v64], self.REDUCE_MODE)
        dr.eval()  # one kernel: the samples and all 2·C atomic sums

    def _add_stored(self, first: int, m: int, values) -> None:
        mi, spp = self.mi, self.spp
        stored = [mi.Float(v) for v in values]
        dr.eval(*stored)  # kernel 1: the samples, stored (float32, element-major)
        g = min(self.WARP, spp)
        lane = dr.arange(mi.UInt32, m * g)
        local, t = lane // g, lane % g
        base = local * spp
        n_samples = dr.opaque(mi.UInt32, spp)
        zero = mi.Float64(0.0)

        def more(k, *_):
            return k < n_samples

        c = self.channels

        def step(k, *acc):  # acc: c partial sums Σv, then c partial sums Σv²
            v = [mi.Float64(dr.gather(mi.Float, x, base + k)) for x in stored]
            sums = [a + x for a, x in zip(acc[:c], v, strict=True)]
            squares = [a + x * x for a, x in zip(acc[c:], v, strict=True)]
            return (k + g, *sums, *squares)

        out = dr.while_loop((t, *[zero] * (2 * c)), more, step)
        self._accumulate(
            local + dr.opaque(mi.UInt32, first), out[1 : 1 + c], out[1 + c :], dr.ReduceMode.Local
        )
        dr.eval()  # kernel 2: G lanes per element, one warp-reduced atomic per element and channel

    def _packed(self, stats, dtype: DTypeLike):
        """``stats(s, q)``'s two results for every element and channel, as one array of 2·elements·channels
        values ([first][element][channel] then [second][element][channel]) computed by one kernel and read
        back in one device→host copy, shaped (2, elements, channels)."""
        mi, nc = self.mi, self.n * self.channels
        j = dr.arange(mi.UInt32, 2 * nc)
        second = j >= nc
        k = dr.select(second, j - nc, j)
        first_value, second_value = stats(dr.gather(mi.Float64, self.s, k), dr.gather(mi.Float64, self.q, k))
        out = dr.select(second, second_value, first_value)
        if np.dtype(dtype) == np.float32:
            out = mi.Float(out)  # round to nearest even on the device: NumPy's astype(float32)
        elif np.dtype(dtype) != np.float64:
            raise ValueError(f"dtype must be float32 or float64 (got {dtype})")
        return np.asarray(out).reshape(2, self.n, self.channels)

    def sums(self) -> tuple[np.ndarray, np.ndarray]:
        """Σ v and Σ v², each (elements, channels) float64, in one device→host copy."""
        a = self._packed(lambda s, q: (s, q), np.float64)
        return a[0], a[1]

    def result(self, dtype: DTypeLike = np.float64) -> tuple[np.ndarray, np.ndarray]:
        """Per-element mean and unbiased sample variance, each an (elements, channels) array of ``dtype``
        (float64 or float32): `mean_var`'s formula evaluated in float64 on the device, rounded to ``dtype``
        there, copied to the host once (no conversion on the host)."""
        mi = self.mi
        n = dr.opaque(mi.Float64, self.spp)
        n1 = dr.opaque(mi.Float64, self.spp - 1)

        def stats(s, q):
            mean = s / n
            return mean, dr.maximum(q - s * mean, 0.0) / n1

        a = self._packed(stats, dtype)
        return a[0], a[1]


def default_reduction(mi) -> str:
    """`PassMoments`' reduction on ``mi``'s backend: ``"stored"`` on the GPU, ``"atomic"`` on the CPU."""
    return "stored" if dr.backend_v(mi.Float) == dr.JitBackend.CUDA else "atomic"


def channel_moments(mi, dr, channels, spp: int):
    """Per-element float64 sums Σ v and Σ v² of each per-lane value in ``channels`` (lanes grouped by
    ``spp``), arrays of shape (elements, channels): one `PassMoments` chunk (one kernel launch, one
    device→host copy). Passes with several chunks use `PassMoments` directly (one copy per pass)."""
    acc = PassMoments(mi, dr.width(channels[0]) // spp, len(channels), spp)
    acc.add(0, channels)
    return acc.sums()


def moments(mi, dr, value, spp: int):
    """Per-element float64 sums of a per-lane RGB value and of its square (`channel_moments` of its three
    channels), each of shape (elements, 3)."""
    return channel_moments(mi, dr, [value[c] for c in range(3)], spp)


def mean_var(s: np.ndarray, q: np.ndarray, n: int):
    """Mean Σv/n and unbiased variance max(Σv² − Σv·mean, 0)/(n − 1) of n samples from their sums."""
    mean = s / n
    var = np.maximum(q - s * mean, 0.0) / (n - 1)
    return mean, var


def check_spp(spp: int):
    if spp < 2:
        raise ValueError(f"spp per pass must be >= 2 to estimate the variance (got {spp})")


# ----------------------------------------------------------------------------------- radiance pass
def radiance_pass(
    mi,
    mi_scene,
    spp: int,
    seed: int,
    dtype: DTypeLike = np.float64,
    *,
    integrator=None,
    sensor=None,
    footprint: str = "centre",
) -> PassResult:
    """Point-sampled radiance at every pixel centre with the scene's own integrator (or ``integrator``, a
    loaded Mitsuba integrator) through its first sensor (or ``sensor``). ``dtype``: the precision (float64
    or float32) the float64 mean and variance are rounded to on the device before the copy to the host, and
    the dtype of the arrays returned (`PassMoments.result`). ``footprint="box"``: each sample's ray through a
    uniformly drawn point of its pixel instead (the pixel's area average: a film with a box filter, an
    antialiased frame; `rtfit compare`)."""

    check_spp(spp)
    t0 = time.perf_counter()
    sensor = sensor if sensor is not None else mi_scene.sensors()[0]
    width, height = sensor.film().crop_size()
    integrator = integrator if integrator is not None else mi_scene.integrator()
    if footprint not in ("centre", "box"):
        raise ValueError(f"footprint {footprint!r}: expected 'centre' or 'box'")
    if mi.variant().startswith("scalar"):
        if footprint != "centre":
            raise ValueError("scalar variants render pixel centres only")
        mean, var = _radiance_scalar(mi, mi_scene, sensor, integrator, width, height, spp, seed)
        return PassResult(mean, var, spp, seed, time.perf_counter() - t0)
    n_pixels = width * height
    acc = PassMoments(mi, n_pixels, 3, spp)
    sampler = mi.load_dict({"type": "independent"})
    media = counters(mi_scene)
    for k, (a, b) in enumerate(chunk_ranges(n_pixels, spp, pass_max_lanes(mi))):
        sampler.seed(sub_seed(seed, "chunk", k), (b - a) * spp)
        offset = sampler.next_2d() if footprint == "box" else None
        ray, weight = pixel_rays(mi, dr, sensor, width, a, b - a, spp, offset)
        with ArmedMedia(media, mi.UInt32, (b - a) * spp) as armed:
            if media:  # lane index for the media's event counts (rtfit.reference.budget)
                ray.time = mi.Float(dr.arange(mi.UInt32, (b - a) * spp))
            value, _, _ = integrator.sample(mi_scene, sampler, ray, sensor.get_medium(), True)
            value = value * weight
            acc.add(a, [value[c] for c in range(3)])
            armed.check()
    mean, var = acc.result(dtype)
    shape = (height, width, 3)
    return PassResult(mean.reshape(shape), var.reshape(shape), spp, seed, time.perf_counter() - t0)


def _radiance_scalar(mi, mi_scene, sensor, integrator, width, height, spp, seed):
    """scalar_* variants: one Python call per sample (slow; for debugging and cross-checks)."""
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(sub_seed(seed, "scalar"))
    s = np.zeros((height, width, 3))
    q = np.zeros((height, width, 3))
    for j in range(height):
        for i in range(width):
            uv = mi.Point2f((i + 0.5) / width, (j + 0.5) / height)
            for _ in range(spp):
                ray, weight = sensor.sample_ray(0.0, 0.5, uv, mi.Point2f(0.5, 0.5))
                value, _, _ = integrator.sample(mi_scene, sampler, ray, sensor.get_medium(), True)
                v = np.array([value[0], value[1], value[2]], dtype=np.float64) * float(weight[0])
                s[j, i] += v
                q[j, i] += v * v
                sampler.advance()
    return mean_var(s, q, spp)


# ---------------------------------------------------------------------------------- irradiance pass
def irradiance_pass(
    mi,
    mi_scene,
    points: np.ndarray | DeviceProbes,
    normals: np.ndarray | None,
    spp: int,
    seed: int,
    transport: str = "direct",
    dtype: DTypeLike = np.float64,
) -> PassResult:
    """Irradiance (W/m², RGB) at ``points`` (N, 3) for unit ``normals`` (N, 3), or at `DeviceProbes` passed as
    ``points`` (``normals`` None: the passes of one reference share one upload); ``dtype`` as in
    `radiance_pass`."""

    check_spp(spp)
    if mi.variant().startswith("scalar"):
        raise ValueError("irradiance probes need a vectorised variant (llvm_ad_rgb or cuda_ad_rgb)")
    if transport not in ("direct", "global", "bounce"):
        raise ValueError(f"transport must be 'direct', 'global' or 'bounce' (got {transport!r})")
    t0 = time.perf_counter()
    probes = as_device_probes(mi, points, normals, normalise=False)
    acc = PassMoments(mi, probes.count, 3, spp)
    columns = [(mi.Point3f, probes.points), (mi.Vector3f, probes.normals)]
    for a, sampler, (p, nrm) in point_chunks(mi, spp, seed, columns):
        if transport == "direct":
            value = direct_irradiance(mi, dr, mi_scene, sampler, p, nrm)
        elif transport == "bounce":
            value = bounce_irradiance(mi, dr, mi_scene, sampler, p, nrm)
        else:
            value = global_irradiance(mi, dr, mi_scene, sampler, p, nrm)
        acc.add(a, [value[c] for c in range(3)])
    mean, var = acc.result(dtype)
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)
