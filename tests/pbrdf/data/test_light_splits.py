"""The lighting-aware input's splits: wider distances than the engine's, carried through the renderer."""

from __future__ import annotations

import numpy as np
import pytest

from pbrdf.data import sample as psample
from pbrdf.data.splits import SPLITS


def test_light_splits_widen_the_engine_distances_only():
    train, val, engine = SPLITS["train-light"], SPLITS["val-light"], SPLITS["train-engine"]
    assert (train.role, val.role) == ("train", "val")
    assert train.distance == val.distance == (0.35, 1.6) and engine.distance == (0.5, 1.0)
    for name in ("resolution", "spp", "shapes", "pbrdfs", "objects", "table_fraction"):
        assert getattr(train, name) == getattr(engine, name), name
    assert len({s.seed for s in SPLITS.values() if s.twin_of is None}) == len(
        [s for s in SPLITS.values() if not s.twin_of]
    )


@pytest.mark.mitsuba
def test_generate_places_objects_in_the_distance_range(tmp_path):
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate

    generate(GenerateConfig(out=tmp_path, count=2, resolution=32, spp=4, seed=7, distance=(1.45, 1.55)), progress=False)
    for i in range(2):
        sample, meta = psample.read_sample(tmp_path, i, keys=("mask", "depth"))
        d = float(np.median(sample["depth"][sample["mask"]]))
        assert 1.2 < d < 1.8, d  # the centre at 1.45-1.55 m, the surface within the object's radius
        assert meta["distance_range"] == [1.45, 1.55]
