"""bounded_lm against SciPy's least_squares(method="trf", x_scale="jac", bounds, jac) on the problems
bounded_lm solves (issue 37): the sdf-occlusion family's two Evans fits (stage 1: (log B, c_i) on fixed
terms D_i at a grid of (α, base); stage 2: the continuous fit through the Dr.Jit kernel, exact and noisy
synthetic targets on the sphere-on-plane scene of tests/test_sdf_fit.py) and the small problems of
tests/test_bounded_lm.py. Prints, per problem and optimiser: cost ½‖r‖², max |Δx| between the two,
iterations, calls of fun (residuals+Jacobian), wall seconds (best of ``--repeat``).

    .venv/bin/python scripts/bench-bounded-lm.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rtfit.experiments.sdf_occlusion_fit import (
    EvansFitData,
    evans_fit_bounds,
    evans_fit_residuals,
    evans_param_names,
    evans_value_and_slope,
)
from rtfit.fitting import bounded_lm
from rtfit.realtime.sdf_occlusion import AnalyticSDF, EvansParams, evans_occlusion, evans_terms
from tests.test_sdf_fit import INIT, SPHERE_PLANE, TRUE, VOXEL, _sphere_plane_points, _synthetic


def scipy_trf(fun, x0, lo, hi, max_nfev=None):
    """least_squares with fun returning (r, J): one call per point (the Jacobian comes with the residuals)."""
    memo = {}
    calls = [0]

    def both(x):
        key = x.tobytes()
        if key not in memo:
            memo.clear()
            memo[key] = fun(x)
            calls[0] += 1
        return memo[key]

    x0 = np.clip(np.asarray(x0, np.float64), lo, hi)
    res = least_squares(
        lambda x: both(x)[0],
        x0,
        jac=lambda x: both(x)[1],
        bounds=(lo, hi),
        method="trf",
        x_scale="jac",
        max_nfev=max_nfev,
    )
    return {
        "x": res.x,
        "ssr": 2 * res.cost,
        "iterations": res.njev,
        "evaluations": calls[0],
        "msg": res.message,
    }


def timed(f, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t0)
    return out, best


def problems():
    # tests/test_bounded_lm.py: a line (free / slope on a bound), an exponential from far off
    rng = np.random.default_rng(0)
    t = np.linspace(0, 1, 50)
    y = 2.0 * t - 0.5 + rng.normal(0, 0.01, 50)
    a = np.column_stack([t, np.ones_like(t)])
    line = lambda p: (a @ p - y, a)  # noqa: E731
    yield "line, free", line, [0.0, 0.0], np.array([-10.0, -10]), np.array([10.0, 10])
    yield "line, slope<=1.5", line, [0.0, 0.0], np.array([-10.0, -10]), np.array([1.5, 10])
    te = np.linspace(0.0, 3.0, 80)
    ye = 1.7 * np.exp(-0.8 * te)

    def expo(p):
        e = np.exp(-p[1] * te)
        return p[0] * e - ye, np.column_stack([e, -p[0] * te * e])

    yield "exp a·e^-bt", expo, [0.5, 3.0], np.array([0.0, 0.0]), np.array([10.0, 10.0])
    yield "exp, b>=1.2 active", expo, [0.5, 3.0], np.array([0.0, 1.2]), np.array([10.0, 10.0])

    n = 4
    lo, hi = evans_fit_bounds(n)
    for noise in (0.0, 0.01, "study size"):
        if noise == "study size":  # m ≈ 4 scenes × FIT_POINTS = 8192 points, σ = 0.01
            pts, nrm = _sphere_plane_points(4400, 2)
            sdf = AnalyticSDF(SPHERE_PLANE)
            prm = EvansParams(
                n=4,
                base=TRUE["base_voxels"] * VOXEL,
                k=TRUE["k"],
                alpha=TRUE["alpha"],
                weights=TRUE["w"],
                brightness=TRUE["B"],
            )
            y = np.asarray(evans_occlusion(pts, nrm, sdf, prm, backend="numpy"))
            y = y + np.random.default_rng(3).normal(0.0, 0.01, len(y))
            data = [EvansFitData(pts, nrm, sdf, VOXEL, y)]
        else:
            data = _synthetic(noise=noise, seed=1 if noise else 0)
        dd = data[0]
        # stage 1 (fit_free): (log B, c_i) on fixed D_i at three (α, base) points of the grid
        for alpha, base in ((0.0, 0.5), (0.5, 1.0), (1.0, 2.0)):
            d = evans_terms(
                dd.points, dd.normals, dd.sdf, EvansParams(n=n, base=base * VOXEL, k=1.0, alpha=alpha)
            )
            d = np.asarray(d, np.float64)

            def free(x, d=d, yy=dd.target):
                pred, pl = evans_value_and_slope(d, x[0], x[1:])
                return pred - yy, np.column_stack([pl, -pl[:, None] * d.T])

            x0 = np.array([0.0] + [1.0 / (10 * VOXEL)] * n)
            yield f"evans stage 1 σ={noise} α={alpha} base={base}", free, x0, lo[: 1 + n], hi[: 1 + n]
        # stage 2 (fit_evans_continuous): through the Dr.Jit kernel, α and base by forward-mode autodiff
        x0 = np.array([INIT[k] for k in evans_param_names(n)])
        print(f"# evans σ={noise}: m = {len(dd.target)} points")
        yield (
            f"evans stage 2 σ={noise} (kernel)",
            (lambda x, data=data: evans_fit_residuals(x, data, n)),
            x0,
            lo,
            hi,
        )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    head = ("problem", "opt", "½‖r‖²", "max|Δx|", "Δcost/cost", "iter", "fun", "wall s")
    row = "{:42s} {:6s} {:>12s} {:>9s} {:>10s} {:>5s} {:>5s} {:>8s}"
    print(row.format(*head))
    for name, fun, x0, lo, hi in problems():
        fun(np.clip(np.asarray(x0, np.float64), lo, hi))  # warm-up (Dr.Jit compiles its kernels once)
        lm, t_lm = timed(lambda f=fun, x=x0, a=lo, b=hi: bounded_lm(f, x, a, b, max_iter=300), args.repeat)
        sp, t_sp = timed(lambda f=fun, x=x0, a=lo, b=hi: scipy_trf(f, x, a, b), args.repeat)
        dx = float(np.max(np.abs(lm["x"] - sp["x"])))
        rel = (lm["ssr"] - sp["ssr"]) / max(sp["ssr"], 1e-300)
        for label, o, t, extra in (
            ("lm", lm, t_lm, (f"{dx:.2e}", f"{rel:.1e}")),
            ("trf", sp, t_sp, ("", "")),
        ):
            cells = (name if label == "lm" else "", label, f"{o['ssr'] / 2:.5e}", *extra)
            print(row.format(*cells, str(o["iterations"]), str(o["evaluations"]), f"{t:.4f}"))
        sys.stdout.flush()


if __name__ == "__main__":
    main()
