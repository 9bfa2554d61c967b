"""RGB preview scene of an exported Blender scene (blender_addon/core/mitsuba_preview.py) and its XML."""

import dataclasses

import numpy as np
import pytest

from blender_addon.core import mitsuba_preview, scenegen
from blender_addon.core.spec import LightSpec
from pbrdf.sensor.rig import Rig

pytestmark = pytest.mark.mitsuba
mi = pytest.importorskip("mitsuba")


def _pose(t=(0.0, 0.0, 0.0)) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


def test_preview_xml_loads_and_renders_like_the_dict(tmp_path):
    mi.set_variant("scalar_rgb")
    spec = scenegen.random_scene(Rig(), 3)
    spec = dataclasses.replace(spec, lights=(LightSpec("p", "point", _pose((0, 0.3, -0.2)), power=30.0),))
    scene = mitsuba_preview.preview_scene_dict(spec, tmp_path, resolution=24, spp=4)
    mitsuba_preview.write_xml(scene, tmp_path / "scene.xml")
    a = np.asarray(mi.render(mi.load_dict(scene), seed=3))
    b = np.asarray(mi.render(mi.load_file(str(tmp_path / "scene.xml")), seed=3))
    assert a.shape == (20, 24, 4) and a[..., 3].max() == 1.0  # sensor aspect kept; the object is seen
    np.testing.assert_allclose(b, a, atol=1e-5)
