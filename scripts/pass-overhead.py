"""Where a radiance pass's time goes beyond ``mi.render``'s (issue 21 §3), on any variant, in one process.

    python3 scripts/pass-overhead.py [--variant V] [--rounds N] [--baseline COMMIT] [RES:SPP ...]
    python3 scripts/pass-overhead.py --variant cuda_ad_rgb --rounds 11 --baseline a4f68d1 256:256 1024:64

(``--baseline`` also takes a file: ``git show a4f68d1:reference/estimators.py > scratch/est-a4f68d1.py``
where the machine's copy of the checkout has no git history.)

For the diffuse experiment's scene (α = 5° sun + sky, ``direct``) at each RES² × SPP (default: the bench's
256:256 and 1024:64):

1. **Side by side, paired and interleaved:** rtfit's `radiance_pass` as the pass cache runs it (mean and
   variance read back in `REFERENCE_PASS_DTYPE`), the same pass read back in float64, the pass with the
   backend's other `PassMoments` reduction, where the pass has several chunks the same pass in one launch
   (what the chunking costs), on the GPU both reductions in chunks of `MAX_LANES` (2^24) lanes,
   ``mi.render`` with the same integrator and, with ``--baseline``, `radiance_pass` of
   ``reference/estimators.py`` at that commit (loaded from git into this process). One warm-up call each,
   then ``--rounds`` rounds of one call each, the order rotated every round, a fresh seed per round; every
   call ends in host data (``dr.sync_thread`` around it). Printed: each call's median time and samples/s,
   and per round the ratio of its samples/s to ``mi.render``'s of the same round: median [min, max] — on a
   shared machine the spread says how far to trust one run.
2. **Stages** from Dr.Jit's kernel history of one call of each: launches by kind with their device time
   (sampling kernels = JIT launches of a chunk's lanes, or all of ``mi.render``'s; reduction = the stored
   samples' reduction kernels (`PassMoments`, ``stored``); other JIT = copies, packing, ``mi.render``'s film
   development; block reductions; memsets) and the wall time not spent in
   them (tracing, code generation, cache look-ups, launches; on a GPU, device work overlapping the host is
   counted once).
3. **Readback:** the device→host copy of the pass's packed mean and variance (2·pixels·3 values) in float64
   and float32 against ``mi.render``'s image (pixels·3 float32), each copied from an evaluated array (median).
4. **Statistics:** the float32 and float64 readbacks agree (float32 = float64 rounded); with ``--baseline``
   the baseline pass of the same seed gives the same means and variances (largest difference in float64 ulp).
5. **Host cost of one chunk:** a 64² × 16 spp pass cut into 64 chunks (``MAX_LANES`` = 1024), whose kernels
   are tiny: its time per chunk is the tracing, code generation, cache look-up and launch of one chunk.
"""

import argparse
import dataclasses
import importlib.util
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import drjit as dr
import numpy as np

from rtfit.experiments.cost import stock_render
from rtfit.reference import estimators
from rtfit.reference.build import load_mitsuba_scene
from rtfit.reference.cache import REFERENCE_PASS_DTYPE
from rtfit.scenes import ConstantEnv, library_path, load_scene

REPO = Path(__file__).resolve().parent.parent


def baseline_estimators(commit: str):
    """``reference/estimators.py`` at ``commit`` (or the file at that path, for a copy without git history)
    as a module of the package ``rtfit.reference`` (its relative imports resolve to this checkout's
    modules)."""
    if Path(commit).is_file():
        src = Path(commit).read_text()
    else:
        show = ["git", "show", f"{commit}:reference/estimators.py"]
        src = subprocess.run(show, cwd=REPO, check=True, capture_output=True, text=True).stdout
    name = f"rtfit.reference.estimators_at_{Path(commit).stem.replace('.', '_').replace('-', '_')}"
    spec = importlib.util.spec_from_loader(name, loader=None)
    assert spec is not None
    mod = importlib.util.module_from_spec(spec)
    mod.__package__ = "rtfit.reference"
    sys.modules[name] = mod
    exec(compile(src, f"{commit}:reference/estimators.py", "exec"), mod.__dict__)
    return mod


def timed(call, seed: int) -> float:
    dr.sync_thread()
    t0 = time.perf_counter()
    call(seed)
    dr.sync_thread()
    return time.perf_counter() - t0


