"""Roughness from the LP lobe (network/refine_roughness.py): recovered where the normals hold, kept where not.

The observations are a sphere cap rendered by the re-renderer (tested against Mitsuba in
tests/network/test_rerender.py) at a known roughness; the estimate starts from a wrong one.
"""

import functools

import numpy as np
import pytest
import torch

from network import refine_roughness as rr
from network.rerender import display_patches, points_from_depth, rerender
from pbrdf.sensor.rig import Rig

SIZE, DIST = 32, 0.6
K = np.array([[300.0, 0.0, SIZE / 2], [0.0, 300.0, SIZE / 2], [0.0, 0.0, 1.0]])
#: A weak prior: the test asks what the LP alone says.
FREE = rr.RoughnessParams(sigma=10.0, broadening=0.0)


@functools.lru_cache
def _rendered(roughness: float):
    """A sphere cap's true maps and its nine maps rendered at ``roughness`` (dielectric, grey)."""
    yy, xx = np.mgrid[:SIZE, :SIZE] + 0.5
    dx, dy = (xx - SIZE / 2) / (SIZE / 2.4), -(yy - SIZE / 2) / (SIZE / 2.4)
    mask = dx**2 + dy**2 < 0.85
    normal = np.zeros((SIZE, SIZE, 3))
    normal[..., 2] = 1.0
    normal[mask] = np.stack([dx, dy, np.sqrt(np.clip(1 - dx**2 - dy**2, 0, 1))], -1)[mask]
    pred = {"normal": normal.astype(np.float32), "mask": mask[..., None].astype(np.float32),
            "albedo": np.where(mask[..., None], 0.5, 0.0).repeat(3, -1).astype(np.float32),
            "roughness": np.full((SIZE, SIZE, 1), roughness, np.float32),
            "metallic": np.zeros((SIZE, SIZE, 1), np.float32)}  # fmt: skip

    def t(x):
        return torch.from_numpy(np.ascontiguousarray(x.reshape(-1, x.shape[-1]).T))[None].float()

    pts = points_from_depth(torch.full((1, 1, SIZE, SIZE), DIST), K).reshape(1, 3, -1)
    out = rerender(t(pred["normal"]), t(pred["albedo"]), t(pred["roughness"]), t(pred["metallic"]), pts,
                   display_patches(Rig(), (12, 12)), diffuse="fresnel")  # fmt: skip
    maps = np.zeros((SIZE, SIZE, 9), np.float32)
    maps[..., :3] = out["unpol"][0].T.reshape(SIZE, SIZE, 3).numpy() * mask[..., None]
    maps[..., 3:6] = out["lp"][0].T.reshape(SIZE, SIZE, 3).numpy() * mask[..., None]
    return pred, maps


def _scene(truth: float, start: float):
    pred, maps = _rendered(truth)
    pred = {k: v.copy() for k, v in pred.items()}
    pred["roughness"] = np.where(pred["mask"] > 0, start, 0.0).astype(np.float32)
    return pred, maps.copy()


def _mean(res) -> float:
    mask = res.pred["mask"][..., 0] > 0
    return float(res.pred["roughness"][mask].mean())


@pytest.mark.parametrize(("truth", "start"), [(0.25, 0.7), (0.6, 0.2)])
def test_recovers_the_true_roughness(truth, start):
    pred, maps = _scene(truth, start)
    res = rr.refine_roughness(pred, maps, K, Rig(), DIST, params=FREE)
    assert res.refined, res.message
    assert abs(_mean(res) - truth) < 0.06  # the start was off by 0.4-0.45


def test_the_prior_pulls_towards_the_network():
    pred, maps = _scene(0.25, 0.7)
    free = _mean(rr.refine_roughness(pred, maps, K, Rig(), DIST, params=FREE))
    tight = _mean(rr.refine_roughness(pred, maps, K, Rig(), DIST, params=rr.RoughnessParams(sigma=0.05)))
    assert free < tight < 0.7


def _noisy(pred, sigma=0.45):
    """``pred`` with normals off by ~40 deg at random (not integrable)."""
    noisy = pred["normal"] + np.random.default_rng(0).normal(0.0, sigma, pred["normal"].shape).astype(np.float32)
    noisy[..., 2] = np.abs(noisy[..., 2])
    return {**pred, "normal": noisy / np.linalg.norm(noisy, axis=-1, keepdims=True)}


def test_normal_trust_separates_integrable_from_noisy_normals():
    pred, _ = _scene(0.25, 0.7)
    mask = pred["mask"][..., 0] > 0
    inner = mask & (np.hypot(*np.mgrid[:SIZE, :SIZE] + 0.5 - SIZE / 2) < SIZE / 2.4 * 0.8)  # off the rim
    good, depth = rr.normal_trust(pred["normal"], mask, K, DIST)
    bad, _ = rr.normal_trust(_noisy(pred)["normal"], mask, K, DIST)
    assert np.median(good[inner]) < 5.0 and np.median(bad[inner]) > 25.0
    assert np.median(depth[mask]) == pytest.approx(DIST, rel=0.1) and (depth[~mask] == 0).all()


def test_wrong_normals_fall_back_to_the_network():
    pred, maps = _scene(0.25, 0.7)
    noisy = _noisy(pred)
    res = rr.refine_roughness(noisy, maps, K, Rig(), DIST, params=FREE)
    assert not res.refined and res.pred is noisy and res.objects[1]["kept"]
    assert _mean(res) == pytest.approx(0.7)


def test_an_unexplained_lp_is_not_trusted():
    pred, maps = _scene(0.25, 0.7)
    maps[..., 3:6] = np.random.default_rng(1).random(maps[..., 3:6].shape) * (pred["mask"] > 0)  # LP as noise
    res = rr.refine_roughness(pred, maps, K, Rig(), DIST, params=FREE)
    assert not res.refined and "explains too little" in res.objects[1]["why"]


def test_a_fit_no_better_than_the_network_is_not_applied():
    pred, maps = _scene(0.4, 0.4)  # the network is already right
    res = rr.refine_roughness(pred, maps, K, Rig(), DIST, params=rr.RoughnessParams(broadening=0.0))
    assert not res.refined and res.pred is pred, res.objects
    assert "no lower fit loss" in res.objects[1]["why"]


@pytest.mark.parametrize("case", ["dark", "saturated", "grazing", "smooth", "tiny", "empty"])
def test_finite_for_bad_input(case):
    pred, maps = _scene(0.0 if case == "smooth" else 0.4, 0.5)
    if case == "dark":
        maps = np.zeros_like(maps)
    elif case == "saturated":
        maps[..., :6] = np.where(pred["mask"] > 0, 1e6, 0.0)
    elif case == "grazing":
        pred["normal"] = np.where(pred["mask"] > 0, np.array([1.0, 0.0, 0.0], np.float32), 0.0)
    elif case in ("tiny", "empty"):
        one = np.zeros_like(pred["mask"])
        one[SIZE // 2, SIZE // 2] = 1.0 if case == "tiny" else 0.0
        pred["mask"] = one
    res = rr.refine_roughness(pred, maps, K, Rig(), DIST)
    for k, v in res.pred.items():
        assert np.isfinite(v).all(), k
    assert 0.0 <= res.pred["roughness"].min() and res.pred["roughness"].max() <= 1.0
    if case != "smooth":
        assert not res.refined  # nothing trustworthy to fit
    else:
        assert _mean(res) < 0.5  # a mirror-like lobe pulls the start down
