"""Objaverse-like random scenes: one or more objects at random poses in view, random polarimetric materials.

Everything is drawn from one seed, so a sample index and a run seed reproduce the scene bit for
bit (``sample_seed``). Shapes come from a pool of asset files (GLB/GLTF/OBJ/PLY, :mod:`.assets`)
and built-in shapes (:mod:`.procedural`, :mod:`.generated_shapes`, :mod:`.unseen_shapes`).
Materials come from a folder of measured/generated pBRDF tables (a ``materials.json`` there lists
each table with its Disney parameters), from analytic ``pplastic`` and ``roughconductor``
materials with random parameters, or from both (``table_fraction``). Objects never interpenetrate:
their bounding spheres are disjoint. One object with the default arguments draws exactly the
random stream of the single-object scenes before multi-object scenes existed, so existing
datasets and splits reproduce.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pbrdf.sensor.rig import Rig

from . import assets
from .asset_materials import asset_parts
from .placement import place
from .procedural import PROCEDURAL_SHAPES
from .random_textures import textured_material
from .spec import MaterialSpec, ObjectSpec, SceneSpec
from .unseen_shapes import UNSEEN_SHAPES

__all__ = [
    "METALS",
    "POSE_TRIES",
    "sample_seed",
    "random_material",
    "load_material_library",
    "random_scene",
    "benchmark_scene",
]

#: Approximate complex IOR n - ik of common metals at the display primaries (630, 532, 465 nm),
#: rounded from standard tabulations (e.g. Johnson and Christy 1972 for Au, Ag, Cu; Rakic 1995
#: for Al). Good enough for data variety; measured tables replace them when given.
METALS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "gold": ((0.18, 0.50, 1.30), (3.20, 2.30, 1.85)),
    "silver": ((0.06, 0.05, 0.05), (4.20, 3.40, 2.70)),
    "copper": ((0.27, 1.00, 1.20), (3.40, 2.60, 2.40)),
    "aluminium": ((1.45, 0.96, 0.63), (7.60, 6.60, 5.60)),
    "chrome": ((3.10, 2.90, 2.30), (3.30, 3.20, 3.10)),
    "iron": ((2.90, 2.90, 2.40), (3.10, 2.90, 2.70)),
    "brass": ((0.44, 0.74, 1.10), (3.70, 2.60, 2.10)),
}


#: Poses drawn for an object of a multi-object scene while its bounding sphere overlaps an earlier
#: object's; then the object is left out.
POSE_TRIES = 20


def sample_seed(run_seed: int, index: int) -> int:
    """Seed of sample ``index`` in a run: independent of sharding and of the order of work."""
    return int(np.random.SeedSequence([int(run_seed), int(index)]).generate_state(1)[0])


def random_material(rng: np.random.Generator, name: str = "material", *, metal_fraction: float = 0.3) -> MaterialSpec:
    """An analytic polarimetric material with random Disney-compatible parameters."""
    roughness = float(rng.uniform(0.05, 0.8))
    if rng.random() < metal_fraction:
        metal = sorted(METALS)[int(rng.integers(len(METALS)))]
        eta, k = METALS[metal]
        return MaterialSpec.metal(f"{name}_{metal}", eta, k, roughness)
    albedo = tuple(float(v) for v in rng.uniform(0.05, 0.9, size=3))
    ior = float(rng.uniform(1.35, 1.7))
    return MaterialSpec.plastic(f"{name}_plastic", albedo, roughness, ior=ior)


def load_material_library(folder: str | Path) -> list[MaterialSpec]:
    """Measured/generated pBRDF tables from ``folder/materials.json``.

    The file lists ``{"name", "table", "albedo", "roughness", "metallic"}`` entries; ``table``
    is relative to the folder.
    """
    folder = Path(folder)
    index = folder / "materials.json"
    if not index.is_file():
        raise FileNotFoundError(f"{index}: missing; a pBRDF folder needs materials.json listing its tables")
    try:
        entries = json.loads(index.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{index}: invalid JSON: {exc}") from None
    out = []
    for e in entries:
        table = folder / e["table"]
        if not table.is_file():
            raise FileNotFoundError(f"{index}: table {table} does not exist")
        out.append(MaterialSpec.measured(e["name"], str(table), e["albedo"], e["roughness"], e["metallic"]))
    if not out:
        raise ValueError(f"{index}: lists no materials")
    return out


def _object_range(objects: tuple[int, int]) -> tuple[int, int]:
    try:
        lo, hi = (int(v) for v in objects)
    except (TypeError, ValueError):
        lo, hi = 0, -1
    if not 1 <= lo <= hi or (lo, hi) != tuple(objects):
        raise ValueError(f"objects must be (min, max) integers with 1 <= min <= max, got {objects!r}")
    return lo, hi


def _unique(name: str, used: set[str]) -> str:
    """``name``, or ``name_2``, ``name_3``, ... whichever is not in ``used`` first."""
    out, k = name, 2
    while out in used:
        out, k = f"{name}_{k}", k + 1
    return out


def _bounding_sphere(mesh, to_world: NDArray) -> tuple[NDArray, float]:
    """World centre and radius of a placed mesh's bounding sphere (bounding-box centre, half diameter)."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    centre = (v.min(axis=0) + v.max(axis=0)) / 2
    radius = float(np.sqrt(np.max(np.sum((v - centre) ** 2, axis=1))))
    scale = float(np.linalg.norm(to_world[:3, 0]))  # rotation times a uniform scale
    return to_world[:3, :3] @ centre + to_world[:3, 3], scale * radius


