"""blender_addon/core/mesh_corpus.py: the real-mesh training corpus, usable, sorted, disjoint from the test splits."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from blender_addon.core import assets, mesh_corpus, scenegen  # noqa: E402
from blender_addon.core.unseen_shapes import unseen_shape  # noqa: E402
from pbrdf.data import splits  # noqa: E402
from pbrdf.sensor.rig import Rig  # noqa: E402

INSTALLED = (splits.MESH_CORPUS_DIR / ".complete").is_file()
NOT_INSTALLED = f"the mesh corpus is not unpacked in {splits.MESH_CORPUS_DIR} (`make setup`)"


def _tiny_corpus(root: Path) -> Path:
    """A corpus of files written here: two usable meshes and one of each refusal."""
    root.mkdir(parents=True)
    trimesh.creation.icosphere(subdivisions=2).apply_scale(0.3).export(root / "blob.off")  # 320 faces
    trimesh.creation.capsule(height=1.0, radius=0.3, count=[16, 16]).export(root / "capsule.stl")
    trimesh.creation.icosphere(subdivisions=2).apply_translation([5, 0, 0]).export(root / "moved_blob.ply")  # again
    trimesh.creation.box().export(root / "box.off")  # 12 faces: too few
    (root / "broken.off").write_text("OFF\n3 1 0\n0 0 0\n1 0\n")  # truncated
    trimesh.creation.torus(1.0, 0.3).export(root / "knot_like.off")  # a test split's kind, by name
    raw = unseen_shape("vase")  # a test split's mesh under a neutral name
    trimesh.Trimesh(raw.vertices, raw.faces).export(root / "cup.off")
    return root


def test_tiny_corpus_keeps_the_usable_meshes_and_logs_every_refusal(tmp_path, caplog):
    root = _tiny_corpus(tmp_path / "corpus")
    with caplog.at_level(logging.INFO, logger="blender_addon.core.mesh_corpus"):
        files = mesh_corpus.corpus_files(root)
    assert [f.name for f in files] == ["blob.off", "capsule.stl"]
    index = json.loads((root / "index.json").read_text())
    refused = index["refused"]
    assert set(refused) == {"box.off", "broken.off", "knot_like.off", "cup.off", "moved_blob.ply"}
    assert "faces" in refused["box.off"] and "'knot'" in refused["knot_like.off"]
    assert "test split" in refused["cup.off"] and "blob.off" in refused["moved_blob.ply"]
    assert sum("left out" in r.message for r in caplog.records) == 5
    # The cache answers the next call; a changed file rebuilds it.
    (root / "index.json").write_text(json.dumps({**index, "files": ["capsule.stl"]}))
    assert [f.name for f in mesh_corpus.corpus_files(root)] == ["capsule.stl"]
    trimesh.creation.icosphere(subdivisions=3).export(root / "blob.off")  # no longer moved_blob's geometry
    assert [f.name for f in mesh_corpus.corpus_files(root)] == ["blob.off", "capsule.stl", "moved_blob.ply"]


def test_empty_corpus_and_missing_folder_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    trimesh.creation.box().export(tmp_path / "empty" / "box.off")
    with pytest.raises(ValueError, match="no usable mesh"):
        mesh_corpus.corpus_files(tmp_path / "empty")
    with pytest.raises(FileNotFoundError):
        mesh_corpus.corpus_files(tmp_path / "nope")


def test_corpus_fraction_draws_that_share_of_objects_and_zero_keeps_the_scene_stream(tmp_path):
    files = mesh_corpus.corpus_files(_tiny_corpus(tmp_path / "corpus"))
    base = scenegen.random_scene(Rig(), 11, objects=(3, 3))
    same = scenegen.random_scene(Rig(), 11, objects=(3, 3), corpus_files=files, corpus_fraction=0.0)
    assert same == base
    drawn = [o.mesh for s in range(24) for o in scenegen.random_scene(
        Rig(), s, objects=(2, 2), corpus_files=files, corpus_fraction=0.5).objects]  # fmt: skip
    share = np.mean([m in {str(f) for f in files} for m in drawn])
    assert 0.3 < share < 0.7, share
    with pytest.raises(ValueError, match="corpus_fraction"):
        scenegen.random_scene(Rig(), 1, corpus_fraction=0.3)


@pytest.mark.skipif(not INSTALLED, reason=NOT_INSTALLED)
def test_real_package_files_index_as_expected(tmp_path):
    """A few real files of the unpacked packages: animals and a CAD part kept, a cube and a knot left out."""
    src = splits.MESH_CORPUS_DIR / "libcgal-demo"
    root = tmp_path / "few"
    root.mkdir()
    for name in ("cow.off", "elk.off", "fandisk.off", "cube.off", "knot1.off"):
        shutil.copy(src / name, root / name)
    usable, refused = mesh_corpus.index_corpus(root)
    assert list(usable) == ["cow.off", "elk.off", "fandisk.off"] and set(refused) == {"cube.off", "knot1.off"}
    mesh = assets.load_mesh(root / "cow.off")
    assert len(mesh.faces) > 1000 and np.all(np.isfinite(mesh.vertices))


@pytest.mark.slow
@pytest.mark.skipif(not INSTALLED, reason=NOT_INSTALLED)
def test_installed_corpus_is_disjoint_from_every_test_split():
    files = mesh_corpus.corpus_files(splits.MESH_CORPUS_DIR)
    assert len(files) >= 50 and files == sorted(files)
    index = json.loads((splits.MESH_CORPUS_DIR / "index.json").read_text())
    corpus = {tuple(tuple(v) if isinstance(v, list) else v for v in fp) for fp in index["fingerprints"].values()}
    # Every test split's meshes: test-meshes' unseen shapes, test-textured's glTFs, test-scenes' assimp files.
    test_refs = [f"builtin:{s}" for s in assets.UNSEEN_SHAPES]
    test_refs += [str(p) for p in assets.list_assets(splits.ASSET_CORPORA["examples-gltf"])]
    assimp = Path(splits.ASSET_CORPORA["assimp-testmodels"])
    if assimp.is_dir():
        test_refs += [str(p) for p in assets.usable_assets(assets.list_assets(assimp))[0]]
    for ref in test_refs:
        assert mesh_corpus.fingerprint(assets.load_mesh(ref)) not in corpus, ref
    test_names = {Path(r).stem.lower() for r in test_refs} | {r.split(":")[1] for r in test_refs if ":" in r}
    assert not test_names & {f.stem.lower() for f in files}


@pytest.mark.mitsuba
def test_corpus_objects_render_and_another_corpus_refuses_to_resume(tmp_path):
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate
    from pbrdf.data import sample as psample

    corpus = _tiny_corpus(tmp_path / "corpus")
    cfg = GenerateConfig(out=tmp_path / "out", count=2, resolution=32, spp=2, seed=3, corpus=corpus,
                         corpus_fraction=1.0, shard=(0, 2))  # fmt: skip
    report = generate(cfg, progress=False)
    assert report.written == [0] and not report.failed
    _, meta = psample.read_sample(tmp_path / "out", 0, keys=("mask",))
    assert all(Path(o["mesh"]).parent == corpus for o in meta["objects"]) and meta["corpus_fraction"] == 1.0
    trimesh.creation.capsule(height=2.0, radius=0.3, count=[16, 16]).export(corpus / "long_capsule.stl")  # one more
    with pytest.raises(ValueError, match="corpus_digest="):
        generate(GenerateConfig(**{**cfg.__dict__, "shard": (1, 2), "resume": True}), progress=False)
