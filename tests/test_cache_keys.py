"""Cache keys depend on the physics only, never on the state of Dr.Jit (issue 21 §4).

Meshes shaded with smooth normals used to get them from Mitsuba's load-time recomputation, an atomic
``scatter_reduce`` over threads whose float32 sums depend on scheduling: the probe normals taken from
the shading normals, and with them the cache keys of the ambient-aperture ``bumps`` and sdf-occlusion
``character`` references, changed between processes (a cold or warm kernel cache shifts the timing).
The generated meshes now ship deterministic normals (`rtfit.experiments.mesh_normals`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from rtfit.experiments.mesh_normals import vertex_normals
from rtfit.scenes import library_path, load_scene

# Computes the keys of the two references from scene generation and the probe ray casts only (no
# rendering), with 8 Dr.Jit threads (more than the cores, so that any atomic race shows).
KEYS_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    import drjit as dr
    import mitsuba as mi
    from rtfit.reference import ReferenceRequest, load_mitsuba_scene
    from rtfit.reference.cache import array_digest
    from rtfit.reference.estimators import gbuffer
    from rtfit.reference.visibility import surface_points
    from rtfit.scenes import library_path, load_scene, scene_hash
    from rtfit.experiments.sdf_occlusion_scenes import load_case_scene

    mi.set_variant("llvm_ad_rgb")
    dr.set_thread_count(8)
    scene = load_scene(library_path("aperture_bumps"))
    g = np.linspace(-1.6, 1.6, 24)
    x, y = np.meshgrid(g, g[::-1], indexing="xy")
    xy = np.stack([x.ravel(), y.ravel()], axis=-1)
    pts, nrm, m = surface_points(scene, xy, 3.0, "llvm_ad_rgb")
    req = ReferenceRequest(scene=scene, spp=64, quantity="irradiance", points=pts[m], normals=nrm[m])
    sc = load_case_scene("character", 40)
    mi_, ms = load_mitsuba_scene(sc, "llvm_ad_rgb")
    gb = gbuffer(mi_, ms)
    keys = {
        "bumps": req.key(),
        "character": [scene_hash(sc), array_digest(gb.position[gb.mask], gb.normal[gb.mask])],
    }
    json.dump(keys, sys.stdout)
    """
)


def _keys(home: Path) -> dict:
    """The keys computed in a fresh process whose HOME (and Dr.Jit kernel cache) is ``home``."""
    home.mkdir(exist_ok=True)
    env = {**os.environ, "HOME": str(home), "DRJIT_CACHE_DIR": str(home / ".drjit")}
    env["RTFIT_CACHE"] = str(home / "rtfit")
    out = subprocess.run(
        [sys.executable, "-c", KEYS_SCRIPT], env=env, capture_output=True, text=True, timeout=300, check=True
    )
    return json.loads(out.stdout)


def test_keys_identical_with_fresh_and_warm_kernel_caches(tmp_path):
    first = _keys(tmp_path / "a")  # an empty Dr.Jit kernel cache
    second = _keys(tmp_path / "b")  # another empty one
    warm = _keys(tmp_path / "a")  # the first one again, now warm
    assert first == second == warm


SMOOTH_SCENES = ("aperture_bumps", "sdf_character", "sdf_sphere_plane")
SMOOTH_MESHES = [
    (scene_name, shape.file)
    for scene_name in SMOOTH_SCENES
    for shape in load_scene(library_path(scene_name)).shapes
    if shape.kind == "mesh" and not shape.face_normals
]


def _ply_normals(path) -> np.ndarray | None:
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    head = data[:end].decode()
    if "property float nx" not in head:
        return None
    nv = int(head.split("element vertex ")[1].split()[0])
    return np.frombuffer(data, dtype="<f4", count=6 * nv, offset=end).reshape(nv, 6)[:, 3:]


