"""Textures of untextured assets (blender_addon/core/random_textures.py): seeded, in range, slots by kind."""

import numpy as np
import pytest

from blender_addon.core.random_textures import random_material_textures
from blender_addon.core.textures import MaterialTextures, texture_array


class TestRandomMaterialTextures:
    def test_deterministic_from_the_generator(self):
        a = random_material_textures(np.random.default_rng(3), "pplastic", size=32)
        b = random_material_textures(np.random.default_rng(3), "pplastic", size=32)
        assert a.to_dict() == b.to_dict()

    @pytest.mark.parametrize("kind", ["pplastic", "conductor", "diffuse", "measured"])
    def test_values_in_range_and_procedural(self, kind):
        rng = np.random.default_rng(0)
        for _ in range(8):
            t = random_material_textures(rng, kind, size=32)
            assert isinstance(t, MaterialTextures)
            for slot, tex in t.slots().items():
                assert tex.procedural and "seed" in tex.params
                a = texture_array(tex)
                assert a.min() >= 0.0 and a.max() <= (0.9 + 1e-6 if slot == "albedo" else 1.0), slot

    def test_slots_by_kind(self):
        rng = np.random.default_rng(1)
        drawn = {k: [random_material_textures(rng, k, size=16) for _ in range(40)] for k in ("pplastic", "diffuse")}
        assert any(t.metallic is not None for t in drawn["pplastic"])  # dielectric/metal switching
        assert any(t.metallic is None for t in drawn["pplastic"])
        assert all(t.metallic is None for t in drawn["diffuse"])
        assert all(t.roughness is not None for t in drawn["diffuse"])
        assert any(t.normal is not None for t in drawn["pplastic"])

    def test_measured_tables_mixed_by_segments(self):
        t = random_material_textures(np.random.default_rng(2), "measured", tables=("b.pbrdf", "c.pbrdf"), size=32)
        assert t.tables == ("b.pbrdf", "c.pbrdf") and t.roughness is None
        w = texture_array(t.weights)
        assert w.shape == (32, 32, 2) and np.all(w.sum(-1) <= 1 + 1e-6)
        own = 1 - w.sum(-1)
        assert min(own.max(), w[..., 0].max(), w[..., 1].max()) > 0.9  # every table has its own region

    def test_albedo_varies_around_the_given_base_colour(self):
        base = np.array([0.5, 0.25, 0.125])
        rng, seen = np.random.default_rng(4), set()
        for _ in range(12):
            t = random_material_textures(rng, "diffuse", albedo=base, size=32)
            a = texture_array(t.albedo).reshape(-1, 3).astype(np.float64)
            kind = t.albedo.source.split(":")[1]
            seen.add(kind)
            scale = a / base
            grey = np.ptp(scale, axis=1) < 1e-5  # texels that are the base colour times a number
            if kind == "decals":  # decals on the base colour (with grain: darkened by up to 30 %)
                assert 0.3 < grey.mean() < 1 and 0.7 - 1e-6 <= scale[grey].min() and scale[grey].max() <= 1 + 1e-6
            else:  # the base colour darkened, by noise or stripes
                assert grey.all() and scale.max() <= 1 + 1e-6 and scale.min() < 0.9
        assert seen == {"noise", "stripes", "decals"}

    def test_bad_kind(self):
        with pytest.raises(ValueError, match="material_kind"):
            random_material_textures(np.random.default_rng(0), "wood")
        with pytest.raises(ValueError, match="tables"):
            random_material_textures(np.random.default_rng(0), "pplastic", tables=("a",))
