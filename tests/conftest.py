"""Shared pytest fixtures, and the tolerance table :data:`TOL` (``from tests.conftest import TOL``)."""

from dataclasses import dataclass

import numpy as np
import pytest


@dataclass(frozen=True)
class Tolerances:
    """Default tolerances by dtype and quantity, each with the reason for its size.

    Sized for O(1) values: an ``atol``, or an ``rtol`` where the values are not O(1) (scale-free
    ratios at 1e30). A test that claims more keeps its own literal, with the
    measured error in a comment; a looser one says what makes it loose (Monte-Carlo render noise, which
    depends on the samples per pixel and the pixels averaged, is always measured per test).
    """

    f64_exact: float = 1e-15
    """float64, a few operations on O(1) values: a handful of ulp (eps = 2.2e-16)."""
    f64: float = 1e-12
    """float64 closed forms: tens of operations on O(1) values (1e-12 is about 4,500 ulp of 1)."""
    f64_inverse: float = 1e-9
    """float64 through inverse trigonometry, square roots or matrix solves, which amplify round-off."""
    f32: float = 1e-6
    """float32 round-off of O(1) values after a few operations (eps = 1.2e-7)."""
    f32_sum: float = 1e-5
    """float32 after sums or products of tens of terms (errors add up to ~1e2 eps)."""
    mitsuba_f32: float = 2e-5
    """Mitsuba's scalar variants compute in float32 (worst case measured 3.7e-6: Fresnel r_p at eta 2.4)."""


#: The project's tolerance table.
TOL = Tolerances()


@pytest.fixture
def rng():
    """Seeded generator, so random test inputs are reproducible."""
    return np.random.default_rng(1234)


@pytest.fixture
def disc_capture(rng):
    """``(raws (4, 32, 48) uint16, model)``: a noisy bracket of a lit disc on a black background, no dark frames.

    The capture a user should make (background dark, object framed with room to spare): the automatic
    mask finds the disc (about 20 % of the frame), so checks of a good capture stay silent.
    """
    from pbrdf.sensor.camera import CameraModel, simulate_capture
    from tests.helpers import disc_stokes

    model = CameraModel()
    return simulate_capture(disc_stokes(32, 48, 10.0), model, rng=rng), model


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
def mi_variant():
    """``use(name)`` switches Mitsuba to a variant (skips if unavailable); the old one is restored."""
    mi = pytest.importorskip("mitsuba")
    previous = mi.variant()

    def use(name):
        if name not in mi.variants():
            pytest.skip(f"mitsuba has no variant {name}")
        try:
            mi.set_variant(name)
        except ImportError as e:  # e.g. the LLVM backend is inactive
            pytest.skip(f"{name}: {e}")
        return mi

    yield use
    if previous is not None:
        mi.set_variant(previous)


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


@pytest.fixture(scope="module")
def addon_registered():
    """The Blender add-on registered in a factory-fresh bpy session (per module); skips without bpy."""
    bpy = pytest.importorskip("bpy")
    import blender_addon

    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender_addon.register()
    yield blender_addon
    blender_addon.unregister()


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    """Three rendered samples (32 x 32, 4 spp, seed 5) for training and evaluation tests."""
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate

    root = tmp_path_factory.mktemp("ds")
    report = generate(GenerateConfig(out=root, count=3, resolution=32, spp=4, seed=5), progress=False)
    assert len(report.written) == 3
    return root


@pytest.fixture
def empty_blend_file():
    """An empty Blender file before the test (the add-on stays registered)."""
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_homefile(use_empty=True)


@pytest.fixture
def bpy(addon_registered):
    """bpy with an empty scene (factory settings); the add-on stays registered for the module."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy


@pytest.fixture(scope="module")
def build_spec(addon_registered):
    """The add-on's ``build_spec`` module (needs the registered add-on)."""
    from blender_addon import build_spec

    return build_spec


@pytest.fixture(scope="module")
def export_spec(addon_registered):
    """The add-on's ``export_spec`` module (needs the registered add-on)."""
    from blender_addon import export_spec

    return export_spec


@pytest.fixture(scope="module")
def render_operator(addon_registered):
    """The add-on's ``render_operator`` module (needs the registered add-on)."""
    from blender_addon import render_operator

    return render_operator


@pytest.fixture
def clean_file(addon_registered):
    """A factory-fresh scene set up for tiny, deterministic Cycles renders (CPU, 2 threads, no denoising)."""
    bpy = pytest.importorskip("bpy")

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2
    scene.cycles.filter_width = 0.01  # sample pixel centres: compare with per-pixel analytic values
    scene.view_settings.view_transform = "Standard"
    yield scene


@pytest.fixture
def torch_one_thread():
    """Torch limited to one thread during the test (a shared 2-core machine: faster and steadier)."""
    torch = pytest.importorskip("torch")

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def pbrdf_library(tmp_path_factory):
    """A two-table pBRDF library (coarse seed tables), as ``--pbrdfs`` reads it."""
    import json

    from pbrdf.brdf import seeds, table

    folder = tmp_path_factory.mktemp("pbrdfs")
    entries = []
    for mat, albedo, metallic in ((seeds.SEED_MATERIALS[3], (0.6, 0.05, 0.04), 0.0),
                                  (seeds.SEED_MATERIALS[14], (0.9, 0.7, 0.3), 1.0)):  # fmt: skip
        table.save_table(folder / f"{mat.name}.pbsdf", seeds.seed_table(mat, grid=(4, 4, 6)), for_mitsuba=True)
        entries.append({"name": mat.name, "table": f"{mat.name}.pbsdf", "albedo": list(albedo),
                        "roughness": mat.roughness, "metallic": metallic})  # fmt: skip
    (folder / "materials.json").write_text(json.dumps(entries))
    return folder