def side_by_side(calls: dict, samples: int, rounds: int, stock: str) -> None:
    names = list(calls)
    for name in names:  # warm-up: compilation or cache load
        calls[name](0)
    times = {name: [] for name in names}
    for k in range(1, rounds + 1):
        order = names[k % len(names) :] + names[: k % len(names)]
        for name in order:
            times[name].append(timed(calls[name], k))
    for name in names:
        t = statistics.median(times[name])
        line = f"  {name:34s} median {t * 1e3:9.2f} ms  {samples / t / 1e6:9.1f} Msamples/s"
        if name != stock:
            r = [s / x for x, s in zip(times[name], times[stock], strict=True)]
            line += f"  vs mi.render {statistics.median(r):.3f} [{min(r):.3f}, {max(r):.3f}]"
        print(line, flush=True)


def stages(call, chunk_lanes: set[int], reduction_lanes: set[int]) -> str:
    call(0)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        wall = timed(call, 99)
        h = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    by_kind = defaultdict(lambda: [0, 0.0])
    misses = 0
    for k in h:
        kind = str(k["type"]).split(".")[-1]
        if kind == "JIT":
            size = int(k.get("size", 0))
            kind = (
                "sampling" if size in chunk_lanes else "reduction" if size in reduction_lanes else "other JIT"
            )
            misses += not k.get("cache_hit")
        by_kind[kind][0] += 1
        by_kind[kind][1] += float(k.get("execution_time", 0.0))
    device = sum(ms for _, ms in by_kind.values())
    parts = ", ".join(f"{kind} ×{n} {ms:.2f} ms" for kind, (n, ms) in sorted(by_kind.items()))
    return (
        f"wall {wall * 1e3:.2f} ms: {parts}; not on the device {wall * 1e3 - device:.2f} ms; "
        f"{misses} kernels built anew"
    )


def readback(mi, count: int, dtype) -> float:
    t = mi.Float64 if dtype == np.float64 else mi.Float
    a = dr.arange(t, count)
    dr.eval(a)
    times = []
    for _ in range(9):
        b = a + 1.0
        dr.eval(b)
        dr.sync_thread()
        t0 = time.perf_counter()
        np.asarray(b)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


@contextmanager
def launch_lanes(lanes: int):
    """Passes launched in chunks of at most ``lanes`` lanes on either backend (both lane limits set)."""
    saved = estimators.MAX_LANES, estimators.MAX_LANES_CUDA
    estimators.MAX_LANES = estimators.MAX_LANES_CUDA = lanes
    try:
        yield
    finally:
        estimators.MAX_LANES, estimators.MAX_LANES_CUDA = saved


@contextmanager
def reduction(name: str):
    """Passes whose `PassMoments` use the reduction ``name`` (``atomic`` or ``stored``) on either backend."""
    saved = estimators.default_reduction
    estimators.default_reduction = lambda mi: name
    try:
        yield
    finally:
        estimators.default_reduction = saved


def variant_pass(mi, ms, spp: int, seed: int, lanes: int | None = None, name: str | None = None):
    """`radiance_pass` as cached, in chunks of ``lanes`` lanes and with the reduction ``name`` (None: the
    backend's own). Other chunks draw other sampler streams: not a drop-in, it prices the choice."""
    with (
        launch_lanes(lanes or estimators.pass_max_lanes(mi)),
        reduction(name or estimators.default_reduction(mi)),
    ):
        return estimators.radiance_pass(mi, ms, spp, seed, REFERENCE_PASS_DTYPE)


def ulp_diff(a: np.ndarray, b: np.ndarray) -> float:
    scale = np.spacing(np.maximum(np.abs(a), np.abs(b)).max())
    return float(np.max(np.abs(a - b)) / scale) if scale > 0 else 0.0


def case_scene(res: int):
    """The diffuse scene of the numbers above: scenes/library/diffuse_sphere_a5.toml (α = 5° sun, E⊥ = π)
    with a constant sky of radiance 0.2, at res²."""
    base = load_scene(library_path("diffuse_sphere_a5"))
    camera = dataclasses.replace(base.camera, width=res, height=res)
    return dataclasses.replace(base, camera=camera, lights=(*base.lights, ConstantEnv(radiance=(0.2,) * 3)))


