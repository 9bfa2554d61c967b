"""The lighting-aware input's splits: wider distances than the engine's, carried through the renderer."""

from __future__ import annotations

import numpy as np
import pytest

from pbrdf.data import sample as psample
from pbrdf.data.splits import SPLITS
from pbrdf.data.splits import test_splits as nominal_test_splits


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


def test_next_splits_turn_on_jitter_and_the_corpus_and_every_other_split_stays_nominal():
    train, val = SPLITS["train-next"], SPLITS["val-next"]
    assert (train.role, train.seed, train.count, val.role, val.seed, val.count) == ("train", 34_000, 4000, "val",
                                                                                   35_000, 64)  # fmt: skip
    assert train.objects == val.objects == (1, 5) and train.distance == (0.35, 1.6)
    assert train.rig_jitter == val.rig_jitter == 1.0 and train.corpus_fraction == val.corpus_fraction == 0.3
    pseudo = ("train-pseudo-real", "test-pseudo-real")  # the real-data branch's jittered captures
    assert all(SPLITS[n].rig_jitter == 1.5 and SPLITS[n].corpus_fraction == 0.0 for n in pseudo)
    assert not set(pseudo) & {s.name for s in nominal_test_splits()}  # never in the ship gate's nominal test splits
    others = [s for s in SPLITS.values() if s.name not in ("train-next", "val-next", *pseudo)]
    assert all(s.rig_jitter == 0.0 and s.corpus_fraction == 0.0 for s in others)
    with pytest.raises(ValueError, match="training only"):
        type(train)("x", "test", seed=1, count=1, corpus_fraction=0.3)


def test_next_split_without_the_corpus_refuses_in_one_line_naming_the_packages(tmp_path, monkeypatch):
    from pbrdf.data import splits

    monkeypatch.setattr(splits, "MESH_CORPUS_DIR", tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match=r"libcgal-demo and openscad-testing-data.*make setup") as info:
        SPLITS["train-next"].corpus_folder()
    assert "\n" not in str(info.value)
    assert SPLITS["train-light"].corpus_folder() is None
