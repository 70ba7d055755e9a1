r"""A density grid fitted with the exponential height density of height fog (the audit of Mitsuba media).

Model. Height fog's extinction is σt(p) = b·exp(−c·(p·ĝ − h₀)) (1/scene unit): ``b`` ≥ 0 the density at
height 0, ``c`` ≥ 0 the falloff (the scale height is 1/c), ĝ the unit direction of increasing height and h₀
the height origin. Its logarithm is affine in p,

    ln σt(p) = α + β·p,   β = −c·ĝ,   α = ln b + c·h₀,

so the fit (`fit_height_density`) is linear least squares of ln σ over the grid's voxels of positive density
(each voxel equally weighted: the relative residual, to first order), solved on positions centred on their
mean (conditioning). Then c = |β|, ĝ = −β/c and h₀ is the lowest corner of the grid's box along ĝ, so that
heights inside the box are ≥ 0 and b is the fitted density at the box's bottom. Where c·(the box's extent
along any axis) < `FLAT` the fit is constant fog: c = 0 and ĝ the scene's up axis.

How far the grid is from the model (`HeightFit`): the relative residual r = σ_grid/σ_fit − 1 over **all**
voxels (a voxel of zero density counts −1): its root mean square and its largest magnitude, and the share of
empty voxels. A grid filled from the model has r at float32 rounding (≤ 1e-6).

Discretisation. Mitsuba's ``gridvolume`` holds the density at voxel centres (texel centres at
(i + ½)/n of the unit cube `to_world` maps, checked against ``Medium.get_scattering_coefficients``) and
interpolates trilinearly. Linear interpolation of e^(−c·x) between two nodes a height h apart is exact at the
nodes and worst at the midpoint: (1 + e^(−ch))/2 ÷ e^(−ch/2) − 1 = cosh(ch/2) − 1 ≈ (ch)²/8. Trilinear
interpolation of e^(−c·ĝ·p) = Π_k e^(−c·g_k·x_k) is the product of three such interpolations, so its relative
error is at most ≈ Σ_k (c·|ĝ·a_k|)²/8 with a_k the cell's edge vectors (`HeightFit.interpolation_error`).
Between the outermost voxel centres and the box's faces (half a cell) the texture clamps to the face voxels:
the rendered density there is constant, off the model by up to c·h/2 relative.

The grid of a loaded medium (`grid_of_medium`): its ``sigma_t.data`` and ``scale`` through ``mi.traverse``;
the volume's world transform is not a traversable parameter in Mitsuba 3.9, so it is read from the
medium's own description (``str(medium)``: the grid volume's ``to_local`` matrix, printed to 6 significant
digits, i.e. box corners to ~1e-6 relative).
"""

from __future__ import annotations

import ast
import itertools
import math
import re
from dataclasses import dataclass

import numpy as np

__all__ = ["FLAT", "GridDensity", "HeightFit", "fit_height_density", "grid_of_medium"]

FLAT = 1e-7
"""c·(largest box extent) below which the fitted gradient is taken as none (constant fog, c = 0)."""


@dataclass(frozen=True)
class GridDensity:
    """A density grid: ``data`` (Z, Y, X) float64, the extinction (1/scene unit) at voxel centres, and
    ``to_world`` (4×4) mapping the unit cube [0, 1]³ (x, y, z) onto the grid's box in the world."""

    data: np.ndarray
    to_world: np.ndarray

    @property
    def resolution(self) -> tuple[int, int, int]:
        """(nx, ny, nz)."""
        nz, ny, nx = self.data.shape
        return nx, ny, nz

    def centres(self) -> np.ndarray:
        """World positions (Z·Y·X, 3) of the voxel centres, in the order of ``data.ravel()``."""
        nx, ny, nz = self.resolution
        z, y, x = np.meshgrid(
            (np.arange(nz) + 0.5) / nz, (np.arange(ny) + 0.5) / ny, (np.arange(nx) + 0.5) / nx, indexing="ij"
        )
        unit = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
        return unit @ self.to_world[:3, :3].T + self.to_world[:3, 3]

    def corners(self) -> np.ndarray:
        """The box's eight world corners (8, 3)."""
        unit = np.array(list(itertools.product((0.0, 1.0), repeat=3)))
        return unit @ self.to_world[:3, :3].T + self.to_world[:3, 3]

    def cell_edges(self) -> np.ndarray:
        """The three edge vectors of one cell (3, 3), rows along x, y, z (world units)."""
        return (self.to_world[:3, :3] / np.asarray(self.resolution, np.float64)).T


