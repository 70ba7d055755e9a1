"""The integrator rule (pure Python): cheapest integrator that is exact for what the scene declares."""

from rtfit.reference import choose_integrator
from rtfit.scenes.model import (
    ConstantEnv,
    Cube,
    Cylinder,
    Diffuse,
    HomogeneousMedium,
    ReferenceSettings,
    Sphere,
)

from .conftest import sphere_scene

BLACK = Diffuse((0.0, 0.0, 0.0))


def test_direct_transport_uses_direct():
    c = choose_integrator(sphere_scene(transport="direct"))
    assert (c.type, c.max_depth) == ("direct", None)


def test_single_convex_reflector_global_is_direct():
    # One convex surface cannot see itself: a second bounce cannot contribute.
    c = choose_integrator(sphere_scene(transport="global", lights=(ConstantEnv((1.0, 1.0, 1.0)),)))
    assert c.type == "direct"


def test_two_reflectors_need_path_unbounded():
    shapes = (Sphere((0, 0, 0), 1.0), Sphere((3, 0, 0), 1.0))
    c = choose_integrator(sphere_scene(transport="global", shapes=shapes))
    assert (c.type, c.max_depth) == ("path", -1)


def test_non_convex_single_reflector_needs_path():
    c = choose_integrator(sphere_scene(transport="global", shapes=(Cylinder((0, 0, 0), (0, 0, 1), 0.5),)))
    assert c.type == "path"


def test_black_surfaces_do_not_count():
    shapes = (Sphere((0, 0, 0), 1.0), Sphere((3, 0, 0), 1.0, material=BLACK))
    assert choose_integrator(sphere_scene(transport="global", shapes=shapes)).type == "direct"


def test_max_depth_respected():
    import dataclasses

    shapes = (Sphere((0, 0, 0), 1.0), Sphere((3, 0, 0), 1.0))
    scene = dataclasses.replace(
        sphere_scene(transport="global", shapes=shapes), reference=ReferenceSettings("global", max_depth=3)
    )
    assert choose_integrator(scene).max_depth == 3


def test_media_use_volpathmis_never_volpath():
    import dataclasses

    medium = HomogeneousMedium(
        boundary=Cube((0, 0, 0), (4, 4, 4)), sigma_t=(0.1, 0.2, 0.3), albedo=(0.9,) * 3
    )
    scene = dataclasses.replace(sphere_scene(transport="global"), media=(medium,))
    c = choose_integrator(scene)
    assert (c.type, c.max_depth) == ("volpathmis", -1)
    single = dataclasses.replace(scene, reference=ReferenceSettings("direct"))
    assert (choose_integrator(single).type, choose_integrator(single).max_depth) == ("volpathmis", 2)
