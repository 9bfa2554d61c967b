"""network.demo.figures: per-image tone map, normal-colour key, scene figures and their captions."""

import numpy as np
import pytest
from PIL import Image

from network.demo import figures, report


def _disk(size: int = 48) -> np.ndarray:
    yy, xx = np.mgrid[0:size, 0:size]
    return (xx - size / 2 + 0.5) ** 2 + (yy - size / 2 + 0.5) ** 2 < (0.4 * size) ** 2


def _metal_unpol(mask: np.ndarray) -> np.ndarray:
    """A conductor's unpolarized map: weak shading (3e-4 to 8e-4) and a bright streak on 2 % of the object."""
    h, w = mask.shape
    shade = np.linspace(3e-4, 8e-4, w)[None, :, None] * np.ones((h, 1, 3))
    idx = np.argwhere(mask)
    streak = idx[: max(1, len(idx) // 50)]
    shade[streak[:, 0], streak[:, 1]] = 1e-2
    return shade * mask[..., None]


def test_tone_map_shows_the_weak_structure_of_a_metal():
    mask = _disk()
    img, white = figures.tone_map(_metal_unpol(mask), mask)
    lit = img[mask].max(-1)
    assert (lit > 0.15).mean() > 0.9, "the metal is black apart from its streak"
    shade = lit < 0.99  # off the streak the left-to-right shading survives
    assert np.corrcoef(lit[shade], np.argwhere(mask)[shade, 1])[0, 1] > 0.9
    assert 5e-4 < white <= 1e-2 and img.max() <= 1.0 and np.all(img[~mask] == 0)


def test_normal_key_uses_the_normal_panels_mapping():
    key = figures.normal_key(65)
    np.testing.assert_allclose(key[32, 64], [1.0, 0.5, 0.5], atol=0.02)  # x right -> red
    np.testing.assert_allclose(key[0, 32], [0.5, 1.0, 0.5], atol=0.02)  # y up -> green
    np.testing.assert_allclose(key[32, 32], [0.5, 0.5, 1.0], atol=0.02)  # z toward the camera -> blue
    assert np.all(key[0, 0] == 1.0)  # outside the hemisphere
    assert "x→red" in figures.NORMAL_KEY_TITLE and "z→blue" in figures.NORMAL_KEY_TITLE


@pytest.fixture
def scene():
    rng = np.random.default_rng(0)
    mask = _disk(32)
    maps = np.zeros((32, 32, 9), np.float32)
    maps[..., 0:3] = _metal_unpol(mask)
    maps[..., 3:6] = 0.1 * mask[..., None]
    maps[..., 6:9] = np.linspace(-0.01, 0.01, 32)[None, :, None] * mask[..., None]  # faint CP, left to right
    n = np.zeros((32, 32, 3))
    n[..., 2] = 1.0
    truth = {"normal": n, "albedo": np.full((32, 32, 3), 0.5), "roughness": np.full((32, 32, 1), 0.3),
             "metallic": np.ones((32, 32, 1))}  # fmt: skip
    pred = {**truth, "normal": n + rng.normal(0, 0.05, n.shape)}
    return maps, mask, truth, pred


def test_scene_figures_are_written_with_reading_guides(tmp_path, scene):
    maps, mask, truth, pred = scene
    out = figures.scene_figures(tmp_path / "figures", "s", maps, mask, truth, pred, pred)
    assert [p for p, _ in out] == ["figures/s_inputs.png", "figures/s_results.png"]
    for rel, caption in out:
        assert (tmp_path / rel).is_file() and not report.placeholder_caption(rel, caption), caption
    inputs, results = (c for _, c in out)
    assert "99.5th percentile" in inputs and "gamma 2.2" in inputs and "red positive" in inputs
    assert "x (right) as red" in results and "key" in results
    # The CP panel shows CP of only +-1e-2 in clear reds and blues, not as one near-white (its colour bar alone
    # has about 1000 such pixels).
    with Image.open(tmp_path / out[0][0]) as img:
        rgb = np.asarray(img.convert("RGB"), dtype=int)
    assert (np.abs(rgb[..., 0] - rgb[..., 2]) > 60).sum() > 5000
