"""The polarized display emitter against the physical model it replaces: an unpolarized display
behind Mitsuba's ``polarizer`` sheet (real renders of both, compared to Monte Carlo noise)."""

import dataclasses
import math

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
pytest.importorskip("mitsuba")

from blender_addon.core import mitsuba_scene as ms  # noqa: E402
from blender_addon.core import render  # noqa: E402
from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec  # noqa: E402
from pbrdf.sensor.rig import DisplaySpec, Rig  # noqa: E402

PLASTIC = MaterialSpec.plastic("plastic", (0.1, 0.3, 0.6), roughness=0.15)
GOLD = MaterialSpec.metal("gold", eta=(0.18, 0.5, 1.3), k=(3.2, 2.3, 1.85), roughness=0.1)


def _spec(material, shape="builtin:sphere", angle=math.pi / 2, seed=0):
    m = np.eye(4)
    m[:3, :3] *= 0.2
    m[:3, 3] = (0.02, -0.01, -0.7)
    rig = Rig(display=DisplaySpec(polarization_angle=angle))
    obj = ObjectSpec("obj", shape, tuple(map(tuple, m)), material.name)
    return SceneSpec(rig=rig, objects=(obj,), materials=(material,), seed=seed)


@pytest.mark.parametrize(
    ("material", "shape", "angle", "integrator"),
    [
        (PLASTIC, "builtin:sphere", math.pi / 2, "direct"),  # the default display, direct light only
        (GOLD, "builtin:sphere", math.pi / 2, "direct"),
        (GOLD, "builtin:sphere", math.pi / 4, "direct"),  # S2 carries the polarization here
        (PLASTIC, "builtin:torus", math.pi / 2, "path"),  # interreflections: path, max_depth 3
    ],
    ids=["plastic", "gold", "gold-45deg", "torus-path"],
)
def test_emitter_renders_what_the_sheet_renders(material, shape, angle, integrator):
    spec = _spec(material, shape, angle)
    sheet_settings = render.RenderSettings(resolution=40, spp=96, display="sheet")
    sheet = render.render_stokes(spec, sheet_settings)
    sheet2 = render.render_stokes(dataclasses.replace(spec, seed=7), sheet_settings)
    emitter = render.render_stokes(spec, render.RenderSettings(resolution=40, spp=96))
    assert (sheet.display, sheet.integrator) == ("sheet", "volpath")
    assert (emitter.display, emitter.integrator) == ("emitter", integrator)
    assert emitter.max_depth == sheet.max_depth == (2 if integrator == "direct" else 3)

    mask = sheet.mask & emitter.mask
    a, b, a2 = sheet.stokes[mask], emitter.stokes[mask], sheet2.stokes[mask]  # (N, 3, 4)
    s0 = a[..., 0].mean(0)
    # Means over the object per channel and Stokes component agree to 1.5 % of S0 (the noise of
    # a mean over about 700 pixels at 96 spp is a few tenths of a percent).
    np.testing.assert_allclose(b.mean(0), a.mean(0), atol=0.015 * s0.max(), rtol=0)
    assert np.all(np.abs(b.mean(0)[:, 1:] - a.mean(0)[:, 1:]) < 0.015 * s0[:, None] + 1e-5)
    # Pixel by pixel the difference is noise: no larger than between two sheet renders.
    rms = lambda x: float(np.sqrt(np.mean(x**2)))  # noqa: E731
    assert rms(b - a) < 1.2 * rms(a2 - a)
    if angle == math.pi / 4:  # +45 deg field, mirrored by reflection: s2 < 0 carries the light
        lit = a[..., 0] > 0.2 * a[..., 0].max()
        assert np.median(b[..., 2][lit] / b[..., 0][lit]) < -0.5


def test_emitter_only_where_the_display_allows_it(slab_path):
    curved = Rig(display=DisplaySpec(curvature_radius=0.5))
    assert not ms.polarized_emitter_possible(curved.display)
    assert ms.polarized_emitter_possible(Rig().display)
    with pytest.raises(ValueError, match="flat display"):
        ms.display_shapes(curved.display, 0, polarized_emitter=True)
    flat = ms.display_shapes(Rig().display, 0, polarized_emitter=True)
    assert "display_polarizer" not in flat and flat["display"]["emitter"]["type"] == "pdir_polarized_display"
    spec = dataclasses.replace(_spec(PLASTIC), rig=curved)
    res = render.render_stokes(spec, render.RenderSettings(resolution=16, spp=4))
    assert (res.display, res.integrator) == ("sheet", "volpath")  # the fallback
    with pytest.raises(ValueError, match="through the polarizer sheet"):
        render.render_stokes(spec, render.RenderSettings(resolution=16, spp=4, integrator="direct"))
    with pytest.raises(ValueError, match="display must be"):
        render.RenderSettings(display="film")
