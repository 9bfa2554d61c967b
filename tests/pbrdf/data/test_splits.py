"""pbrdf/data/splits.py: one definition of the splits, disjoint scenes, and the role guard."""

import json

import pytest

from pbrdf.data import splits


def test_roles_and_sizes():
    roles = {s.name: s.role for s in splits.SPLITS.values()}
    assert roles["train"] == "train" and roles["val"] == "val"
    tests = splits.test_splits()
    assert {s.name for s in tests} == {"test-procedural", "test-meshes", "test-pbrdf", "test-scenes", "test-textured"}
    assert all(s.count >= 48 and s.keep_raw for s in tests)  # scored through the real-capture path
    independent = [s for s in splits.SPLITS.values() if s.twin_of is None]
    assert len({s.seed for s in independent}) == len(independent)


def test_twins_rerender_their_split_under_another_pattern():
    twins = {s.name: s for s in splits.SPLITS.values() if s.twin_of is not None}
    assert set(twins) == {"train-engine-white", "test-scenes-white"}
    for twin in twins.values():
        base = splits.get_split(twin.twin_of)
        assert twin.pattern == "white" != base.pattern and twin.role == base.role
        assert (twin.seed, twin.count, twin.resolution, twin.objects) == (base.seed, base.count, base.resolution,
                                                                          base.objects)  # fmt: skip


def test_no_scene_in_two_splits():
    # Scene seeds are hashes of (run seed, index): check the sets for the configured counts.
    scenegen = pytest.importorskip("blender_addon.core.scenegen")
    seen: dict[int, str] = {}
    for s in splits.SPLITS.values():
        if s.twin_of is not None:  # the same scenes as its split, by definition
            continue
        for i in range(s.count):
            seed = scenegen.sample_seed(s.seed, i)
            assert seed not in seen, f"{s.name} scene {i} repeats a scene of {seen[seed]}"
            seen[seed] = s.name


def test_unknown_split_names_the_valid_ones():
    with pytest.raises(ValueError, match="valid: train, val, test-procedural"):
        splits.get_split("test")


def _labelled(tmp_path, name, where="manifest"):
    root = tmp_path / name
    (root / "samples").mkdir(parents=True)
    if where == "manifest":
        (root / "manifest.json").write_text(json.dumps({"split": name}))
    else:  # a run killed before its manifest: the sidecars carry the label
        (root / "samples" / "000000.json").write_text(json.dumps({"split": name}))
    return root


@pytest.mark.parametrize("where", ["manifest", "sidecar"])
def test_training_refuses_a_test_split(tmp_path, where):
    root = _labelled(tmp_path, "test-meshes", where)
    assert splits.dataset_split(root) == "test-meshes"
    with pytest.raises(ValueError, match="test split 'test-meshes'; training may read only train"):
        splits.require_role(root, ("train",), "training")
    with pytest.raises(ValueError, match="validation may read only val"):
        splits.require_role(root, ("val",), "validation")
    assert splits.require_role(root, ("test",), "evaluation") == "test-meshes"


def test_unlabelled_data_is_no_test_split(tmp_path):
    root = tmp_path / "mine"
    root.mkdir()
    assert splits.require_role(root, ("train",), "training") is None
    with pytest.raises(ValueError, match="not a test split"):
        splits.require_role(root, ("test",), "evaluation")
    val = _labelled(tmp_path, "val")
    with pytest.raises(ValueError, match="val split 'val'"):
        splits.require_role(val, ("train",), "training")


def test_engine_splits_and_their_guards():
    train, val, test = (splits.get_split(n) for n in ("train-engine", "val-engine", "test-scenes"))
    assert train.count >= 2000 and train.resolution >= 192 and train.objects[1] >= 2
    # Training and selection see none of the test scenes' shapes: no corpus, no unseen meshes.
    assert train.shapes == val.shapes == "train" and train.assets is None and val.assets is None
    assert test.shapes == "meshes" and test.assets == "assimp-testmodels" and test.keep_raw
    # Textures on for the engine's splits (and the white twin); the fixed test splits keep their history.
    white = splits.get_split("train-engine-white")
    assert train.texture_fraction == val.texture_fraction == white.texture_fraction == 0.5
    fixed = {s.name: s.texture_fraction for s in splits.test_splits()}
    assert fixed == {"test-procedural": 0.0, "test-meshes": 0.0, "test-pbrdf": 0.0, "test-scenes": 0.0,
                     "test-textured": 1.0}  # fmt: skip
    with pytest.raises(ValueError, match="objects must be"):
        splits.Split("x", "train", seed=1, count=1, objects=(2, 1))
    with pytest.raises(ValueError, match="shapes must be one of"):
        splits.Split("x", "train", seed=1, count=1, shapes="blobs")
    with pytest.raises(ValueError, match="assets must be one of"):
        splits.Split("x", "train", seed=1, count=1, assets="objaverse")
    missing = splits.Split("x", "test", seed=1, count=1, assets="assimp-testmodels")
    object.__setattr__(missing, "assets", "assimp-testmodels")
    if not (splits.Path(splits.ASSET_CORPORA["assimp-testmodels"])).is_dir():
        with pytest.raises(FileNotFoundError, match="make setup"):
            missing.asset_folder()
    else:
        assert missing.asset_folder().is_dir()
