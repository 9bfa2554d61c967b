"""The display's angular emission profile in Mitsuba against the closed form with the profile.

A Lambertian plane facing the camera under the polarized display emitter is rendered by Mitsuba
(Monte Carlo over the display's area) and compared with ``albedo / pi`` times the irradiance of
:func:`pbrdf.sensor.irradiance.irradiance_vectors` with the same ``cos^p`` profile (Lambert's polygons
on sub-patches), block by block.
"""

import math

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
pytest.importorskip("mitsuba")

from blender_addon.core import mitsuba_scene as ms  # noqa: E402
from blender_addon.core import polarized_display  # noqa: E402
from pbrdf.sensor.irradiance import irradiance_vectors  # noqa: E402
from pbrdf.sensor.patches import constant_patches  # noqa: E402
from pbrdf.sensor.rig import DisplaySpec  # noqa: E402

RES, SPP, FOV_DEG, DEPTH, ALBEDO, BLOCK = 32, 256, 70.0, 0.35, 0.8, 8


def _render(mi, display: DisplaySpec) -> np.ndarray:
    """S0 ``(RES, RES)`` of a diffuse plane at ``z = -DEPTH`` facing the camera (at the origin, looking down -z)."""
    plane = mi.ScalarTransform4f().translate([0.0, 0.0, -DEPTH]).scale([2.0, 2.0, 1.0])  # rectangle normal +z
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 4, "bsdf_samples": 0},
        "sensor": {
            "type": "perspective", "fov": FOV_DEG, "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=[0, 0, -1], up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": SPP},
            "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"}},
        },
        "plane": {"type": "rectangle", "to_world": plane, "bsdf": {"type": "diffuse", "reflectance": ALBEDO}},
        **ms.display_shapes(display, 0, polarized_emitter=True),
    })  # fmt: skip
    return np.asarray(mi.render(scene, seed=3))[..., 0]


def _closed_form(display: DisplaySpec) -> np.ndarray:
    """``albedo / pi`` times the profiled irradiance at the pixel centres' points on the plane, ``(RES, RES)``."""
    t = math.tan(math.radians(FOV_DEG) / 2)
    c = ((np.arange(RES) + 0.5) / RES * 2 - 1) * t
    x, y = np.meshgrid(c, -c)  # row 0 at the top; the scene is symmetric in x, so the image's x sense is moot
    points = np.stack([x * DEPTH, y * DEPTH, np.full_like(x, -DEPTH)], -1).reshape(-1, 3)
    normals = np.broadcast_to([0.0, 0.0, 1.0], points.shape)
    p = constant_patches(display)
    phi = irradiance_vectors(p.vertices, p.radiance, points, normals, exponent=display.emission_exponent)
    return (ALBEDO / math.pi * phi[:, 0, 2]).reshape(RES, RES)


def _blocks(img: np.ndarray) -> np.ndarray:
    return img.reshape(RES // BLOCK, BLOCK, RES // BLOCK, BLOCK).mean(axis=(1, 3))


@pytest.mark.parametrize("exponent", [0.0, 2.0])
def test_profiled_display_renders_the_closed_form(mi_variant, exponent):
    mi = mi_variant("llvm_ad_mono_polarized")
    display = DisplaySpec(pattern="white", center=(0.0, 0.0, 0.05), emission_exponent=exponent)
    rendered, expected = _blocks(_render(mi, display)), _blocks(_closed_form(display))
    # 8 x 8 pixel blocks at 256 spp x 4 emitter samples: Monte Carlo noise well under 1 %.
    np.testing.assert_allclose(rendered, expected, rtol=0.015)
    if exponent:
        # The profile is seen: the flat display's closed form is off by far more than the tolerance
        # at the frame's corners, and so is a wrong exponent.
        flat = _blocks(_closed_form(DisplaySpec(pattern="white")))
        assert np.max(np.abs(rendered / flat - 1)) > 0.1
        wrong = _blocks(_closed_form(DisplaySpec(pattern="white", emission_exponent=exponent * 1.15)))
        assert np.max(np.abs(rendered / wrong - 1)) > 0.03


def test_nominal_display_keeps_its_emitter_and_kernels(mi_variant):
    """A flat display's emitter dict is the one before the profile existed (same Mitsuba kernels, same renders)."""
    mi_variant("llvm_ad_mono_polarized")  # the emitter registers for the mono JIT variants
    d = ms.display_shapes(DisplaySpec(), 0, polarized_emitter=True)["display"]["emitter"]
    assert set(d) == {"type", "radiance", "absorbing_axis"}
    profiled = ms.display_shapes(DisplaySpec(emission_exponent=1.5), 0, polarized_emitter=True)
    assert profiled["display"]["emitter"]["exponent"] == 1.5
    with pytest.raises(ValueError, match="emission_exponent"):
        polarized_display.emitter_dict(1.0, (1.0, 0.0, 0.0), emission_exponent=-1.0)
    with pytest.raises(NotImplementedError, match="display.emission_exponent"):  # the sheet cannot render it
        ms.display_shapes(DisplaySpec(emission_exponent=1.0), 0)
