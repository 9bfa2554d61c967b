"""Test-time refinement (network/refine.py): the albedo scale it recovers, its guards, and finite output.

The observations are rendered with the re-renderer's ``"fresnel"`` lobe (checked against Mitsuba's
``pplastic`` in tests/network/test_rerender.py) at a known albedo; the refinement starts from a
wrong one and must find the true scale, or keep the network's maps where it cannot know.
"""

import functools
from dataclasses import replace

import numpy as np
import pytest
import torch

from network import refine as rf
from network import refine_guard as rg
from network.rerender import display_patches, points_from_depth, rerender
from pbrdf.sensor.rig import Rig

SIZE, DIST = 40, 0.6
#: The default guard with the fitted scale applied in full (these tests check the fit; the shrink towards the
#: network's albedo is tests/network/test_refine_guard.py's).
FULL_STEP = replace(rg.GUARD, shrink=1.0)
K = np.array([[300.0, 0.0, SIZE / 2], [0.0, 300.0, SIZE / 2], [0.0, 0.0, 1.0]])


def _scene(albedo=(0.6, 0.4, 0.3), metallic=0.0, roughness=0.5, two=False):
    """Copies of :func:`_rendered_scene` (rendered once per argument set)."""
    pred, maps = _rendered_scene(tuple(albedo), metallic, roughness, two)
    return {k: v.copy() for k, v in pred.items()}, maps.copy()


@functools.lru_cache
def _rendered_scene(albedo, metallic, roughness, two):
    """A hemisphere-like normal field on a disc (two discs with ``two``), its true maps and rendered nine maps."""
    yy, xx = np.mgrid[:SIZE, :SIZE] + 0.5
    mask = np.zeros((SIZE, SIZE), bool)
    centres = [(SIZE / 4, SIZE / 2), (3 * SIZE / 4, SIZE / 2)] if two else [(SIZE / 2, SIZE / 2)]
    normal = np.zeros((SIZE, SIZE, 3))
    normal[..., 2] = 1.0
    rad = SIZE / 5 if two else SIZE / 3
    for cx, cy in centres:
        dx, dy = (xx - cx) / rad, -(yy - cy) / rad
        inside = dx**2 + dy**2 < 0.8
        mask |= inside
        normal[inside] = np.stack([dx, dy, np.sqrt(np.clip(1 - dx**2 - dy**2, 0, 1))], -1)[inside]
    alb = np.zeros((SIZE, SIZE, 3), np.float32)
    alb[mask] = albedo
    if two:
        alb[mask & (xx > SIZE / 2)] = np.asarray(albedo) * 0.5
    pred = {"normal": normal.astype(np.float32), "albedo": alb, "mask": mask[..., None].astype(np.float32),
            "roughness": np.full((SIZE, SIZE, 1), roughness, np.float32),
            "metallic": np.full((SIZE, SIZE, 1), metallic, np.float32)}  # fmt: skip
    maps = np.zeros((SIZE, SIZE, 9), np.float32)
    pts = points_from_depth(torch.full((1, 1, SIZE, SIZE), DIST), K).reshape(1, 3, -1)

    def t(x):
        return torch.from_numpy(np.ascontiguousarray(x.reshape(-1, x.shape[-1]).T))[None].float()

    out = rerender(t(pred["normal"]), t(alb), t(pred["roughness"]), t(pred["metallic"]), pts,
                   display_patches(Rig(), (10, 10)), diffuse="fresnel")  # fmt: skip
    maps[..., :3] = out["unpol"][0].T.reshape(SIZE, SIZE, 3).numpy() * mask[..., None]
    maps[..., 3:6] = out["lp"][0].T.reshape(SIZE, SIZE, 3).numpy() * mask[..., None]
    return pred, maps


def _with_albedo(pred, factor):
    return {**pred, "albedo": np.clip(pred["albedo"] * factor, 0, 1).astype(np.float32)}


@pytest.mark.parametrize("factor", [0.5, 1.6])
def test_recovers_the_true_albedo_scale(factor):
    truth, maps = _scene()
    res = rf.refine(_with_albedo(truth, factor), maps, K, Rig(), 1.0, DIST, guard=FULL_STEP)
    assert res.refined and res.loss_after < res.loss_before
    mask = truth["mask"][..., 0] > 0
    ratio = res.pred["albedo"][mask].sum() / truth["albedo"][mask].sum()
    assert abs(ratio - 1.0) < 0.05  # the start was off by 50 %/60 %


