"""pbrdf/sensor/patches.py: the display's two tilings against the pattern convention and its areas."""

import numpy as np
import pytest
from PIL import Image

from pbrdf.sensor.patches import MAX_PATCHES, channel_patches, constant_patches
from pbrdf.sensor.rig import DisplaySpec


def _polygon_area(verts):
    return np.linalg.norm(np.cross(verts[:, 1] - verts[:, 0], verts[:, 3] - verts[:, 0]), axis=-1)


def _image_display(tmp_path, img, **kw):
    path = tmp_path / "pattern.png"
    Image.fromarray(img).save(path)
    return DisplaySpec(pattern=str(path), **kw)


class TestConstantPatches:
    def test_rgb_halves(self):
        """Red on the display's right half (+X, world -x), green on the left, blue on the upper half."""
        display = DisplaySpec()
        p = constant_patches(display)
        assert p.vertices.shape == (4, 4, 3) and np.allclose(p.vertices[..., 2], display.center[2])
        centres = p.vertices.mean(1)
        np.testing.assert_allclose(centres, p.centers, atol=1e-15)
        for c, sign_x in ((0, -1), (1, 1)):
            lit = p.radiance[:, c] > 0
            assert np.all(np.sign(centres[lit, 0]) == sign_x)
        assert np.all(centres[p.radiance[:, 2] > 0, 1] > 0) and np.all(centres[p.radiance[:, 2] == 0, 1] < 0)
        np.testing.assert_allclose(_polygon_area(p.vertices), p.area, rtol=1e-12)
        assert p.area.sum() == pytest.approx(display.width * display.height)
        # Corners counter-clockwise seen from the front: the polygon normal is the display's front normal.
        n = np.cross(p.vertices[:, 1] - p.vertices[:, 0], p.vertices[:, 2] - p.vertices[:, 1])
        np.testing.assert_allclose(n / np.linalg.norm(n, axis=-1, keepdims=True), p.normals, atol=1e-12)

    def test_curved_chords_lie_on_the_cylinder(self):
        display = DisplaySpec(curvature_radius=1.0)
        p = constant_patches(display)
        # Built-in pattern (36 x 64): every quadrant of 32 columns gives 8 strips of 4 columns.
        assert len(p) == 4 * 8
        local = (p.vertices - np.asarray(display.center)) @ display.world_trans_display()
        r = display.curvature_radius
        np.testing.assert_allclose(local[..., 0] ** 2 + (r - local[..., 2]) ** 2, r * r, rtol=1e-12)
        # Each strip is the arc's chord: its area is below the arc length times the height, by at most 1e-3.
        arc = display.width * display.height
        assert arc * (1 - 1e-3) < _polygon_area(p.vertices).sum() < arc
        np.testing.assert_allclose(p.area.sum(), arc)

    def test_image_pattern_keeps_its_light_and_is_bounded(self, tmp_path, rng):
        """Block averaging keeps each channel's flux (area times radiance) and the patch count stays bounded.

        72 x 128 pixels average to 36 x 64 and then, with more than MAX_PATCHES rectangles, to 9 x 16: equal
        blocks, so the flux is exact.
        """
        img = (rng.random((72, 128, 3)) > 0.5).astype(np.uint8) * 255
        display = _image_display(tmp_path, img, radiance=2.0)
        p = constant_patches(display)
        assert len(p) <= MAX_PATCHES
        flux = (p.area[:, None] * p.radiance).sum(0)
        np.testing.assert_allclose(flux, 2.0 * display.width * display.height * (img / 255.0).mean((0, 1)), rtol=1e-9)


class TestChannelPatches:
    @pytest.mark.parametrize("curved", [False, True])
    def test_rgb_halves_regions(self, curved):
        display = DisplaySpec(curvature_radius=1.0 if curved else None, radiance=3.0)
        p = channel_patches(display, (4, 3))
        assert len(p) == 3 * 12
        half = display.width * display.height / 2
        for c, region in enumerate(np.split(np.arange(len(p)), 3)):
            assert p.area[region].sum() == pytest.approx(half)
            # Only its own channel, fully lit.
            np.testing.assert_array_equal(p.radiance[region], np.tile(np.eye(3)[c] * 3.0, (12, 1)))
        # The patch centres sample the pattern in their own channel (nearest, as the renderer shows it).
        local = (p.centers - np.asarray(display.center)) @ display.world_trans_display()
        if curved:  # back to arc length
            local[:, 0] = display.curvature_radius * np.arcsin(local[:, 0] / display.curvature_radius)
        seen = display.pattern_rgb_at(local[:, :2])
        assert np.all(seen[np.arange(len(p)), np.repeat(np.arange(3), 12)] == 1.0)
        np.testing.assert_allclose(np.linalg.norm(p.normals, axis=-1), 1.0)

    def test_dim_pixels_count_as_light(self, tmp_path):
        """A channel's region includes every pixel with a value > 0, and the patches average the pattern."""
        img = np.zeros((4, 8, 3), np.uint8)
        img[0:2, 0:4, 0] = 255
        img[3, 7, 0] = 51  # 0.2: a dim pixel far from the bright block
        display = _image_display(tmp_path, img)
        assert display.lit_rectangle(0) == display.pattern_rectangle((0, 4), (0, 8), (4, 8))
        p = channel_patches(display, (8, 4), supersample=2)  # one patch per pattern pixel
        red = p.radiance[: 8 * 4, 0]
        assert red.sum() == pytest.approx(8 + 0.2)
        flux = (p.area[:32] * red).sum()
        assert flux == pytest.approx(display.width * display.height * (8 + 0.2) / 32)

    def test_dark_channel_keeps_the_count(self, tmp_path):
        img = np.zeros((2, 2, 3), np.uint8)
        img[..., 1] = 255
        p = channel_patches(_image_display(tmp_path, img), (2, 2))
        assert len(p) == 12
        assert np.all(p.area[:4] == 0) and np.all(p.radiance[:4] == 0) and np.all(p.radiance[8:] == 0)

    @pytest.mark.parametrize("n, supersample", [((0, 3), 4), ((3, 3), 0)])
    def test_bad_counts(self, n, supersample):
        with pytest.raises(ValueError, match="patch counts and supersample"):
            channel_patches(DisplaySpec(), n, supersample=supersample)
