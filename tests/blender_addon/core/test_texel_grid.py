"""texel_grid: textures on one grid, the metal's extinction from its reflectance, convex table weights."""

import math

import numpy as np
import pytest

from blender_addon.core import texel_grid as tg
from blender_addon.core.spec import MaterialSpec
from blender_addon.core.textures import MaterialTextures, TextureSpec


def _png(path, img):
    from PIL import Image

    Image.fromarray(np.asarray(img, np.uint8)).save(path)
    return str(path)


def test_sample_bilinear_wraps_and_puts_row_0_at_the_top():
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    # texel centres: column j at u = (j + 0.5) / 4, row i at v = 1 - (i + 0.5) / 3
    uv = np.array([[(j + 0.5) / 4, 1 - (i + 0.5) / 3] for i in range(3) for j in range(4)])
    np.testing.assert_allclose(tg.sample_bilinear(img, uv), img.reshape(-1), atol=1e-5)
    np.testing.assert_allclose(tg.sample_bilinear(img, uv + 1.0), img.reshape(-1), atol=1e-5)  # wraps
    # halfway between the last and first column wraps around
    assert float(tg.sample_bilinear(img, np.array([0.0, 1 - 0.5 / 3]))) == pytest.approx((0 + 3) / 2)


def test_material_grid_resamples_a_transformed_texture_onto_the_finest(tmp_path):
    big = np.zeros((16, 16, 3), np.uint8)
    big[:, :8] = 255  # left half white
    small = np.zeros((4, 4, 3), np.uint8)
    small[:2] = 255  # top half white
    tex = MaterialTextures(
        albedo=TextureSpec(_png(tmp_path / "big.png", big)),
        roughness=TextureSpec(_png(tmp_path / "small.png", small), channels=(0,), factor=(1.0,), offset=(0.0, 0.5)),
    )
    mat = MaterialSpec("m", "pplastic", (0.5,) * 3, 0.5, 0.0, ior=1.5, textures=tex)
    grid = tg.material_grid(mat)
    assert grid.shape == (16, 16) and grid.albedo.shape == (16, 16, 3)
    # the glTF offset v + 0.5 swaps the small texture's halves: white at the bottom of the grid
    assert grid.roughness[12, 8] == pytest.approx(1.0) and grid.roughness[3, 8] == pytest.approx(0.0)
    real = tg.realized(mat, grid)
    assert real["metallic"] == 0.0 and real["albedo"].shape == (16, 16, 3)


def test_table_weights_are_convex_and_a_repeated_table_is_merged(tmp_path):
    w = np.zeros((2, 2, 3), np.uint8)
    w[0, 0] = (255, 255, 0)  # 2 in all: normalized to 1/2 + 1/2, own weight 0
    w[1, 1] = (51, 0, 0)
    weights = TextureSpec(_png(tmp_path / "w.png", w), channels=(0, 1), factor=(1.0, 1.0))
    tex = MaterialTextures(tables=("b.pbsdf", "a.pbsdf"), weights=weights)
    mat = MaterialSpec.measured("t", "a.pbsdf", (0.5,) * 3, 0.5, 0.0)
    grid = tg.material_grid(dataclasses_replace(mat, tex))
    assert grid.tables == ("a.pbsdf", "b.pbsdf")
    np.testing.assert_allclose(grid.weights.sum(-1), 1.0, atol=1e-6)
    np.testing.assert_allclose(grid.weights[0, 0], [0.5, 0.5], atol=1e-6)  # own 0 + "a" again 1/2; "b" 1/2
    np.testing.assert_allclose(grid.weights[1, 1], [0.8, 0.2], atol=1e-6)
    assert math.isclose(float(grid.weights[1, 0, 0]), 1.0)


def dataclasses_replace(mat, tex):
    import dataclasses

    return dataclasses.replace(mat, textures=tex)


def test_textures_larger_than_a_render_can_show_are_averaged_down(tmp_path, monkeypatch):
    """A 64-texel checker with a cap of 32: the grid is 32 a side and keeps the checker's mean."""
    from blender_addon.core.spec import MaterialSpec
    from blender_addon.core.textures import MaterialTextures, TextureSpec

    monkeypatch.setattr(tg, "MAX_TEXTURE_SIZE", 32)
    tex = TextureSpec("procedural:checker", channels=(0,), params={"seed": 0, "size": 64, "cells": 4})
    m = MaterialSpec("m", "pplastic", (0.5, 0.5, 0.5), 0.5, 0.0, textures=MaterialTextures(roughness=tex))
    grid = tg.material_grid(m)
    assert grid.shape == (32, 32)
    assert float(grid.roughness.mean()) == pytest.approx(0.5, abs=0.02)
