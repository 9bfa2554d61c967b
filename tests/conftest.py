"""Shared pytest fixtures."""

import numpy as np
import pytest


@pytest.fixture
def rng():
    """Seeded generator, so random test inputs are reproducible."""
    return np.random.default_rng(1234)


def _mitsuba_variant(name):
    """Mitsuba 3 in variant ``name``; skips without mitsuba; restores the process-wide variant."""
    mi = pytest.importorskip("mitsuba")
    previous = mi.variant()
    mi.set_variant(name)
    yield mi
    if previous is not None:
        mi.set_variant(previous)


@pytest.fixture
def mitsuba_rgb():
    """Mitsuba 3 in ``scalar_rgb`` (float32)."""
    yield from _mitsuba_variant("scalar_rgb")


@pytest.fixture
def mitsuba_polarized():
    """Mitsuba 3 in ``scalar_spectral_polarized`` (float32)."""
    yield from _mitsuba_variant("scalar_spectral_polarized")


# Property tests explore new examples on developer machines but replay a fixed sequence under CI
# (CI=true), so a CI run is reproducible and never fails on an example nobody has seen.
try:
    import os

    from hypothesis import settings

    settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
    if os.environ.get("CI"):
        settings.load_profile("ci")
except ImportError:  # pragma: no cover - hypothesis is a dev dependency
    pass


@pytest.fixture(scope="session")
def slab_path(tmp_path_factory):
    """A 0.3 m square, 1 cm thick slab (PLY) facing +z (toward the camera), finely subdivided so
    the front face's vertex normals are exactly +z."""
    trimesh = pytest.importorskip("trimesh")
    from blender_addon.core import assets

    box = trimesh.creation.box(extents=(0.3, 0.3, 0.01))
    for _ in range(4):
        box = box.subdivide()
    path = tmp_path_factory.mktemp("mesh") / "slab.ply"
    assets.write_ply(box, path)
    return str(path)
