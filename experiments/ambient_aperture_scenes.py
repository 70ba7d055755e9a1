"""Meshes of the ``ambient-aperture`` scenes (scenes/library/aperture_*.toml): their generators.

Meshes (written as binary little-endian PLY; the shipped copies in ``scenes/library/meshes/`` are the output
of `write_library_meshes`, and a test regenerates them byte for byte):

* ``aperture_hole_plate.ply`` — a square plate of half-size ``half`` in the plane z = 0 with a circular hole
  of radius ``hole_radius`` at the origin (``segments`` edges), triangulated as rings between the circle and
  the square. Scaled/placed by the scene file. Seen from a point on the axis below it, the visible sky is
  exactly a spherical cap (a cone of half-angle atan(R/h)); off-axis it is an oblique cone, nearly a cap.
* ``aperture_bumps.ply`` — a height field z = Σ hᵢ exp(−|p − cᵢ|²/(2sᵢ²)) over [−2, 2]² on a regular grid:
  a general occluder whose visible region is only approximately a cap. It is shaded smoothly, so it
  ships its vertex normals (`rtfit.experiments.mesh_normals.vertex_normals`, float64): Mitsuba's own
  recomputation at load time is not deterministic, and the probe normals (part of the cache key) come from
  the shading normals.

The well scene uses Mitsuba's open cylinder around a floor disk: visibility through the top opening.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .mesh_normals import vertex_normals
from .mesh_ply import write_ply

HOLE_PLATE = "aperture_hole_plate.ply"
BUMPS = "aperture_bumps.ply"
MESH_COMMENT = "rtfit ambient-aperture mesh"  # the header comment line of the meshes written here
BUMPS_GRID = 49
BUMPS_HALF = 2.0
# (cx, cy, height, sigma) of the Gaussian bumps (scene units).
BUMPS_SPEC = (
    (-0.7, -0.5, 0.55, 0.35),
    (0.6, 0.4, 0.7, 0.3),
    (0.1, -0.9, 0.35, 0.25),
    (-0.4, 0.9, 0.45, 0.3),
    (1.2, -0.8, 0.5, 0.35),
    (-1.3, 0.2, 0.4, 0.3),
)


def hole_plate(hole_radius: float = 1.0, half: float = 20.0, segments: int = 96, rings: int = 6):
    """(vertices, faces) of a square plate [−half, half]² at z = 0 with a circular hole of radius
    ``hole_radius``: ring k at parameter s = (k/rings)² blends the circle (s = 0) into the square (s = 1)."""
    if not 0 < hole_radius < half:
        raise ValueError(f"hole_radius must be in (0, half) (got {hole_radius})")
    phi = 2 * math.pi * np.arange(segments) / segments
    circle = np.stack([np.cos(phi), np.sin(phi)], axis=-1) * hole_radius
    square = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
    square = square / np.max(np.abs(square), axis=1, keepdims=True) * half
    verts = []
    for k in range(rings + 1):
        s = (k / rings) ** 2
        ring = (1 - s) * circle + s * square
        verts.append(np.concatenate([ring, np.zeros((segments, 1))], axis=1))
    verts = np.concatenate(verts)
    faces = []
    for k in range(rings):
        for i in range(segments):
            j = (i + 1) % segments
            a, b = k * segments + i, k * segments + j
            c, d = a + segments, b + segments
            faces += [(a, b, d), (a, d, c)]
    return verts, np.array(faces)


def bumps_height(x, y):
    z = np.zeros_like(np.asarray(x, dtype=np.float64))
    for cx, cy, h, s in BUMPS_SPEC:
        z = z + h * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
    return z


def bumps(grid: int = BUMPS_GRID, half: float = BUMPS_HALF):
    """(vertices, faces) of the bumpy height field on a ``grid`` × ``grid`` vertex lattice."""
    g = np.linspace(-half, half, grid)
    x, y = np.meshgrid(g, g, indexing="xy")
    verts = np.stack([x.ravel(), y.ravel(), bumps_height(x, y).ravel()], axis=-1)
    faces = []
    for j in range(grid - 1):
        for i in range(grid - 1):
            a = j * grid + i
            b, c, d = a + 1, a + grid, a + grid + 1
            faces += [(a, b, d), (a, d, c)]  # counter-clockwise seen from +z: normals up
    return verts, np.array(faces)


def write_library_meshes(directory) -> list[Path]:
    """Write the experiment's meshes into ``directory`` (the shipped ones live in scenes/library/meshes)."""
    directory = Path(directory)
    bumps_v, bumps_f = bumps()
    return [
        write_ply(directory / HOLE_PLATE, *hole_plate(), comment=MESH_COMMENT),
        write_ply(
            directory / BUMPS, bumps_v, bumps_f, vertex_normals(bumps_v, bumps_f), comment=MESH_COMMENT
        ),
    ]
