"""Dataset splits: one definition of train, val and the test splits, and the rule that guards them.

Every split is a rendered dataset made by one command (``headless/render.py --split NAME``, or
``make test-sets`` for all test splits) from a fixed run seed, so it is reproducible bit for
bit. The dataset's manifest and every sample's sidecar carry ``"split": NAME``.

Roles:

* ``train`` - what training reads;
* ``val`` - the only data any selection may read (early stopping, checkpoint choice,
  hyper-parameters);
* ``test`` - read by nothing but the final evaluation. Training and validation refuse a test
  split (:func:`require_role`).

Convention:
    Run seeds of different splits differ, and the scene seed of sample ``i`` of a run is a hash
    of ``(run_seed, i)`` (``blender_addon.core.scenegen.sample_seed``), so no scene appears in
    two splits (checked for the listed counts by the tests). The one exception is a *twin*
    (``twin_of``): the same scenes as another split of the same role, lit by another display
    pattern (the ablation's uniform white illumination).

Example:
    >>> SPLITS["test-procedural"].role, SPLITS["test-procedural"].count
    ('test', 48)
    >>> sorted(s.name for s in test_splits())
    ['test-meshes', 'test-pbrdf', 'test-procedural', 'test-scenes', 'test-textured']
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from pbrdf.io.strict_json import read_json_object

__all__ = [
    "ROLES",
    "Split",
    "SPLITS",
    "get_split",
    "test_splits",
    "dataset_split",
    "require_role",
]

#: The three roles a split can have.
ROLES = ("train", "val", "test")
#: Built-in shape sets a split may draw from (``headless/render.py --shapes``).
SHAPE_SET_NAMES = ("procedural", "generated", "train", "meshes", "none")
#: Asset corpora a split may add to its shape pool, by name -> folder.
ASSET_CORPORA = {
    "assimp-testmodels": "/usr/share/assimp/models",
    "examples-gltf": str(Path(__file__).resolve().parents[2] / "examples" / "gltf"),  # CC0 models the project ships
}
#: The real-mesh training corpus (``tools/ensure_meshcorpus.sh`` unpacks it; ``PBRDF_MESH_CORPUS`` overrides the
#: folder): the meshes of Debian's packages below, which no test split uses (:mod:`blender_addon.core.mesh_corpus`).
MESH_CORPUS_DIR = Path(
    os.environ.get("PBRDF_MESH_CORPUS") or Path(__file__).resolve().parents[2] / "corpora" / "meshes"
)
MESH_CORPUS_PACKAGES = ("libcgal-demo", "openscad-testing-data")


@dataclass(frozen=True)
class Split:
    """One split: how to render it and what it may be used for.

    Attributes:
        name: unique name, also the default folder name.
        role: ``train``, ``val`` or ``test``.
        seed: run seed of ``headless/render.py``.
        count: number of scenes.
        resolution: rendered sample size in pixels.
        spp: samples per pixel per colour pass.
        shapes: built-in shape set of ``headless/render.py --shapes``: ``procedural`` (the
            primitives), ``generated`` (seeded concave, sharp-edged, thin and multi-part training
            shapes), ``train`` (both), ``meshes`` (the unseen test meshes) or ``none``.
        pbrdfs: materials from expanded pBRDF tables (``True``) or analytic ones.
        keep_raw: store the raw HDR brackets (a capture folder per sample), so the split can be
            scored through the real-capture path.
        description: one line for tables and ``--help``.
        objects: ``(min, max)`` objects per scene.
        table_fraction: with ``pbrdfs``, the probability that an object's material is a table
            (the rest analytic); None: every object a table.
        assets: an asset corpus added to the shape pool: ``"assimp-testmodels"`` (Debian's
            package, :data:`ASSET_CORPORA`) or None.
        pattern: the display pattern (:data:`pbrdf.sensor.rig.BUILTIN_PATTERNS`).
        twin_of: the split whose scenes (seed, count and every setting but ``pattern``) this one
            re-renders; None for an independent split.
        texture_fraction: the probability that an object's drawn material gets seeded procedural
            textures (``headless/render.py --texture-fraction``).
        asset_materials: asset files keep their own materials (``--asset-materials``).
        distance: ``(min, max)`` object distance from the camera in m (uniform; the light-input
            splits widen the engine's 0.5-1.0 m so the network sees the display's fall-off).
        rig_jitter: scale of the rig imperfections drawn per scene (:mod:`pbrdf.sensor.rig_jitter`;
            0: the nominal rig).
        corpus_fraction: the probability that an object is a real mesh of the training corpus
            (:data:`MESH_CORPUS_DIR`) rather than one of ``shapes``; train and val splits only.
    """

    name: str
    role: str
    seed: int
    count: int
    resolution: int = 128
    spp: int = 16
    shapes: str = "procedural"
    pbrdfs: bool = False
    keep_raw: bool = False
    description: str = ""
    objects: tuple[int, int] = (1, 1)
    table_fraction: float | None = None
    assets: str | None = None
    pattern: str = "rgb_halves"
    twin_of: str | None = None
    texture_fraction: float = 0.0
    asset_materials: bool = False
    distance: tuple[float, float] = (0.5, 1.0)
    rig_jitter: float = 0.0
    corpus_fraction: float = 0.0

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ValueError(f"split {self.name!r}: role must be one of {ROLES}, got {self.role!r}")
        if self.shapes not in SHAPE_SET_NAMES:
            raise ValueError(f"split {self.name!r}: shapes must be one of {SHAPE_SET_NAMES}, got {self.shapes!r}")
        if not 1 <= self.objects[0] <= self.objects[1]:
            raise ValueError(f"split {self.name!r}: objects must be (min, max) with 1 <= min <= max")
        if self.assets is not None and self.assets not in ASSET_CORPORA:
            raise ValueError(f"split {self.name!r}: assets must be one of {sorted(ASSET_CORPORA)} or None")
        if self.corpus_fraction and self.role == "test":
            raise ValueError(f"split {self.name!r}: the mesh corpus is for training only (corpus_fraction must be 0)")

    def corpus_folder(self) -> Path | None:
        """The real-mesh corpus folder (None when ``corpus_fraction`` is 0).

        Raises:
            FileNotFoundError: the corpus is not unpacked (one line naming the packages and `make setup`).
        """
        if not self.corpus_fraction:
            return None
        if not (MESH_CORPUS_DIR / ".complete").is_file():
            raise FileNotFoundError(
                f"split {self.name!r} draws real meshes from {MESH_CORPUS_DIR}, which is missing: unpack Debian's "
                f"{' and '.join(MESH_CORPUS_PACKAGES)} there (`make setup` does: tools/ensure_meshcorpus.sh)"
            )
        return MESH_CORPUS_DIR

    def asset_folder(self) -> Path | None:
        """The folder of the split's asset corpus (None without one).

        Raises:
            FileNotFoundError: the corpus is not installed (the message says how to install it).
        """
        if self.assets is None:
            return None
        folder = Path(ASSET_CORPORA[self.assets])
        if not folder.is_dir():
            raise FileNotFoundError(
                f"split {self.name!r} draws assets from {folder}, which is missing: install Debian's "
                f"{self.assets} (`make setup` does)"
            )
        return folder

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form (stored in the manifest)."""
        return asdict(self)


