"""The lat-long quadrature by prefix sums (`rtfit.reference.latlong_quadrature`) against the dense sum
Σ_k w_k L_k max(n·d_k, 0) written out here over every grid sample."""

import numpy as np
import pytest

from rtfit.reference import environments as envs
from rtfit.reference.latlong_quadrature import latlong_irradiance


def dense(normals, d, wl):
    return np.maximum(normals @ d.T, 0.0) @ wl


@pytest.mark.parametrize(("height", "width", "supersample"), [(8, 16, 3), (9, 20, 2), (5, 7, 1)])
def test_prefix_sums_equal_the_dense_sum(height, width, supersample):
    rng = np.random.default_rng(height)
    img = rng.random((height, width, 3)) ** 6 * 40.0  # a few bright texels over a dark map
    n = rng.normal(size=(300, 3))
    n[:6] = [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 1, 0], [0, -1, 0], [1e-9, 0, 1]]  # poles, wrap at φ = 0
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d, w, radiance = envs.quadrature_samples(img, supersample)
    wl = radiance * w[:, None]
    got = latlong_irradiance(n, d, wl, supersample * height, supersample * width)
    np.testing.assert_allclose(got, dense(n, d, wl), rtol=1e-12, atol=1e-14)


def test_irradiance_quadrature_of_a_map_is_the_dense_sum():
    img = np.random.default_rng(3).random((6, 12, 3))
    env = envs.map_environment("m", "m", "map", img)
    n = np.random.default_rng(4).normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d, w, radiance = envs.quadrature_samples(env.radiance_map, 2)  # the map as stored
    np.testing.assert_allclose(envs.irradiance_quadrature(env, n, 2), dense(n, d, radiance * w[:, None]),
                               rtol=1e-12)  # fmt: skip