def test_one_scale_per_object():
    truth, maps = _scene(two=True)
    start = {
        **truth,
        "albedo": np.where(truth["mask"] > 0, 0.3, 0.0).repeat(3, -1).astype(np.float32),
    }  # grey everywhere
    res = rf.refine(start, maps, K, Rig(), 1.0, DIST, guard=FULL_STEP)
    assert len(res.scales) == 2
    left, right = sorted(res.scales.items())
    # The right object is half as bright; each gets its own scale (albedo 0.433 mean -> 0.3 start).
    assert right[1] / left[1] == pytest.approx(0.5, rel=0.06)


def test_robust_to_a_cast_shadow():
    truth, maps = _scene()
    shadowed = maps.copy()
    shadowed[: SIZE // 2 - 6, :, :6] *= 0.1  # another object shadows the top of this one
    res = rf.refine(_with_albedo(truth, 0.5), shadowed, K, Rig(), 1.0, DIST, guard=FULL_STEP)
    mask = truth["mask"][..., 0] > 0
    ratio = res.pred["albedo"][mask].sum() / truth["albedo"][mask].sum()
    assert abs(ratio - 1.0) < 0.1  # least squares would land near 0.6


def test_maps_scale_follows_the_display_radiance():
    truth, maps = _scene()
    res = rf.refine(_with_albedo(truth, 0.5), maps * 4.0, K, Rig(), 4.0, DIST, guard=FULL_STEP)  # maps in other units
    mask = truth["mask"][..., 0] > 0
    assert res.pred["albedo"][mask].sum() / truth["albedo"][mask].sum() == pytest.approx(1.0, abs=0.05)


def test_keeps_the_network_where_it_cannot_know():
    truth, maps = _scene()
    start = _with_albedo(truth, 0.5)
    uncal = rf.refine(start, maps, K, Rig(), None, DIST)
    assert not uncal.refined and "relative" in uncal.message and uncal.pred is start
    metal_truth, metal_maps = _scene(metallic=1.0)
    metal = rf.refine(_with_albedo(metal_truth, 0.5), metal_maps, K, Rig(), 1.0, DIST)
    assert not metal.refined and "dielectric" in metal.message
    empty = {**start, "mask": np.zeros_like(start["mask"])}
    assert not rf.refine(empty, maps, K, Rig(), 1.0, DIST).refined


def test_a_fit_that_does_not_help_is_not_applied():
    obs = np.full((100, 3), 0.2)
    scales, before, after = rf.object_scales(obs, obs.copy(), 0 * obs, np.ones(100), np.zeros(100, int))
    assert scales[0] == pytest.approx(1.0) and after == pytest.approx(before)
    truth, maps = _scene()
    res = rf.refine(truth, maps, K, Rig(), 1.0, DIST)  # already right: nothing to lower
    assert not res.refined or abs(res.scales[0] - 1.0) < 0.03


def test_refine_input_warns_without_distance():
    from network.infer import InferenceInput

    truth, maps = _scene()
    inp = InferenceInput(maps, truth["mask"][..., 0] > 0, 1.0, K, None, Rig())
    with pytest.warns(UserWarning, match="default distance"):
        rf.refine_input(_with_albedo(truth, 0.5), inp)
    with pytest.warns(UserWarning, match="relative .* network's (maps are|albedo is) kept"):
        rf.refine_input(_with_albedo(truth, 0.5), InferenceInput(maps, inp.mask, None, K, DIST, Rig()))
    # warn=False (infer.py's default refinement): the same result, told by the caller from its message
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        quiet = rf.refine_input(_with_albedo(truth, 0.5), InferenceInput(maps, inp.mask, None, K, DIST, Rig()),
                                warn=False)  # fmt: skip
    assert not quiet.refined and quiet.message.startswith("not refined: the capture's radiometry is relative")


@pytest.mark.parametrize("case", ["dark", "saturated", "grazing", "smooth", "tiny"])
def test_finite_for_bad_input(case):
    truth, maps = _scene(roughness=0.0 if case == "smooth" else 0.5)
    start = _with_albedo(truth, 0.5)
    if case == "dark":
        maps = np.zeros_like(maps)
    elif case == "saturated":
        maps[..., :6] = np.where(truth["mask"] > 0, 1e6, 0.0)
    elif case == "grazing":
        start["normal"] = np.where(truth["mask"] > 0, np.array([1.0, 0.0, 0.0], np.float32), 0.0)
    elif case == "tiny":
        one = np.zeros_like(truth["mask"])
        one[SIZE // 2, SIZE // 2] = 1.0
        start = {**start, "mask": one}
    res = rf.refine(start, maps, K, Rig(), 1.0, DIST)
    for k, v in res.pred.items():
        assert np.isfinite(v).all(), k
    assert res.pred["albedo"].min() >= 0 and res.pred["albedo"].max() <= 1
    if case in ("dark", "saturated", "grazing", "tiny"):
        assert not res.refined  # nothing trustworthy to fit
