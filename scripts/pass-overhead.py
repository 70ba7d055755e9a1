"""Where a radiance pass's time goes beyond ``mi.render``'s (issue 21 §3), on any variant, in one process.

    python3 scripts/pass-overhead.py [VARIANT] [RES:SPP ...]
    python3 scripts/pass-overhead.py cuda_ad_rgb 256:256 1024:64 1024:256

For the diffuse experiment's scene (α = 5° sun + sky, ``direct``) at each RES² × SPP:

1. rtfit's `radiance_pass` beside ``mi.render`` with the same integrator, side by side (best of 5 rounds,
   alternating, fresh seeds; both read back to the host), and their ratio;
2. the pass's launches from Dr.Jit's kernel history: count, whether each was a kernel-cache hit, and the
   device time by kind (sampling kernels, reductions, memsets, the packing of mean and variance);
3. the host cost of one chunk: a 64² × 16 spp pass cut into 64 chunks (``MAX_LANES`` = 1024), whose kernels
   are tiny, so its time per chunk is the tracing, code generation, cache look-up and launch of one chunk.

A pass of k chunks pays (3) k times; if (1) stays below 0.9 with (2) showing no more than the sampling
kernels' device time, (3) × k is what is left.
"""

import sys
import time
from collections import defaultdict

import drjit as dr

from rtfit.experiments.cost import stock_render
from rtfit.experiments.diffuse import case_scene
from rtfit.reference import estimators
from rtfit.reference.build import load_mitsuba_scene


def best_of(calls, rounds: int = 5) -> list[float]:
    for f in calls:  # warm-up: compilation or cache load
        f(0)
    best = [float("inf")] * len(calls)
    for k in range(1, rounds + 1):
        for i, f in enumerate(calls):
            dr.sync_thread()
            t0 = time.perf_counter()
            f(k)
            dr.sync_thread()
            best[i] = min(best[i], time.perf_counter() - t0)
    return best


def history(call) -> str:
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        call()
        dr.sync_thread()
        h = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    by_kind = defaultdict(lambda: [0, 0.0])
    misses = 0
    for k in h:
        kind = str(k["type"]).split(".")[-1]
        by_kind[kind][0] += 1
        by_kind[kind][1] += float(k.get("execution_time", 0.0))
        misses += kind == "JIT" and not k.get("cache_hit")
    parts = ", ".join(f"{kind} ×{n}: {ms:.2f} ms" for kind, (n, ms) in sorted(by_kind.items()))
    return f"{len(h)} launches ({parts}); {misses} JIT kernels built anew"


def measure(variant: str, res: int, spp: int) -> None:
    mi, ms = load_mitsuba_scene(case_scene(5.0, 0.2, res), variant)
    stock = stock_render(mi, ms, spp)
    t_ref, t_stock = best_of([lambda s: estimators.radiance_pass(mi, ms, spp, s), stock])
    n = res * res * spp
    chunks = -(-res * res // max(1, estimators.MAX_LANES // spp))
    print(
        f"{res}² × {spp} spp ({chunks} chunks): rtfit {n / t_ref / 1e6:.1f} Msamples/s "
        f"({t_ref * 1e3:.2f} ms), mi.render {n / t_stock / 1e6:.1f} ({t_stock * 1e3:.2f} ms), "
        f"ratio {t_stock / t_ref:.3f}",
        flush=True,
    )
    print("  rtfit pass:", history(lambda: estimators.radiance_pass(mi, ms, spp, 99)), flush=True)
    print("  mi.render: ", history(lambda: stock(99)), flush=True)


def main(argv):
    variant = argv[1] if len(argv) > 1 else "llvm_ad_rgb"
    sizes = [tuple(int(x) for x in a.split(":")) for a in argv[2:]] or [(256, 256), (1024, 64)]
    for res, spp in sizes:
        measure(variant, res, spp)
    mi, ms = load_mitsuba_scene(case_scene(5.0, 0.2, 64), variant)
    saved = estimators.MAX_LANES
    estimators.MAX_LANES = 1024
    try:
        (t,) = best_of([lambda s: estimators.radiance_pass(mi, ms, 16, s)], rounds=3)
    finally:
        estimators.MAX_LANES = saved
    print(f"host cost per chunk (64² × 16 spp in 64 chunks): {t / 64 * 1e3:.2f} ms", flush=True)


if __name__ == "__main__":
    main(sys.argv)