@dataclass(frozen=True)
class HeightFit:
    """The fitted σ(p) = b·exp(−c·(p·ĝ − h₀)) (module docstring) and how far the grid is from it.

    ``b`` (1/scene unit), ``c`` (1/scene unit), ``gradient`` (unit ĝ), ``h0`` (scene units);
    ``rms_relative``, ``max_relative``: the relative residual σ_grid/σ_fit − 1 over all voxels;
    ``empty_fraction``: the share of voxels with zero density; ``voxels``; ``interpolation_error``: the
    relative error ≈ Σ_k (c·|ĝ·a_k|)²/8 of trilinear interpolation of the fitted model over one cell."""

    b: float
    c: float
    gradient: tuple[float, float, float]
    h0: float
    rms_relative: float
    max_relative: float
    empty_fraction: float
    voxels: int
    interpolation_error: float

    def height(self, p) -> np.ndarray:
        """p·ĝ − h₀ (scene units) for points ``p`` (…, 3)."""
        return np.asarray(p, np.float64) @ np.asarray(self.gradient) - self.h0

    def density(self, p) -> np.ndarray:
        """The fitted extinction at points ``p`` (…, 3), 1/scene unit."""
        return self.b * np.exp(-self.c * self.height(p))


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def fit_height_density(grid: GridDensity, up=(0.0, 0.0, 1.0)) -> HeightFit:
    """Least squares of ln σ over the grid's positive voxels (module docstring). ``up``: the gradient of a
    fit without one (constant fog, or an empty grid: b = 0, c = 0)."""
    rho = np.asarray(grid.data, np.float64).ravel()
    if not np.all(np.isfinite(rho)) or np.any(rho < 0.0):
        raise ValueError("the density grid has negative or non-finite values")
    p = grid.centres()
    pos = rho > 0.0
    corners = grid.corners()
    extent = float(np.max(np.ptp(corners, axis=0)))
    g = _unit(up)
    if not pos.any():  # no fog at all: b = 0 (every form gives τ = 0 exactly)
        h0 = float(np.min(corners @ g))
        return HeightFit(0.0, 0.0, tuple(g.tolist()), h0, 0.0, 0.0, 1.0, rho.size, 0.0)
    centre = p[pos].mean(axis=0)
    design = np.column_stack([np.ones(int(pos.sum())), p[pos] - centre])
    coef, *_ = np.linalg.lstsq(design, np.log(rho[pos]), rcond=None)
    alpha, beta = float(coef[0]), coef[1:]
    c = float(np.linalg.norm(beta))
    if c * max(extent, 1e-300) < FLAT:
        c = 0.0
    else:
        g = -beta / c
    h0 = float(np.min(corners @ g))
    # ln σ = α + β·(p − centre) = ln b − c·(p·ĝ − h₀)  ⇒  ln b = α + c·(centre·ĝ − h₀)
    log_b = alpha + c * (float(centre @ g) - h0)
    b = math.exp(min(log_b, 700.0))
    fit = b * np.exp(-c * (p @ g - h0))
    rel = rho / fit - 1.0
    interp = float(np.sum((c * np.abs(grid.cell_edges() @ g)) ** 2) / 8.0)
    return HeightFit(
        b=b,
        c=c,
        gradient=tuple(float(x) for x in g),
        h0=h0,
        rms_relative=float(np.sqrt(np.mean(rel * rel))),
        max_relative=float(np.max(np.abs(rel))),
        empty_fraction=float(np.mean(~pos)),
        voxels=int(rho.size),
        interpolation_error=interp,
    )


_GRID_LOCAL = re.compile(r"GridVolume\[\s*to_local\s*=\s*Transform\[\s*matrix=(\[\[.*?\]\])", re.S)


def grid_of_medium(mi, medium) -> GridDensity:
    """The `GridDensity` of a loaded ``heterogeneous`` Mitsuba medium whose ``sigma_t`` is a ``gridvolume``
    (module docstring): data × the medium's ``scale``, the first channel of a multi-channel grid. Raises
    ValueError (one line) for another medium."""
    params = mi.traverse(medium)
    if "sigma_t.data" not in params.keys():
        raise ValueError(f"{medium.id() or 'the medium'}: its sigma_t is not a grid volume")
    data = np.asarray(params["sigma_t.data"], np.float64)
    scale = float(params["scale"]) if "scale" in params.keys() else 1.0
    found = _GRID_LOCAL.search(str(medium))
    if found is None:
        raise ValueError(f"{medium.id() or 'the medium'}: the grid volume's transform could not be read")
    to_local = np.array(ast.literal_eval(found.group(1)), np.float64)
    return GridDensity(data=data[..., 0] * scale, to_world=np.linalg.inv(to_local))