#: What the data engine's train and val splits share (scenes from one distribution). Half the drawn
#: materials are textured (issue 26: on by default for the engine's splits); a folder rendered
#: before that refuses ``--resume`` with one line (:data:`blender_addon.core.generate.SCENE_FIELDS`).
_ENGINE = {"resolution": 192, "spp": 16, "shapes": "train", "pbrdfs": True, "objects": (1, 3), "table_fraction": 0.5,
           "texture_fraction": 0.5}  # fmt: skip
#: The lighting-aware input's splits (issue 27): the engine's scenes over a wider distance range.
_LIGHT = {**_ENGINE, "distance": (0.35, 1.6)}
#: The next model's data (issue 29): the engine's scenes with 1-5 objects over the light splits' distances, rig
#: imperfections drawn per scene (issue 28) and 30 % of the objects real meshes of the training corpus.
_NEXT = {**_LIGHT, "objects": (1, 5), "rig_jitter": 1.0, "corpus_fraction": 0.3}
#: Pseudo-real captures (issue 28 item 5): the engine's scenes through a rig jittered at 1.5, raw brackets kept so
#: they are read through the capture path (decoded with the nominal rig); training never reads their ground truth.
_PSEUDO = {**_ENGINE, "rig_jitter": 1.5, "keep_raw": True}