@pytest.mark.parametrize(("scene_name", "path"), SMOOTH_MESHES)
def test_smooth_library_meshes_ship_normals_that_mitsuba_uses(scene_name, path):
    """Mitsuba loads the stored normals (renormalised in float32, element by element: no reduction), so
    repeated loads on 8 threads give the same bits."""
    import drjit as dr  # drjit: thread count of the loads
    import mitsuba as mi  # mitsuba: the loader under test

    mi.set_variant("llvm_ad_rgb")
    stored = _ply_normals(path)
    assert stored is not None, f"{path} has no vertex normals (Mitsuba would recompute them)"
    assert np.allclose(np.linalg.norm(stored, axis=1), 1.0, atol=1e-6)
    threads = dr.thread_count()
    dr.set_thread_count(8)
    try:
        loads = []
        for _ in range(3):
            mesh = mi.load_dict({"type": "ply", "filename": str(path), "face_normals": False})
            loads.append(np.array(mi.traverse(mesh)["vertex_normals"]).reshape(-1, 3))
    finally:
        dr.set_thread_count(threads)
    assert np.abs(loads[0] - stored).max() < 3e-7
    assert all(np.array_equal(a, loads[0]) for a in loads)


def test_every_curved_smooth_library_mesh_ships_normals():
    """Every library mesh shaded smoothly is in `SMOOTH_SCENES`, except planar ones (every face normal
    the same, so any summation order gives the same unit normal: the hole plate)."""
    from rtfit.experiments.sdf_occlusion_scenes import read_ply

    smooth = set()
    for toml in sorted(library_path("aperture_bumps").parent.glob("*.toml")):
        if toml.stem.startswith("sky_"):  # atmosphere files, no shapes
            continue
        for shape in load_scene(toml).shapes:
            if shape.kind == "mesh" and not shape.face_normals:
                v, f = read_ply(shape.file)
                n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
                length = np.linalg.norm(n, axis=1, keepdims=True)
                n = n[length[:, 0] > 0] / length[length[:, 0] > 0]
                if not np.all(n == n[0]):
                    smooth.add(toml.stem)
    assert smooth == set(SMOOTH_SCENES)


def test_vertex_normals_match_mitsubas_weighting():
    """Against Mitsuba's own (angle-weighted) recomputation on the bumps mesh, one thread (no race):
    the same normals within float32 round-off."""
    import drjit as dr  # drjit: to run Mitsuba's recomputation on one thread
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    from rtfit.experiments.ambient_aperture_scenes import bumps

    v, f = bumps()
    mesh = mi.Mesh("m", len(v), len(f), has_vertex_normals=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(v.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(f.astype(np.uint32).ravel())
    params.update()
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        mesh.recompute_vertex_normals()
        theirs = np.array(mi.traverse(mesh)["vertex_normals"], dtype=np.float64).reshape(-1, 3)
    finally:
        dr.set_thread_count(threads)
    assert np.abs(vertex_normals(v, f) - theirs).max() < 1e-6


def test_vertex_normals_of_a_closed_octahedron():
    """Closed form: the vertices of a regular octahedron have normals along their own position."""
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)
    f = []
    for sx in (0, 1):
        for sy in (2, 3):
            for sz in (4, 5):
                tri = [sx, sy, sz]
                if np.dot(np.cross(v[sy] - v[sx], v[sz] - v[sx]), v[sx] + v[sy] + v[sz]) < 0:
                    tri = [sx, sz, sy]
                f.append(tri)
    f.append([0, 0, 0])  # a degenerate face contributes nothing
    n = vertex_normals(v, np.array(f))
    assert np.allclose(n, v, atol=1e-15)


def test_gpu_keys_name_their_launch_layout_and_cpu_keys_do_not():
    """The GPU cuts a pass into launches of `MAX_LANES_CUDA` lanes, whose chunks seed its sampler streams:
    the GPU's keys carry that layout (a layout change re-renders instead of mixing streams), while the CPU's
    keys, whose layout never changed, stay as they were."""
    from rtfit.reference import ReferenceRequest
    from rtfit.reference.estimators import MAX_LANES_CUDA
    from rtfit.scenes import load_scene

    scene = load_scene(library_path("aperture_hole"))
    cpu = ReferenceRequest(scene=scene, spp=8, pass_spp=4, variant="llvm_ad_rgb").identity()
    gpu = ReferenceRequest(scene=scene, spp=8, pass_spp=4, variant="cuda_ad_rgb").identity()
    assert "launch_lanes" not in cpu
    assert gpu["launch_lanes"] == MAX_LANES_CUDA
    assert {k: v for k, v in gpu.items() if k not in ("launch_lanes", "variant")} == {
        k: v for k, v in cpu.items() if k != "variant"
    }
