"""Procedural textures (blender_addon/core/texture_patterns.py): determinism, tiling, ranges, segments."""

import math

import numpy as np
import pytest

from blender_addon.core.texture_patterns import (
    PATTERNS,
    fbm_noise,
    pattern_array,
    segment_labels,
)
from blender_addon.core.textures import TextureSpec, clear_texture_cache, texture_array

SIZE = 64


def pattern(name, **params):
    return pattern_array(name, {"seed": 5, "size": SIZE, **params})


def seam_ratio(img, axis):
    """Mean step across the wrap (last to first texel) over the mean step between interior neighbours."""
    steps = np.abs(np.diff(img, axis=axis))
    wrap = np.abs(np.take(img, 0, axis=axis) - np.take(img, -1, axis=axis))
    return float(wrap.mean() / steps.mean())


class TestEveryPattern:
    @pytest.mark.parametrize("name", PATTERNS)
    def test_shape_range_and_determinism(self, name):
        a = pattern(name)
        assert a.dtype == np.float32 and a.shape[:2] == (SIZE, SIZE)
        assert a.min() >= 0.0 and a.max() <= 1.0
        np.testing.assert_array_equal(a, pattern(name))  # same params, same array

    @pytest.mark.parametrize("name", [p for p in PATTERNS if p != "checker"])
    def test_seed_changes_it(self, name):
        assert not np.array_equal(pattern_array(name, {"seed": 1, "size": SIZE}),
                                  pattern_array(name, {"seed": 2, "size": SIZE}))  # fmt: skip

    @pytest.mark.parametrize("name", PATTERNS)
    def test_texture_spec_rebuilds_it(self, name):
        params = {"seed": 11, "size": 32}
        tex = TextureSpec(f"procedural:{name}", channels=(0,), factor=(1.0,), params=params)
        clear_texture_cache()
        again = TextureSpec.from_dict(tex.to_dict())  # e.g. read back from a scene's JSON
        np.testing.assert_array_equal(texture_array(again), pattern_array(name, params)[..., :1])

    @pytest.mark.parametrize("name", ["noise", "wear", "normal", "segments"])
    def test_tiles_without_seam(self, name):
        params = {"softness": 0.05, "count": 3} if name == "segments" else {}
        a = pattern_array(name, {"seed": 3, "size": 128, **params})
        for axis in (0, 1):
            assert seam_ratio(a, axis) < 2.0, (axis, seam_ratio(a, axis))

    def test_bad_params(self):
        with pytest.raises(ValueError, match="unknown pattern"):
            pattern_array("marble", {"seed": 0})
        with pytest.raises(ValueError, match=r"unknown params \['octave'\]"):
            pattern_array("noise", {"seed": 0, "octave": 3})
        with pytest.raises(ValueError, match="size"):
            pattern_array("noise", {"seed": 0, "size": 10**6})
        with pytest.raises(ValueError, match="low"):
            pattern_array("noise", {"seed": 0, "low": 2.0})


class TestNoise:
    def test_smooth(self):
        n = fbm_noise(256, seed=4, base=4, octaves=3)
        assert np.abs(np.diff(n, axis=1)).max() < 0.1  # no texel-to-texel jumps

    def test_a_non_periodic_lattice_would_show_a_seam(self):
        # The check above can fail: a noise sampled on a bigger canvas and cropped has a seam.
        n = fbm_noise(256, seed=4, octaves=1, base=4)[:, :100]
        assert seam_ratio(n, 1) > 5

    def test_stretch_makes_features_longer_along_u(self):
        n = fbm_noise(128, seed=2, stretch=8)
        assert np.abs(np.diff(n, axis=0)).mean() > 3 * np.abs(np.diff(n, axis=1)).mean()


