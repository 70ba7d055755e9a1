"""Camera poses of a sequence from JSON (``rtfit compare --camera-path poses.json``,
`rtfit.experiments.compare`): frame i is seen through the scene's sensor ``--camera`` (its film, filter,
near clip) moved to pose i.

The file is a JSON list with one pose per frame, each either

* an object ``{"origin": [x, y, z], "target": [x, y, z], "up": [x, y, z], "fov": degrees}`` (Mitsuba's
  ``lookat``; ``up`` optional, default the sensor's own up; ``fov`` optional, default the sensor's own: the
  **horizontal** field of view in degrees, Mitsuba's ``x_fov``, in (0, 180)), or
* a 4×4 camera-to-world matrix (a list of four rows, or 16 numbers row by row; Mitsuba's ``to_world``: the
  camera looks down its +z column, +y up), a rotation and a translation only (columns orthonormal within
  `RIGID_TOLERANCE`, determinant +1, last row 0 0 0 1), or an object ``{"to_world": matrix, "fov": degrees}``.

Anything else — not JSON, not a list, another count than the frames, a key not listed, a value not finite,
a vector of another length, origin = target, up along the view, a fov out of range, a scaled, sheared or
mirrored matrix — is one `AuditError` line naming the file, the pose and the value, before anything renders.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .audit import AuditError

__all__ = ["RIGID_TOLERANCE", "Pose", "apply_pose", "read_poses"]

RIGID_TOLERANCE = 1e-3
KEYS = {"origin", "target", "up", "fov", "to_world"}


@dataclass(frozen=True)
class Pose:
    """One camera pose: ``to_world`` (4×4 camera-to-world, float64), ``fov`` (horizontal, degrees; None:
    the sensor's own) and ``text`` (``pose i``)."""

    to_world: np.ndarray
    fov: float | None
    text: str

    @property
    def digest(self) -> str:
        """A short identity of the pose (part of its reference's cache key)."""
        h = hashlib.sha256(np.ascontiguousarray(self.to_world, np.float64).tobytes())
        h.update(repr(self.fov).encode())
        return h.hexdigest()[:16]


def _vector(value, where: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 3:
        raise AuditError(f"{where}: expected 3 numbers [x, y, z] (got {json.dumps(value)[:60]})")
    return np.array([_number(v, where) for v in value], np.float64)


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise AuditError(f"{where}: expected a finite number (got {json.dumps(value)[:60]})")
    return float(value)


def look_at(origin: np.ndarray, target: np.ndarray, up: np.ndarray, where: str) -> np.ndarray:
    """Mitsuba's ``Transform4f.look_at`` in float64: columns left = up × dir, up' = dir × left, dir,
    origin."""
    d = target - origin
    if np.linalg.norm(d) <= 1e-9 * max(1.0, float(np.linalg.norm(origin))):
        raise AuditError(f"{where}: origin and target are the same point (no view direction)")
    d = d / np.linalg.norm(d)
    if np.linalg.norm(up) == 0:
        raise AuditError(f"{where}: up is the zero vector")
    left = np.cross(up / np.linalg.norm(up), d)
    if np.linalg.norm(left) < 1e-6:
        raise AuditError(f"{where}: up {up.tolist()} is along the view direction (no image up)")
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, origin
    return m


def _matrix(value, where: str) -> np.ndarray:
    flat = value
    if isinstance(value, list) and len(value) == 4 and all(isinstance(r, list) for r in value):
        if any(len(r) != 4 for r in value):
            raise AuditError(f"{where}: a 4×4 matrix needs four rows of four numbers")
        flat = [x for r in value for x in r]
    if not isinstance(flat, list) or len(flat) != 16:
        raise AuditError(f"{where}: expected a 4×4 matrix (four rows of four numbers, or 16 numbers)")
    m = np.array([_number(v, where) for v in flat], np.float64).reshape(4, 4)
    if np.max(np.abs(m[3] - [0.0, 0.0, 0.0, 1.0])) > RIGID_TOLERANCE:
        raise AuditError(f"{where}: the last row must be 0 0 0 1 (got {m[3].tolist()})")
    r = m[:3, :3]
    off = float(np.max(np.abs(r.T @ r - np.eye(3))))
    if off > RIGID_TOLERANCE:
        scale = np.linalg.norm(r, axis=0)
        raise AuditError(
            f"{where}: not a rotation and translation (columns' lengths {np.round(scale, 4).tolist()}, "
            f"orthonormal within {off:.2g}): a scaled or sheared camera changes the field of view; give the "
            "fov instead"
        )
    if np.linalg.det(r) < 0:
        raise AuditError(f"{where}: determinant −1: a mirrored camera (the other handedness)")
    return m


def read_poses(path_text: str, frames: int, default_up: np.ndarray) -> list[Pose]:
    """The poses of ``path_text`` (module docstring), one per frame (``frames`` of them); ``default_up``: the
    up of a pose without one (the sensor's). `AuditError` (one line) on anything else."""
    path = Path(path_text)
    label = f"--camera-path {path_text}"
    if not path.is_file():
        raise AuditError(f"{label}: no such file (expected sensors, static or a JSON file of camera poses)")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise AuditError(f"{label}: not UTF-8 text") from None
    except json.JSONDecodeError as e:
        raise AuditError(f"{label}: not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})") from None
    if not isinstance(doc, list):
        raise AuditError(f"{label}: expected a JSON list of poses (got a {type(doc).__name__})")
    if len(doc) != frames:
        raise AuditError(f"{label}: {len(doc)} poses for {frames} frames (one pose per frame)")
    poses = []
    for i, item in enumerate(doc):
        where = f"{label}: pose {i}"
        fov = None
        if isinstance(item, dict):
            unknown = sorted(set(item) - KEYS)
            if unknown:
                raise AuditError(
                    f"{where}: unknown key {unknown[0]!r} (keys: origin, target, up, fov or to_world, fov)"
                )
            if "fov" in item:
                fov = _number(item["fov"], f"{where} fov")
                if not 0.0 < fov < 180.0:
                    raise AuditError(f"{where}: fov {fov:g}° out of range (0°, 180°)")
            if "to_world" in item:
                if {"origin", "target", "up"} & set(item):
                    raise AuditError(f"{where}: give to_world or origin/target/up, not both")
                m = _matrix(item["to_world"], f"{where} to_world")
            else:
                for key in ("origin", "target"):
                    if key not in item:
                        raise AuditError(f"{where}: missing {key!r} (origin, target[, up, fov])")
                up = (
                    _vector(item["up"], f"{where} up") if "up" in item else np.asarray(default_up, np.float64)
                )
                origin, target = (
                    _vector(item["origin"], f"{where} origin"),
                    _vector(item["target"], f"{where} target"),
                )
                m = look_at(origin, target, up, where)
        else:
            m = _matrix(item, where)
        poses.append(Pose(m, fov, f"pose {i}"))
    return poses


def apply_pose(mi, sensor, pose: Pose, where: str) -> None:
    """Move ``sensor`` (loaded) to ``pose`` (its ``to_world``, and ``x_fov`` where the pose has a fov)."""
    params = mi.traverse(sensor)
    if "to_world" not in params:
        raise AuditError(f"{where}: the sensor {sensor.class_name()} cannot be moved (no to_world)")
    if pose.fov is not None and "x_fov" not in params:
        raise AuditError(f"{where}: the sensor {sensor.class_name()} has no field of view to set")
    params["to_world"] = mi.Transform4f(pose.to_world.tolist())
    if pose.fov is not None:
        params["x_fov"] = float(pose.fov)
    params.update()
