"""rtfit.scenes: typed scene descriptions, the TOML scene-file format, and the scene hash.

* :mod:`.model`: frozen dataclasses (units and frame conventions in its docstring).
* :mod:`.parse`: :func:`load_scene`, :func:`parse_scene_text`, :func:`library_path`, :class:`SceneError`.
* :mod:`.serialize`: :func:`scene_to_dict`, :func:`scene_to_toml`, :func:`scene_hash`.

The file format is documented in ``scenes/README.md``; shipped scenes live in ``scenes/library/``.
"""

from .model import (
    ENVIRONMENT_KINDS,
    RGB,
    TRANSPORTS,
    Camera,
    ConstantEnv,
    Cube,
    Cylinder,
    Diffuse,
    Disk,
    EnvMap,
    ExponentialFog,
    HomogeneousMedium,
    Light,
    Medium,
    Mesh,
    MitsubaXML,
    PointLight,
    Rectangle,
    RectLight,
    ReferenceSettings,
    Scene,
    Shape,
    Sphere,
    SphereLight,
    SpotLight,
    Sun,
    SunSky,
    Vec3,
)
from .parse import SceneError, library_names, library_path, load_scene, parse_scene_text
from .serialize import scene_hash, scene_to_dict, scene_to_toml

__all__ = [
    "ENVIRONMENT_KINDS",
    "RGB",
    "TRANSPORTS",
    "Camera",
    "ConstantEnv",
    "Cube",
    "Cylinder",
    "Diffuse",
    "Disk",
    "EnvMap",
    "ExponentialFog",
    "HomogeneousMedium",
    "Light",
    "Medium",
    "Mesh",
    "MitsubaXML",
    "PointLight",
    "RectLight",
    "Rectangle",
    "ReferenceSettings",
    "Scene",
    "SceneError",
    "Shape",
    "Sphere",
    "SphereLight",
    "SpotLight",
    "Sun",
    "SunSky",
    "Vec3",
    "library_names",
    "library_path",
    "load_scene",
    "parse_scene_text",
    "scene_hash",
    "scene_to_dict",
    "scene_to_toml",
]
