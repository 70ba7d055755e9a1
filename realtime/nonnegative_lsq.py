"""Non-negative least squares: min ‖A x − b‖₂ subject to x ≥ 0 (Lawson & Hanson 1974, *Solving Least Squares
Problems*, ch. 23, algorithm NNLS), for the small systems of the probe bakes (`irradiance_bases`' NNLS ambient
cube: 6 unknowns a channel; `spherical_gaussians`' NNLS lobes: 6–12).

Why not ``scipy.optimize.nnls`` (which implements the same algorithm): importing ``scipy.optimize`` costs
0.35–0.42 s on the 2-core machine of issue 33 (SciPy 1.17 parses the docstrings of ~280 functions at import),
which an audit of a scene with a probe grid paid in its references even with ``--no-fit`` (session 34). The
result is the same minimiser: tests/test_nonnegative_lsq.py checks the Karush–Kuhn–Tucker conditions and
SciPy's solution on random, rank-deficient and all-negative problems.

The algorithm keeps a passive set P (the unknowns free to be positive; the others held at 0). While some held
unknown has a positive gradient of −½‖Ax − b‖², w = Aᵀ(b − Ax), above the tolerance, the one of largest w
joins P; the unconstrained least squares on P gives s; where some s_j ≤ 0, x moves toward s as far as
feasibility allows (the step α = min x_j / (x_j − s_j) over those j) and the unknowns that reach 0 leave P.
Each outer step lowers ‖Ax − b‖ strictly, so no passive set repeats and the loop ends; `MAX_ITER_FACTOR`
bounds it regardless (3n outer steps, SciPy's default)."""

from __future__ import annotations

import numpy as np

__all__ = ["ENUMERATE_MAX", "MAX_ITER_FACTOR", "nnls", "nnls_columns"]

MAX_ITER_FACTOR = 3
"""At most this many × n outer steps (SciPy's default bound); reaching it raises."""
ENUMERATE_MAX = 8
"""`nnls_columns` solves systems of at most this many unknowns by enumerating the 2ⁿ − 1 supports (255 at 8),
each a small solve shared by every column; larger ones column by column (`nnls`)."""


def _passive_solution(gram: np.ndarray, atb: np.ndarray, passive: np.ndarray) -> np.ndarray:
    """The least-squares solution on the unknowns of ``passive``, 0 on the others: the normal equations
    (AᵀA)_PP s_P = (Aᵀb)_P (n ≤ a dozen here: a solve of the small system, ~100× faster than a QR of A's
    columns a step), their minimum-norm least-squares solution where (AᵀA)_PP is singular (dependent
    columns)."""
    s = np.zeros(atb.shape[0])
    if passive.any():
        g, c = gram[np.ix_(passive, passive)], atb[passive]
        try:
            s[passive] = np.linalg.solve(g, c)
        except np.linalg.LinAlgError:
            s[passive] = np.linalg.lstsq(g, c, rcond=None)[0]
    return s