class TestStripes:
    def test_count_and_duty(self):
        a = pattern("stripes", angle=0.0, period=0.25, duty=0.3, softness=0.0)[..., 0]
        assert np.all(a == a[:1])  # angle 0: constant along v
        rising = np.count_nonzero(np.diff(np.r_[a[0], a[0, :1]]) > 0.5)  # around the wrap
        assert rising == 4
        assert a.mean() == pytest.approx(0.3, abs=1.5 / SIZE)

    def test_angle_snaps_to_whole_periods(self):
        a = pattern_array("stripes", {"seed": 1, "size": 128, "angle": 0.7, "period": 0.13, "softness": 0.02})
        assert seam_ratio(a, 0) < 2 and seam_ratio(a, 1) < 2

    def test_colours(self):
        a = pattern("stripes", low=[0.1, 0.2, 0.3], high=0.9, softness=0.0)
        assert a.shape[-1] == 3
        low, high = np.array([0.1, 0.2, 0.3]), np.array([0.9, 0.9, 0.9])
        t = (a - low) / (high - low)  # each texel one blend of the two colours (edges a texel wide)
        np.testing.assert_allclose(t, np.broadcast_to(t[..., :1], t.shape), atol=1e-6)
        assert np.isclose(t, 0, atol=1e-6).mean() > 0.3 and np.isclose(t, 1, atol=1e-6).mean() > 0.3


class TestDecals:
    def test_labels_carry_ink_on_fill(self):
        a = pattern("decals", count=4, labels=1.0, discs=0.0, background=1.0, fill=0.5, ink=0.0)[..., 0]
        assert np.any(a == 1.0) and np.any(a == 0.5) and np.any(a == 0.0)

    def test_no_decals_is_the_background(self):
        a = pattern("decals", count=0, background=[0.2, 0.4, 0.6])
        np.testing.assert_allclose(a, np.broadcast_to([0.2, 0.4, 0.6], a.shape), atol=1e-7)


class TestWear:
    @pytest.mark.parametrize("amount", [0.05, 0.2, 0.5])
    def test_worn_fraction(self, amount):
        a = pattern_array("wear", {"seed": 2, "size": 128, "amount": amount, "softness": 0.0})
        assert a.mean() == pytest.approx(amount, abs=0.01)


class TestSegments:
    @pytest.mark.parametrize("count", [2, 3, 4])
    def test_hard_labels_one_hot_and_every_label_present(self, count):
        labels = segment_labels(SIZE, seed=9, count=count)
        assert set(np.unique(labels)) == set(range(count))
        w = pattern("segments", seed=9, count=count, softness=0.0)
        assert w.shape[-1] == count - 1
        own = 1.0 - w.sum(-1)
        full = np.concatenate([own[..., None], w], -1)
        np.testing.assert_array_equal(np.argmax(full, -1), labels)
        assert set(np.unique(full)) == {0.0, 1.0}

    def test_soft_weights_convex_and_hard_inside(self):
        hard = pattern("segments", seed=9, count=3, softness=0.0)
        soft = pattern("segments", seed=9, count=3, softness=0.01)
        assert np.all(soft.sum(-1) <= 1 + 1e-6)
        mid = (soft > 0.02) & (soft < 0.98)
        assert 0 < mid.mean() < 0.3  # blended near boundaries only
        assert np.abs(soft - hard).mean() < 0.05


class TestNormal:
    def test_unit_tangent_space_normals_against_the_height_gradient(self):
        a = pattern_array("normal", {"seed": 6, "size": 128, "depth": 0.01})
        n = 2.0 * a - 1.0
        np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)
        h = 0.01 * fbm_noise(128, seed=6)
        dh_dv = np.gradient(h[::-1], 1 / 128, axis=0)[::-1]  # rows from the bottom: v increasing
        dh_du = np.gradient(h, 1 / 128, axis=1)
        inner = np.s_[1:-1, 1:-1]
        assert np.corrcoef(n[..., 0][inner].ravel(), -dh_du[inner].ravel())[0, 1] > 0.99  # tilts downhill in u
        assert np.corrcoef(n[..., 1][inner].ravel(), -dh_dv[inner].ravel())[0, 1] > 0.99  # OpenGL: +y along +v

    def test_flat_at_zero_depth(self):
        np.testing.assert_allclose(pattern("normal", depth=0.0), np.broadcast_to([0.5, 0.5, 1.0], (SIZE, SIZE, 3)))


def test_pattern_module_constants():
    assert set(PATTERNS) == {"noise", "stripes", "decals", "wear", "segments", "normal", "checker"}
    assert math.isclose(pattern("checker", cells=2).mean(), 0.5)
