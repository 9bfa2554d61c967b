"""Real meshes for training scenes, from a corpus no test split uses (Debian's libcgal-demo, openscad-testing-data).

``tools/ensure_meshcorpus.sh`` (``make setup``) unpacks the mesh files of the two packages into
a folder (:data:`pbrdf.data.splits.MESH_CORPUS_DIR`); :func:`corpus_files` lists the usable ones,
in a fixed sorted order so a seed draws the same mesh on every machine. A file is usable when
:func:`.assets.load_mesh` loads it (OFF, PLY, STL; watertight or not), it has at least
:data:`MIN_FACES` faces (the cubes, tetrahedra and single triangles of these test-data packages
add nothing the procedural shapes lack), it is not an earlier file's geometry again (the same
mesh in another format or vertex order), and it is disjoint from the test splits: no name with a
word of :data:`TEST_KINDS` (the kinds of shape ``test-meshes`` and ``test-scenes`` draw:
knots, gears, spheres, cubes, the assimp models) and no geometry of a test split's built-in or
shipped meshes (:func:`held_out_fingerprints`). Refused files get one log line each. The scene
normalises every mesh to the engine's object size when it places it (:func:`.placement.place`).

The listing is cached in ``index.json`` inside the folder (rebuilt when a file's size or the
rules change; it also keeps the usable meshes' fingerprints and every refusal), with a digest
that the data engine's manifest records.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from functools import cache
from pathlib import Path

import numpy as np

from pbrdf.io.atomic import atomic_write_text

from . import assets
from .unseen_shapes import UNSEEN_SHAPES

__all__ = ["MIN_FACES", "SUFFIXES", "TEST_KINDS", "corpus_digest", "corpus_files", "fingerprint", "index_corpus",
           "held_out_fingerprints"]  # fmt: skip

log = logging.getLogger(__name__)

#: Mesh types of the corpus (what the two packages hold and the loader reads).
SUFFIXES = (".off", ".ply", ".stl")
#: Fewest faces of a usable mesh.
MIN_FACES = 200
#: Name fragments (lower case) of meshes left out because a test split draws that kind of shape:
#: test-meshes' unseen shapes (torus knot, vase, gear, L block, dumbbell, thin plate) and
#: test-scenes' assimp-testmodels files (cubes, spheres, Wuson, Spider).
TEST_KINDS = ("knot", "vase", "gear", "pinion", "dumbbell", "plate", "sphere", "cube", "wuson", "spider")
#: Bump when the rules change: the cached index is rebuilt.
RULES = f"v1 min_faces={MIN_FACES} kinds={','.join(TEST_KINDS)}"
INDEX = "index.json"


def fingerprint(mesh) -> tuple:
    """A scale-, position- and format-free summary of a mesh's geometry (face count, extents, area).

    Args:
        mesh: a ``trimesh.Trimesh`` (:func:`.assets.load_mesh`).

    Returns:
        ``(faces, sorted extents / largest (2 decimals), area / largest^2 (2 decimals))``.
    """
    ext = np.asarray(mesh.extents, dtype=np.float64)
    d = float(ext.max())
    ratios = tuple(float(v) for v in np.round(np.sort(ext / d), 2))
    return (len(mesh.faces), ratios, round(float(mesh.area) / d**2, 2))


@cache
def held_out_fingerprints() -> frozenset:
    """Fingerprints of the meshes the test splits draw that every clone has: the unseen shapes and the shipped glTFs."""
    from pbrdf.data.splits import ASSET_CORPORA  # noqa: PLC0415

    refs = [f"builtin:{s}" for s in UNSEEN_SHAPES]
    refs += [str(p) for p in assets.list_assets(ASSET_CORPORA["examples-gltf"])]
    return frozenset(fingerprint(assets.load_mesh(r)) for r in refs)


def _refusal(path: Path, rel: str, seen: dict[tuple, str]) -> tuple[str | None, tuple | None]:
    """Why ``path`` is not usable (None when it is), and its fingerprint."""
    low = rel.lower()
    kind = next((k for k in TEST_KINDS if k in low), None)
    if kind is not None:
        return f"name has {kind!r}: a test split draws this kind of shape", None
    try:
        mesh = assets.load_mesh(path)
    except (ValueError, OSError) as e:
        return str(e), None
    if len(mesh.faces) < MIN_FACES:
        return f"{len(mesh.faces)} faces < {MIN_FACES}", None
    fp = fingerprint(mesh)
    if fp in held_out_fingerprints():
        return "the geometry of a test split's mesh", None
    if fp in seen:
        return f"the geometry of {seen[fp]} again", None
    return None, fp


def index_corpus(folder: str | os.PathLike) -> tuple[dict[str, tuple], dict[str, str]]:
    """Sort a corpus folder's mesh files into usable and refused (module docs), without the cache.

    Returns:
        ``({usable file relative to folder: its fingerprint}`` in sorted order, ``{relative file: the
        one-line reason})``.

    Raises:
        FileNotFoundError: the folder is missing.
    """
    root = Path(folder)
    usable, refused, seen = {}, {}, {}
    for path in assets.list_assets(root, SUFFIXES):
        rel = path.relative_to(root).as_posix()
        why, fp = _refusal(path, rel, seen)
        if why is None:
            usable[rel] = fp
            seen[fp] = rel
        else:
            refused[rel] = why
    return usable, refused


def _sizes(root: Path) -> dict[str, int]:
    return {p.relative_to(root).as_posix(): p.stat().st_size for p in assets.list_assets(root, SUFFIXES)}


def corpus_files(folder: str | os.PathLike) -> list[Path]:
    """The usable meshes of a corpus folder, sorted, from its ``index.json`` (built and written when stale).

    Raises:
        FileNotFoundError: the folder is missing.
        ValueError: no usable mesh in it.
    """
    root = Path(folder)
    sizes = _sizes(root)
    index = root / INDEX
    try:
        cached = json.loads(index.read_text())
        fresh = cached.get("rules") == RULES and cached.get("sizes") == sizes
    except (OSError, ValueError, AttributeError):
        cached, fresh = None, False
    if not fresh:
        usable, refused = index_corpus(root)
        for rel, why in refused.items():
            log.info("mesh corpus: %s left out: %s", rel, why)
        cached = {"rules": RULES, "sizes": sizes, "files": list(usable), "refused": refused,
                  "fingerprints": usable}  # fmt: skip
        try:
            atomic_write_text(index, json.dumps(cached, indent=1, sort_keys=True))
        except OSError as e:  # a read-only corpus still works, indexed per run
            log.warning("mesh corpus: cannot write %s (%s); indexing again next run", index, e)
    if not cached["files"]:
        raise ValueError(f"{root}: no usable mesh in the corpus ({len(cached['refused'])} refused)")
    return [root / rel for rel in cached["files"]]


def corpus_digest(files: list[Path], root: str | os.PathLike) -> str:
    """SHA-256 (16 hex digits) of the listing and the files' contents: the same digest draws the same meshes."""
    h = hashlib.sha256()
    for f in files:
        h.update(
            f"{Path(f).relative_to(root).as_posix()}\0{hashlib.sha256(Path(f).read_bytes()).hexdigest()}\n".encode()
        )
    return h.hexdigest()[:16]