def nnls(a, b) -> tuple[np.ndarray, float]:
    """(x, ‖A x − b‖₂) with x ≥ 0 minimising ‖A x − b‖₂; ``a`` (m, n), ``b`` (m,), finite, float64.
    A column of zeros gets x_j = 0. Raises ValueError on bad shapes or non-finite values, RuntimeError
    where the loop exceeds `MAX_ITER_FACTOR`·n steps (module text: it cannot, in exact arithmetic)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.ndim != 2 or b.shape != (a.shape[0],):
        raise ValueError(f"nnls: a must be (m, n) and b (m,) (got {a.shape} and {b.shape})")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("nnls: a and b must be finite")
    m, n = a.shape
    x = np.zeros(n)
    passive = np.zeros(n, bool)
    # the gradient's tolerance: rounding of Aᵀ(b − Ax) is ~ε·‖A‖·‖b‖ per entry (Lawson–Hanson use ε·‖A‖·m)
    tol = 10.0 * np.finfo(np.float64).eps * max(m, n) * max(np.abs(a).sum(axis=0).max(initial=0.0), 1e-300)
    tol *= max(float(np.abs(b).max(initial=0.0)), 1e-300)
    gram, atb = a.T @ a, a.T @ b
    w = atb.copy()
    steps = 0
    while True:
        free = ~passive & (w > tol)
        if not free.any():
            break
        steps += 1
        if steps > MAX_ITER_FACTOR * max(n, 1):
            raise RuntimeError(f"nnls: no convergence in {MAX_ITER_FACTOR * n} steps")
        j = int(np.argmax(np.where(free, w, -np.inf)))
        passive[j] = True
        s = _passive_solution(gram, atb, passive)
        if s[j] <= 0.0:
            # In exact arithmetic an unknown of w_j > 0 enters with s_j > 0 (Lawson–Hanson lemma 23.17); where
            # rounding says otherwise it cannot enter: held at 0, the next candidate tried (w_j ignored until
            # the next change of x).
            passive[j] = False
            w[j] = 0.0
            continue
        while True:  # each pass that does not end the loop takes at least one unknown out of P
            bad = passive & (s <= 0.0)
            if not bad.any():
                x = s
                break
            ratio = np.where(bad, x / np.where(bad, x - s, 1.0), np.inf)  # (x_j > 0 in P: 0 ≤ α < 1)
            k = int(np.argmin(ratio))
            x = x + ratio[k] * (s - x)
            x[k] = 0.0  # (exactly: rounding of x + α(s − x) may leave a few ulps there)
            passive &= x > 0.0
            x[~passive] = 0.0
            s = _passive_solution(gram, atb, passive)
        w = atb - gram @ x
    if passive.any():  # the final support's solution from A_P itself (`nnls_columns`: the normal equations
        # that led here square A's condition number), clamped at 0 where rounding crosses it
        x = np.zeros(n)
        x[passive] = np.maximum(np.linalg.lstsq(a[:, passive], b, rcond=None)[0], 0.0)
    return x, float(np.linalg.norm(a @ x - b))


def nnls_columns(a, b) -> np.ndarray:
    """`nnls` of each column of ``b`` (m, B) against the one ``a`` (m, n): x (n, B), each column ≥ 0
    minimising ‖A x_j − b_j‖₂ — the probes of a grid share their design matrix
    (`irradiance_bases.fit_ambient_cubes_nnls`).

    Up to `ENUMERATE_MAX` unknowns, by the supports: the minimiser is the least-squares solution on some
    support S (the unknowns it leaves positive: A_S s = the projection of b_j on A_S's columns, s ≥ 0), and at
    such a solution ½‖A s − b‖² = ½‖b‖² − ½ c_S·s (c = Aᵀb, since (AᵀA)_SS s = c_S), so among the supports
    whose solution is ≥ 0 the minimiser is the one of largest c_S·s (the empty support: x = 0, value 0). Every
    support's solution comes from one pseudo-inverse of (AᵀA)_SS (its minimum-norm solution where the
    columns are dependent: c_S lies in its range), applied to all B columns at once: at 2¹⁸ probes × 3
    channels of a 6-unknown cube, 63 supports against 786 432 solves one at a time. A solution that is ≥ 0
    only up to rounding (a component of −1e-17 where the true minimiser is 0 there) is the smaller support's
    solution as well, which is then taken. Larger systems: `nnls` a column."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.ndim != 2 or b.ndim != 2 or b.shape[0] != a.shape[0]:
        raise ValueError(f"nnls_columns: a must be (m, n) and b (m, B) (got {a.shape} and {b.shape})")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("nnls_columns: a and b must be finite")
    n, cols = a.shape[1], b.shape[1]
    if n > ENUMERATE_MAX:
        return np.stack([nnls(a, b[:, j])[0] for j in range(cols)], axis=1) if cols else np.zeros((n, 0))
    gram, c = a.T @ a, a.T @ b
    best = np.zeros(cols)  # c_S·s of the best support so far (the empty one: 0)
    chosen = np.zeros(cols, np.int64)  # each column's support (its bits), 0: empty
    for code in range(1, 1 << n):
        support = _support(code, n)
        g = gram[np.ix_(support, support)]
        s = np.linalg.pinv(g) @ c[support]
        value = np.einsum("ij,ij->j", c[support], s)
        better = np.all(s >= 0.0, axis=0) & (value > best)
        best[better] = value[better]
        chosen[better] = code
    # Each column's solution on its support from A_S itself (an SVD: A's condition number, where the normal
    # equations that chose the support square it; a nearly dependent pair of columns had left a residual of
    # 3e-9 where the exact fit is 0), clamped at 0 where rounding crosses it.
    x = np.zeros((n, cols))
    for code in np.unique(chosen[chosen > 0]):
        support, these = _support(int(code), n), chosen == code
        s = np.linalg.lstsq(a[:, support], b[:, these], rcond=None)[0]
        x[np.ix_(support, these)] = np.maximum(s, 0.0)
    return x


def _support(code: int, n: int) -> np.ndarray:
    """The unknowns whose bits ``code`` sets, as a mask over n."""
    return np.array([(code >> i) & 1 for i in range(n)], bool)
