"""The refinement's guard (network/refine_guard.py): it keeps the network's maps where the capture is not the
re-renderer's material, and lets the refinement correct a plastic the renderer made.

Fires: a capture whose LP is far below (or opposite to) the lobe the re-renderer predicts, as a measured
table's is (docs/measurements/refine.md: ~40 % lower, often of the other sign), and a capture darker than any
albedo scale the guard accepts (a cast shadow over the object). Does not fire: Mitsuba's polarized ``pplastic``
sphere through the renderer's whole pipeline (render, camera, decode), whose albedo is still corrected (by
the guard's shrink, half the fitted log scale).
"""

import numpy as np
import pytest

from network import refine as rf
from network import refine_guard as rg
from pbrdf.sensor.rig import Rig
from tests.network.test_refine import DIST, K, _scene, _with_albedo


def test_lp_gain_is_the_ratio_of_totals():
    obs = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    model = np.array([[2.0, 2.0, 2.0], [1.0, 1.0, 1.0]])
    assert rg.lp_gain(obs, model, np.array([1.0, 1.0])) == pytest.approx(6.0 / 9.0)
    assert rg.lp_gain(obs, model, np.array([1.0, 0.0])) == pytest.approx(1.0)
    assert np.isnan(rg.lp_gain(obs, 0 * model, np.ones(2)))


@pytest.mark.parametrize("lp_factor", [0.1, -0.5], ids=["faint-lp", "opposite-lp"])
def test_fires_where_the_lp_is_not_the_renderers(lp_factor):
    truth, maps = _scene(roughness=0.3)
    maps[..., 3:6] *= lp_factor  # the unpol is the re-renderer's, the LP lobe is not
    start = _with_albedo(truth, 0.5)
    unguarded = rf.albedo_from_terms(start, rf.albedo_terms(start, maps, K, Rig(), 1.0, DIST), rg.OFF)
    assert unguarded.refined  # without the guard the scale would be fitted
    res = rf.refine(start, maps, K, Rig(), 1.0, DIST, roughness=True)
    assert not res.refined
    np.testing.assert_array_equal(res.pred["albedo"], start["albedo"])
    np.testing.assert_array_equal(res.pred["roughness"], start["roughness"])
    (g,) = res.guard.values()
    assert g["lp_gain"] == pytest.approx(lp_factor, abs=0.05)
    assert "LP" in g["albedo"] and "LP" in g["roughness"]


def test_fires_on_a_scale_darker_than_it_accepts():
    truth, maps = _scene()
    shadowed = maps.copy()
    shadowed[..., :3] *= 0.4  # the whole object in another one's shadow (its LP, from the display's image, kept)
    res = rf.refine(truth, shadowed, K, Rig(), 1.0, DIST)
    (g,) = res.guard.values()
    assert g["fitted"] == pytest.approx(0.4, rel=0.05) and "scale" in g["albedo"]
    assert not res.refined
    dimmer = maps.copy()
    dimmer[..., :3] *= 0.8  # a darker albedo than the network's, within the window: corrected
    fixed = rf.refine(truth, dimmer, K, Rig(), 1.0, DIST)
    assert fixed.refined and fixed.guard[1]["fitted"] == pytest.approx(0.8, rel=0.05)
    # Applied: the MAP with the network's albedo as the prior, s ** shrink (0.5: half the fit's log step).
    assert fixed.scales[1] == pytest.approx(fixed.guard[1]["fitted"] ** rg.GUARD.shrink, rel=1e-6)
    assert 0.8 < fixed.scales[1] < 1.0


@pytest.fixture(scope="module")
def mitsuba_plastic(tmp_path_factory):
    """A polarized ``pplastic`` sphere rendered by Mitsuba through the renderer's pipeline, as a dataset sample."""
    pytest.importorskip("mitsuba")
    from blender_addon.core import render
    from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec
    from network.infer import load_input
    from pbrdf.data import sample as psample

    to_world = np.eye(4)
    to_world[:3, :3] *= 0.12
    to_world[:3, 3] = (0.02, -0.01, -0.6)
    mat = MaterialSpec.plastic("plastic", (0.6, 0.4, 0.25), roughness=0.3)
    spec = SceneSpec(rig=Rig(), objects=(ObjectSpec("ball", "builtin:sphere", tuple(map(tuple, to_world)), "plastic"),),
                     materials=(mat,), seed=0)  # fmt: skip
    res = render.render_stokes(spec, render.RenderSettings(resolution=48, spp=64))
    sample, meta = render.synthesize_sample(spec, res, rng=np.random.default_rng(0), noise=False)
    root = tmp_path_factory.mktemp("plastic")
    psample.write_sample(root, 0, sample, meta)
    inp = load_input(psample.sample_paths(root, 0).sidecar)
    gt, _ = psample.read_sample(root, 0, keys=("normal", "albedo", "roughness", "metallic", "mask"))
    h, w = inp.maps.shape[:2]
    mask = (gt["mask"].reshape(h, w) > 0) & inp.mask
    truth = {k: np.where(mask[..., None], gt[k].reshape(h, w, -1), 0.0).astype(np.float32)
             for k in ("normal", "albedo", "roughness", "metallic")}  # fmt: skip
    truth["mask"] = mask[..., None].astype(np.float32)
    return truth, inp


@pytest.mark.parametrize("factor", [0.5, 1.6])
def test_does_not_fire_on_a_mitsuba_plastic(mitsuba_plastic, factor):
    truth, inp = mitsuba_plastic
    res = rf.refine(_with_albedo(truth, factor), inp.maps, inp.intrinsics, inp.rig, inp.radiance, DIST)
    (g,) = res.guard.values()
    assert g["albedo"] is None and g["roughness"] is None, g
    assert 0.7 < g["lp_gain"] < 1.4  # the renderer's plastic LP is the re-renderer's lobe (4 % lower, measured)
    assert res.refined and g["fitted"] * factor == pytest.approx(1.0, abs=0.1)  # the fit finds the truth
    mask = truth["mask"][..., 0] > 0
    ratio = res.pred["albedo"][mask].sum() / truth["albedo"][mask].sum()
    # The applied step is half the log error (shrink 0.5): 0.5 -> 0.71, 1.6 -> 1.26.
    assert abs(np.log(ratio)) == pytest.approx(abs(np.log(factor)) * (1 - rg.GUARD.shrink), abs=0.06)


@pytest.mark.parametrize("case", ["dark", "empty", "tiny", "uncalibrated"])
def test_guarded_refinement_is_finite_and_keeps_the_network_on_bad_input(case):
    truth, maps = _scene(roughness=0.3)
    start = _with_albedo(truth, 0.5)
    start["roughness"] = np.where(truth["mask"] > 0, 0.6, 0.0).astype(np.float32)  # what a fit would move
    radiance = None if case == "uncalibrated" else 1.0
    if case == "dark":
        maps = np.zeros_like(maps)
    elif case == "empty":
        start = {**start, "mask": np.zeros_like(start["mask"])}
    elif case == "tiny":
        one = np.zeros_like(start["mask"])
        one[20, 20] = 1.0
        start = {**start, "mask": one}
    res = rf.refine(start, maps, K, Rig(), radiance, DIST, roughness=True)
    assert not res.refined
    for k, v in res.pred.items():
        assert np.isfinite(v).all(), k
    np.testing.assert_array_equal(res.pred["roughness"], start["roughness"])
    for g in res.guard.values():
        assert g.get("lp_gain") is not None or g.get("roughness")  # no gain: no roughness refined