#: Every split of the project. Train and val reproduce the first (128-px, superseded) model's data;
#: the test seeds are far from both.
SPLITS: dict[str, Split] = {
    s.name: s
    for s in (
        Split("train", "train", seed=100, count=158, description="procedural shapes, analytic materials"),
        Split("val", "val", seed=9000, count=12, description="procedural shapes, analytic materials (selection)"),
        Split(
            "test-procedural",
            "test",
            seed=20_000,
            count=48,
            keep_raw=True,
            description="in-distribution: procedural shapes, analytic materials",
        ),
        Split(
            "test-meshes",
            "test",
            seed=21_000,
            count=48,
            shapes="meshes",
            keep_raw=True,
            description="unseen meshes: concave, sharp-edged, thin, multi-part",
        ),
        Split(
            "test-pbrdf",
            "test",
            seed=22_000,
            count=48,
            pbrdfs=True,
            keep_raw=True,
            description="procedural shapes, expanded measured pBRDFs",
        ),
        # The data engine's scenes (issue #13): 1-3 objects of the procedural and generated
        # training shapes, half the materials expanded pBRDF tables (out/splits/pbrdfs-train),
        # half analytic. `make train-data` renders them; a killed run resumes.
        Split(
            "train-engine",
            "train",
            seed=30_000,
            count=2000,
            description="1-3 procedural and generated shapes, half pBRDF tables, half analytic, half textured",
            **_ENGINE,
        ),
        Split("val-engine", "val", seed=31_000, count=64, description="as train-engine (selection)", **_ENGINE),
        # The lighting-aware input's data (issue 27): train-engine's scenes over a wider distance
        # range, so the light channels vary; `make train-light-model` renders them and fine-tunes.
        Split(
            "train-light",
            "train",
            seed=32_000,
            count=2000,
            description="as train-engine at 0.35-1.6 m (lighting-aware input)",
            **_LIGHT,
        ),
        Split("val-light", "val", seed=33_000, count=64, description="as train-light (selection)", **_LIGHT),
        Split(
            "train-next",
            "train",
            seed=34_000,
            count=4000,
            description="1-5 objects, 30 % real corpus meshes, rig imperfections drawn per scene, half textured",
            **_NEXT,
        ),
        Split("val-next", "val", seed=35_000, count=64, description="as train-next (selection)", **_NEXT),
        # The real-data branch's pseudo-real captures and their held-out split (docs/measurements/pseudo_real.md).
        Split("train-pseudo-real", "train", seed=38_500, count=64, description="jittered rig", **_PSEUDO),
        Split("test-pseudo-real", "test", seed=28_500, count=32, description="as train-pseudo-real", **_PSEUDO),
        Split(
            "test-scenes",
            "test",
            seed=23_000,
            count=48,
            shapes="meshes",
            pbrdfs=True,
            keep_raw=True,
            objects=(1, 4),
            table_fraction=0.5,
            assets="assimp-testmodels",
            description="1-4 objects: assimp-testmodels corpus files and unseen meshes, half pBRDF tables",
        ),
        Split(
            "test-textured",
            "test",
            seed=24_000,
            count=48,
            shapes="meshes",
            pbrdfs=True,
            keep_raw=True,
            objects=(1, 3),
            table_fraction=0.5,
            assets="examples-gltf",
            texture_fraction=1.0,
            asset_materials=True,
            description="1-3 objects with textured materials: unseen meshes with procedural textures (half pBRDF "
            "table mixtures) and the shipped CC0 glTF models with their own",
        ),
    )
}