def measure(variant: str, res: int, spp: int, rounds: int, baseline) -> None:
    mi, ms = load_mitsuba_scene(case_scene(res), variant)
    per = max(1, estimators.pass_max_lanes(mi) // spp)
    chunks = -(-res * res // per)
    samples = res * res * spp
    print(f"{res}² × {spp} spp ({chunks} chunks, {samples} samples), {variant}, {rounds} rounds:", flush=True)
    cached = f"rtfit ({np.dtype(REFERENCE_PASS_DTYPE).name} readback, as cached)"
    calls: dict[str, Callable[[int], object]] = {
        cached: lambda s: estimators.radiance_pass(mi, ms, spp, s, REFERENCE_PASS_DTYPE),
        "rtfit (float64 readback)": lambda s: estimators.radiance_pass(mi, ms, spp, s, np.float64),
    }
    own = estimators.default_reduction(mi)
    other = next(r for r in estimators.PassMoments.REDUCTIONS if r != own)
    calls[f"rtfit, {other} reduction"] = lambda s: variant_pass(mi, ms, spp, s, name=other)
    if chunks > 1:
        calls["rtfit, one launch (other streams)"] = lambda s: variant_pass(mi, ms, spp, s, lanes=samples)
    if estimators.pass_max_lanes(mi) != estimators.MAX_LANES and samples > estimators.MAX_LANES:
        for r in estimators.PassMoments.REDUCTIONS:
            calls[f"rtfit, {r}, 2^24-lane chunks"] = lambda s, r=r: variant_pass(
                mi, ms, spp, s, estimators.MAX_LANES, r
            )
    if baseline is not None:
        calls["rtfit baseline"] = lambda s: baseline.radiance_pass(mi, ms, spp, s)
    stock = stock_render(mi, ms, spp)
    calls["mi.render, same integrator"] = stock
    side_by_side(calls, samples, rounds, "mi.render, same integrator")
    px = res * res
    for name, call in calls.items():
        chunk_sizes = {
            b - a for m in (estimators.MAX_LANES, samples) for a, b in estimators.chunk_ranges(px, spp, m)
        }
        lanes = {n * spp for n in chunk_sizes} | {samples}
        reducing = {n * min(estimators.PassMoments.WARP, spp) for n in chunk_sizes}
        print(f"  stages, {name}: {stages(call, lanes, reducing)}", flush=True)
    rb = {
        "float64 mean+var": readback(mi, 2 * px * 3, np.float64),
        "float32 mean+var": readback(mi, 2 * px * 3, np.float32),
        "float32 image (mi.render)": readback(mi, px * 3, np.float32),
    }
    print("  readback: " + ", ".join(f"{k} {v * 1e3:.2f} ms" for k, v in rb.items()), flush=True)
    r32 = estimators.radiance_pass(mi, ms, spp, 7, np.float32)
    r64 = estimators.radiance_pass(mi, ms, spp, 7, np.float64)
    same32 = np.array_equal(r32.mean, r64.mean.astype(np.float32)) and np.array_equal(
        r32.var, r64.var.astype(np.float32)
    )
    line = f"  statistics: float32 readback == float32(float64 readback): {same32}"
    if baseline is not None:
        rb_ = baseline.radiance_pass(mi, ms, spp, 7)
        line += (
            f"; vs baseline, same seed: mean bit-identical {np.mean(rb_.mean == r64.mean):.4%} of values, "
            f"largest difference {ulp_diff(rb_.mean, r64.mean):.2f} ulp of the largest mean; variance "
            f"{np.mean(rb_.var == r64.var):.4%}, {ulp_diff(rb_.var, r64.var):.2f} ulp of the largest; "
            f"stored float32 identical {np.mean(rb_.mean.astype(np.float32) == r32.mean):.4%} (mean)"
        )
    print(line, flush=True)


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sizes", nargs="*", default=["256:256", "1024:64"])
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--rounds", type=int, default=11)
    ap.add_argument(
        "--baseline", help="a commit (or a file) whose reference/estimators.py runs beside this one's"
    )
    args = ap.parse_args(argv[1:])
    baseline = baseline_estimators(args.baseline) if args.baseline else None
    for size in args.sizes:
        res, spp = (int(x) for x in size.split(":"))
        measure(args.variant, res, spp, args.rounds, baseline)
    mi, ms = load_mitsuba_scene(case_scene(64), args.variant)
    with launch_lanes(1024):
        call = lambda s: estimators.radiance_pass(mi, ms, 16, s, REFERENCE_PASS_DTYPE)  # noqa: E731
        call(0)
        t = statistics.median(timed(call, s) for s in range(1, 6))
    print(f"host cost per chunk (64² × 16 spp in 64 chunks): {t / 64 * 1e3:.2f} ms", flush=True)


if __name__ == "__main__":
    main(sys.argv)
