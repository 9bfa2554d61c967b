"""Plain helper functions shared by several test modules (fixtures live in tests/conftest.py).

Import as ``from tests.helpers import random_hemisphere`` (the repository root is on the path).
"""

import math

import numpy as np

from pbrdf.sensor.camera import CameraModel

#: Grid of the small synthetic dataset samples made by :func:`make_sample`.
H, W = 4, 6


def random_hemisphere(rng, n, min_cos=0.0):
    """Unit vectors uniform on the upper hemisphere with ``z > min_cos``."""
    z = rng.uniform(min_cos, 1.0, n)
    phi = rng.uniform(0, 2 * math.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def make_sample(rng, *, stokes=False, raw=False):
    """A valid sample on an (H, W) grid and its metadata."""
    mask = rng.random((H, W)) > 0.3
    mask[0, 0], mask[0, 1] = True, False
    n = rng.normal(size=(H, W, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    sample = {
        "maps": rng.normal(size=(H, W, 9)).astype(np.float32),
        "mask": mask,
        "normal": np.where(mask[..., None], n, 0).astype(np.float32),
        "albedo": rng.uniform(0, 1, (H, W, 3)).astype(np.float32),
        "roughness": rng.uniform(0, 1, (H, W)).astype(np.float32),
        "metallic": rng.uniform(0, 1, (H, W)).astype(np.float32),
        "depth": np.where(mask, rng.uniform(0.3, 2.0, (H, W)), 0).astype(np.float32),
    }
    sample["albedo"][0, 0] = [0.0, 1.0, 0.5]  # range ends are valid
    metadata = {
        "rig": {"display_distance_m": 0.4, "pose": np.eye(4)},  # numpy values become JSON lists
        "materials": [{"id": "gold", "disney": {"metallic": 1.0, "roughness": np.float64(0.25)}}],
        "seed": 1234,
        "versions": {"pbrdf": "0.1.0"},
    }
    if stokes:
        sample["stokes"] = rng.normal(size=(H, W, 3, 4)).astype(np.float32)
    if raw:
        model = CameraModel(exposures=(0.01, 0.04))
        base = rng.integers(16, 900, (2 * H, 2 * W))
        sample["raw"] = np.stack([base, np.minimum(4 * base, 4095)]).astype(np.uint16)
        metadata["camera_model"] = model.to_dict()
    return sample, metadata


def assert_samples_equal(got, want):
    assert sorted(got) == sorted(want)
    for key, arr in want.items():
        assert got[key].dtype == arr.dtype, key
        assert got[key].shape == arr.shape, key
        np.testing.assert_array_equal(got[key], arr, err_msg=key)
        if arr.dtype == np.float32:  # bit for bit (the test data has no -0.0, but say so anyway)
            np.testing.assert_array_equal(got[key].view(np.uint32), arr.view(np.uint32), err_msg=key)