def random_scene(
    rig: Rig,
    seed: int,
    *,
    asset_files: list[Path] | None = None,
    materials: list[MaterialSpec] | None = None,
    shapes: tuple[str, ...] | None = None,
    distance: tuple[float, float] = (0.5, 1.0),
    size: tuple[float, float] = (0.15, 0.35),
    objects: tuple[int, int] = (1, 1),
    table_fraction: float | None = None,
    pose_tries: int = POSE_TRIES,
    asset_materials: bool = False,
    texture_fraction: float = 0.0,
    corpus_files: list[Path] | None = None,
    corpus_fraction: float = 0.0,
) -> SceneSpec:
    """Objects at random, non-overlapping poses in view, each with its own random material.

    Randomness: one ``numpy.random.default_rng(seed)`` draws the number of objects (only when
    ``objects`` is a range), then per object in order: its shape, its shape seed (when the pool
    has built-in shapes), its pose (redrawn while its bounding sphere overlaps an earlier
    object's, at most ``pose_tries`` times, then the object is left out; the first always
    stays), whether its material is tabulated (only when ``0 < table_fraction < 1``) and the
    material. Objects are named ``object``, ``object_2``, ...; materials keep their names, made
    unique with ``_2``, ``_3``, ... suffixes (a table drawn twice is listed twice).

    Args:
        rig: the capture rig.
        seed: scene seed (e.g. :func:`sample_seed`).
        asset_files: asset meshes of the pool.
        materials: pBRDF table library (:func:`load_material_library`); None: analytic materials.
        shapes: built-in shapes of the pool (:data:`.procedural.PROCEDURAL_SHAPES`,
            :data:`.generated_shapes.GENERATED_SHAPES`, :data:`.unseen_shapes.UNSEEN_SHAPES`);
            None: none with ``asset_files``, else the procedural shapes.
        distance: object distance from the camera in metres.
        size: object diameter in metres.
        objects: (min, max) number of objects, inclusive; fewer when poses run out.
        table_fraction: probability that an object's material is a table of ``materials`` rather
            than an analytic one; None: 1 with ``materials``, else 0.
        pose_tries: pose draws per object while it overlaps an earlier one.
        asset_materials: an asset file with materials (glTF, OBJ+MTL) becomes one object per
            material, ``object_<i>_part<j>`` with mesh ``<file>#material=<K>`` and the file's own
            material (:func:`.asset_materials.asset_parts`; no table or analytic draw; triangles
            without a material get one random analytic material); the notes of its reading go
            to ``metadata["asset_notes"][file]``. False: every file is one object, as before.
        texture_fraction: probability that an object's drawn material (not an asset's own)
            gets seeded procedural textures (:func:`.random_textures.textured_material`: varying
            base colour and roughness, metal segments or wear, a normal map, a mix of tables);
            drawn after the material, only when above 0, so 0 keeps the random stream of
            untextured scenes.
        corpus_files: real meshes (:func:`.mesh_corpus.corpus_files`) an object is drawn from
            with probability ``corpus_fraction`` (drawn first, only when above 0, so 0 keeps the
            random stream), else from the pool; a corpus mesh gets a drawn material.
        corpus_fraction: that probability, in [0, 1]; above 0 it needs ``corpus_files``.

    Returns:
        The scene, seeded with ``seed % 2**31``.

    Raises:
        ValueError: an empty pool, a bad ``objects`` range, a ``table_fraction`` outside [0, 1] or
            above 0 without ``materials``, or no pose in view (:func:`.placement.place`).
    """
    lo, hi = _object_range(objects)
    if table_fraction is None:
        table_fraction = 1.0 if materials else 0.0
    if not 0.0 <= table_fraction <= 1.0:
        raise ValueError(f"table_fraction must be in [0, 1], got {table_fraction}")
    if table_fraction > 0 and not materials:
        raise ValueError(f"table_fraction {table_fraction} > 0 needs a pBRDF table library (materials)")
    if pose_tries < 1:
        raise ValueError(f"pose_tries must be >= 1, got {pose_tries}")
    if not 0.0 <= texture_fraction <= 1.0:
        raise ValueError(f"texture_fraction must be in [0, 1], got {texture_fraction}")
    if not 0.0 <= corpus_fraction <= 1.0 or (corpus_fraction > 0 and not corpus_files):
        raise ValueError(f"corpus_fraction must be in [0, 1] and above 0 only with corpus_files, got {corpus_fraction}")
    files = [str(f) for f in asset_files or ()]
    builtins = tuple(shapes) if shapes is not None else (() if files else PROCEDURAL_SHAPES)
    pool = files + [f"builtin:{s}" for s in builtins]
    if not pool:
        raise ValueError("random_scene: no shapes to draw from (no asset files and no built-in shapes)")
    rng = np.random.default_rng(seed)
    count = lo if lo == hi else int(rng.integers(lo, hi + 1))
    placed: list[tuple[NDArray, float]] = []
    objs: list[ObjectSpec] = []
    mats: list[MaterialSpec] = []
    notes: dict[str, list[str]] = {}
    for _ in range(count):
        if corpus_fraction > 0 and rng.random() < corpus_fraction:
            k, mesh_ref = -1, str(corpus_files[int(rng.integers(len(corpus_files)))])
        else:
            k = int(rng.integers(len(pool)))
            mesh_ref = pool[k]
        if builtins and k >= 0:
            shape_seed = int(rng.integers(2**31))  # drawn for every shape, so the stream does not depend on it
            if k >= len(files) and builtins[k - len(files)] not in UNSEEN_SHAPES:
                mesh_ref = f"{mesh_ref}?seed={shape_seed}"
        mesh = assets.load_mesh(mesh_ref)
        for _ in range(pose_tries):
            to_world = place(mesh, rig, rng, distance=distance, size=size)
            centre, radius = _bounding_sphere(mesh, to_world)
            if all(np.linalg.norm(centre - c) >= radius + r for c, r in placed):
                break
        else:
            continue  # no free pose: leave the object out
        placed.append((centre, radius))
        suffix = "" if len(placed) == 1 else f"_{len(placed)}"  # objects (assets) placed so far
        own = asset_parts(mesh_ref) if asset_materials and 0 <= k < len(files) else None
        if own is not None:
            _add_parts(own, rng, tuple(map(tuple, to_world)), f"object{suffix}", objs, mats)
            notes.update({own.file: list(own.notes)} if own.notes else {})
            continue
        table = table_fraction == 1.0 or (0.0 < table_fraction and rng.random() < table_fraction)
        material = materials[int(rng.integers(len(materials)))] if table else random_material(rng, f"material{suffix}")
        if texture_fraction > 0 and rng.random() < texture_fraction:
            material = textured_material(rng, material, materials or ())
        material = replace(material, name=_unique(material.name, {m.name for m in mats}))
        obj = ObjectSpec(
            name=f"object{suffix}", mesh=mesh_ref, to_world=tuple(map(tuple, to_world)), material=material.name
        )
        objs.append(obj)
        mats.append(material)
    meta = {"asset_notes": notes} if notes else {}
    return SceneSpec(rig=rig, objects=tuple(objs), materials=tuple(mats), seed=int(seed) % 2**31, metadata=meta)


