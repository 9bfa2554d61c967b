"""mitsuba_scene: the crop window through the principal point, the path length a scene needs."""

import numpy as np
import pytest

from blender_addon.core import assets
from blender_addon.core import mitsuba_scene as ms
from pbrdf.sensor.rig import Rig


def _mesh(name, shift=(0.0, 0.0, 0.0)):
    m = assets.load_mesh(name)
    return np.asarray(m.vertices) + shift, np.asarray(m.faces)


def test_auto_max_depth_direct_light_only_for_one_closed_convex_object():
    sphere, torus = _mesh("builtin:sphere"), _mesh("builtin:torus")
    assert ms.auto_max_depth([sphere]) == ms.DIRECT_LIGHT_DEPTH["volpath"] == 2
    assert ms.auto_max_depth([sphere], "path") == 3  # path counts the polarizer sheet as a bounce
    assert ms.auto_max_depth([torus]) == 3
    assert ms.auto_max_depth([_mesh("builtin:l_block")]) == 3
    # Two convex objects can see each other.
    assert ms.auto_max_depth([sphere, _mesh("builtin:sphere", (3.0, 0.0, 0.0))]) == 3
    # An open mesh (a sphere with a hole) can see its own inside.
    v, f = sphere
    assert ms.auto_max_depth([(v, f[f[:, 0] != 0])]) == 3
    assert ms.is_convex(*_mesh("builtin:bevel_box")) and not ms.is_convex(*_mesh("builtin:vase"))


@pytest.mark.mitsuba
@pytest.mark.parametrize("variant", ["llvm_ad_mono_polarized", "scalar_spectral_polarized"])
def test_crop_window_through_the_principal_point_equals_a_cropped_film(variant):
    """The sensor renders only the crop with a shifted principal point: the same pixel rays as a
    cropped film of the whole sensor (whose size and offsets Dr.Jit would compile in)."""
    mi = pytest.importorskip("mitsuba")
    if variant not in mi.variants() or (variant.startswith("llvm") and not ms_llvm_ok()):
        pytest.skip(f"{variant} is not available")
    mi.set_variant(variant)
    cam = Rig().camera
    windows = [
        ms.CropWindow(29.1, (85, 71), (30, 22), (32, 32)),
        ms.CropWindow(10.0, (245, 205), (200, 3), (45, 24)),  # clipped by the film's edge: not square
        ms.CropWindow(10.0, (245, 205), (0, 0), (245, 205)),  # the whole film
    ]
    uv = [(0.1, 0.2), (0.5, 0.5), (0.9, 0.7), (0.3, 0.95), (0.0, 1.0), (1.0, 0.0)]
    for win in windows:
        sensor = ms.sensor_dict(cam, win, 4)
        assert (sensor["film"]["width"], sensor["film"]["height"]) == win.size
        cropped = dict(sensor, fov=np.degrees(win.fov_x(cam)))
        del cropped["principal_point_offset_x"], cropped["principal_point_offset_y"]
        cropped["film"] = dict(sensor["film"], width=win.film_size[0], height=win.film_size[1],
                               crop_offset_x=win.offset[0], crop_offset_y=win.offset[1],
                               crop_width=win.size[0], crop_height=win.size[1])  # fmt: skip
        ours, theirs = mi.load_dict(sensor), mi.load_dict(cropped)
        for p in uv:
            rays = [s.sample_ray(0.0, 0.5, mi.Point2f(*p), mi.Point2f(0.5, 0.5))[0] for s in (ours, theirs)]
            np.testing.assert_allclose(np.ravel(rays[0].d), np.ravel(rays[1].d), atol=3e-7)


def ms_llvm_ok():
    from blender_addon.core import passes

    return passes.llvm_ok()


@pytest.mark.mitsuba
def test_display_shapes_light_the_lit_rectangle_or_the_whole_area(mitsuba_polarized):
    """A built-in pattern's channel emits on its lit rectangle only; a given radiance on the whole active area."""
    mi = mitsuba_polarized
    display = Rig().display

    def world_corners(shape):  # a Mitsuba rectangle spans [-1, 1]^2 of its to_world
        return np.array([list(shape["to_world"] @ mi.ScalarPoint3f(x, y, 0.0)) for x, y in ((-1, -1), (1, 1))])

    w, h = display.width / 2, display.height / 2
    # Red: the right half (+X) seen from the front, which is world -x (DESIGN.md, docs/ARCHITECTURE.md).
    red = ms.display_shapes(display, 0)
    expected = display.surface_points_world([[0.0, -h], [w, h]])
    np.testing.assert_allclose(world_corners(red["display"]), expected, atol=1e-6)
    assert red["display"]["emitter"]["radiance"] == 2.0 * display.radiance  # the sheet passes half
    whole = ms.display_shapes(display, None, radiance={"type": "d65"})
    assert whole["display"]["emitter"]["radiance"] == {"type": "d65"}
    np.testing.assert_allclose(world_corners(whole["display"]), display.surface_points_world([[-w, -h], [w, h]]),
                               atol=1e-6)  # fmt: skip
    assert whole["display_polarizer"].keys() == red["display_polarizer"].keys()
    for channel, radiance in ((None, None), (0, {"type": "d65"})):
        with pytest.raises(ValueError, match="either a channel or a radiance"):
            ms.display_shapes(display, channel, radiance=radiance)
