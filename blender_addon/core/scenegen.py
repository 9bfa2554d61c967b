"""Objaverse-like random scenes: an asset, a random pose in view, a random polarimetric material.

Everything is drawn from one seed, so a sample index and a run seed reproduce the scene bit for
bit (``sample_seed``). Assets come from a folder (GLB/GLTF/OBJ/PLY, :mod:`.assets`) or, without
one, from the built-in procedural set. Materials come from a folder of measured/generated pBRDF
tables (a ``materials.json`` there lists each table with its Disney parameters) or, without one,
from analytic ``pplastic`` and ``roughconductor`` materials with random parameters.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pbrdf.sensor.rig import Rig

from . import assets
from .procedural import PROCEDURAL_SHAPES
from .spec import MaterialSpec, ObjectSpec, SceneSpec
from .unseen_shapes import UNSEEN_SHAPES

__all__ = ["METALS", "sample_seed", "random_material", "load_material_library", "random_scene", "benchmark_scene"]

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


def random_scene(
    rig: Rig,
    seed: int,
    *,
    asset_files: list[Path] | None = None,
    materials: list[MaterialSpec] | None = None,
    shapes: tuple[str, ...] = PROCEDURAL_SHAPES,
    distance: tuple[float, float] = (0.5, 1.0),
    size: tuple[float, float] = (0.15, 0.35),
) -> SceneSpec:
    """One object at a random pose in view, with a random material; reproducible from ``seed``.

    Args:
        rig: the capture rig.
        seed: scene seed (e.g. :func:`sample_seed`).
        asset_files: asset meshes to choose from; None uses the built-in ``shapes``.
        shapes: built-in shapes to choose from (:data:`.procedural.PROCEDURAL_SHAPES`, the
            training shapes, or :data:`.unseen_shapes.UNSEEN_SHAPES`).
        materials: material library to choose from; None draws analytic materials.
        distance: object distance from the camera in metres.
        size: object diameter in metres.
    """
    rng = np.random.default_rng(seed)
    if asset_files:
        mesh_ref = str(asset_files[int(rng.integers(len(asset_files)))])
    else:
        shape = shapes[int(rng.integers(len(shapes)))]
        shape_seed = int(rng.integers(2**31))  # drawn for every shape, so the stream does not depend on it
        mesh_ref = f"builtin:{shape}" if shape in UNSEEN_SHAPES else f"builtin:{shape}?seed={shape_seed}"
    mesh = assets.load_mesh(mesh_ref)
    to_world = assets.place(mesh, rig, rng, distance=distance, size=size)
    material = materials[int(rng.integers(len(materials)))] if materials else random_material(rng)
    obj = ObjectSpec(name="object", mesh=mesh_ref, to_world=tuple(map(tuple, to_world)), material=material.name)
    return SceneSpec(rig=rig, objects=(obj,), materials=(material,), seed=int(seed) % 2**31)


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