def _add_parts(
    own, rng: np.random.Generator, to_world: tuple, name: str, objs: list[ObjectSpec], mats: list[MaterialSpec]
) -> None:
    """One object per part of an asset (:class:`.asset_materials.AssetParts`) at one pose, each with its material."""
    for j, part in enumerate(own.parts):
        fallback = name.replace("object", "material", 1) + f"_part{j}"
        material = part.material if part.material is not None else random_material(rng, fallback)
        material = replace(material, name=_unique(material.name, {m.name for m in mats}))
        objs.append(ObjectSpec(name=f"{name}_part{j}", mesh=part.mesh, to_world=to_world, material=material.name))
        mats.append(material)


def benchmark_scene(seed: int = 0) -> SceneSpec:
    """The render benchmark's fixed scene: a blob of pplastic (albedo 0.6, 0.4, 0.2; roughness 0.3) at 0.7 m.

    Args:
        seed: the scene's render seed.
    """
    m = np.eye(4)
    m[:3, :3] *= 0.25
    m[:3, 3] = (0.03, -0.02, -0.7)
    mat = MaterialSpec.plastic("plastic", (0.6, 0.4, 0.2), roughness=0.3)
    obj = ObjectSpec("blob", "builtin:blob?seed=1", tuple(map(tuple, m)), "plastic")
    return SceneSpec(rig=Rig(), objects=(obj,), materials=(mat,), seed=seed)