def _twin(name: str, of: str, pattern: str, description: str) -> Split:
    """The scenes of split ``of`` (every setting) under another display pattern."""
    return replace(SPLITS[of], name=name, pattern=pattern, twin_of=of, description=description)


# The ablation's uniform white illumination (Table 3, "white"): the same scenes, white display.
for _split in (
    _twin(
        "train-engine-white", "train-engine", "white", "train-engine's scenes under a uniform white display (ablation)"
    ),
    _twin("test-scenes-white", "test-scenes", "white", "test-scenes under a uniform white display (ablation)"),
):
    SPLITS[_split.name] = _split


def get_split(name: str) -> Split:
    """The split called ``name``.

    Raises:
        ValueError: unknown name (the message lists the valid ones).
    """
    try:
        return SPLITS[name]
    except KeyError:
        raise ValueError(f"unknown split {name!r}; valid: {', '.join(SPLITS)}") from None


def test_splits() -> list[Split]:
    """The test splits every model is scored on, in definition order, all of the nominal rig.

    Twins are the ablation's only; a perturbed rig's split is its experiment's, scored by name
    (``headless/evaluate.py --split test-pseudo-real``).
    """
    return [s for s in SPLITS.values() if s.role == "test" and s.twin_of is None and not s.rig_jitter]


test_splits.__test__ = False  # a library function, not a pytest test


def _read_json(path: Path) -> dict | None:
    """The JSON object in ``path``, or None when it is missing or unreadable (a dataset may lack labels)."""
    try:
        return read_json_object(path)
    except (OSError, ValueError):
        return None


def dataset_split(root: str | os.PathLike) -> str | None:
    """The split name a dataset folder was rendered as, or None for an unlabelled dataset.

    Reads ``manifest.json`` and, when it has no label (a run killed before its manifest was
    written), the first sample sidecar.
    """
    root = Path(root)
    manifest = _read_json(root / "manifest.json")
    if manifest is not None and isinstance(manifest.get("split"), str):
        return manifest["split"]
    samples = root / "samples"
    if samples.is_dir():
        for sidecar in sorted(samples.glob("*.json"))[:1]:
            data = _read_json(sidecar)
            if data is not None and isinstance(data.get("split"), str):
                return data["split"]
    return None


def require_role(root: str | os.PathLike, allowed: tuple[str, ...], purpose: str) -> str | None:
    """Refuse a dataset whose split role is not in ``allowed``.

    Unlabelled datasets (rendered without ``--split``) are accepted where ``test`` is not
    required: they cannot be test splits of this project.

    Args:
        root: dataset folder.
        allowed: roles the caller may read, e.g. ``("train",)`` for training data.
        purpose: what the caller does, for the message (e.g. ``"training"``).

    Returns:
        The dataset's split name (None when unlabelled).

    Raises:
        ValueError: the dataset is a split of another role, or unlabelled where only ``test``
            is allowed.
    """
    name = dataset_split(root)
    if name is None:
        if allowed == ("test",):
            raise ValueError(f"{root}: not a test split (render one with `headless/render.py --split test-...`)")
        return None
    role = SPLITS[name].role if name in SPLITS else None
    if role not in allowed:
        raise ValueError(
            f"{root}: is the {role or 'unknown'} split {name!r}; {purpose} may read only {'/'.join(allowed)} splits"
        )
    return name
