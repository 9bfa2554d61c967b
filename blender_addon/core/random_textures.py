"""Seeded procedural textures for an asset without materials: the variation of an artist's object.

:func:`random_material_textures` draws a :class:`.textures.MaterialTextures` of
``procedural:`` textures (:mod:`.texture_patterns`) from a generator: base colour, roughness,
metallic (dielectric/metal switching), a mild normal map and, for pBRDF tables, a segment
mixture. Every pattern seed is drawn from the generator, so a scene's seed fixes its textures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .spec import MaterialSpec
from .textures import MAX_TABLES, PROCEDURAL_PREFIX, MaterialTextures, TextureSpec, texture_mean

__all__ = ["random_material_textures", "textured_material"]


def _seed(rng: np.random.Generator) -> int:
    return int(rng.integers(2**31))


def _spec(pattern: str, channels: Sequence[int], factor: Sequence[float], **params: Any) -> TextureSpec:
    return TextureSpec(f"{PROCEDURAL_PREFIX}{pattern}", channels=tuple(channels), factor=tuple(factor), params=params)


def _albedo_texture(rng: np.random.Generator, base: NDArray, size: int) -> TextureSpec:
    """Base colour modulated by noise, stripes or decals; every value at most ``max(base)`` <= 0.9."""
    kind = rng.choice(["noise", "stripes", "decals"], p=[0.45, 0.25, 0.3])
    seed = _seed(rng)
    if kind == "noise":  # mottled: the base colour darkened by up to 30-70 %
        low = float(rng.uniform(0.3, 0.7))
        return _spec("noise", (0, 1, 2), base, seed=seed, size=size, base=int(rng.integers(2, 9)), low=low)
    if kind == "stripes":
        return _spec("stripes", (0, 1, 2), base, seed=seed, size=size, angle=float(rng.uniform(0, math.pi)),
                     period=float(rng.uniform(0.05, 0.3)), duty=float(rng.uniform(0.2, 0.8)),
                     softness=float(rng.uniform(0.0, 0.02)), low=float(rng.uniform(0.2, 0.8)),
                     grain=float(rng.uniform(0.0, 0.3)))  # fmt: skip
    fill = [float(x) for x in rng.uniform(0.05, 0.9, 3)]
    ink = [float(x) for x in rng.uniform(0.0, 0.15, 3)]
    return _spec("decals", (0, 1, 2), (1.0, 1.0, 1.0), seed=seed, size=size, count=int(rng.integers(2, 7)),
                 labels=0.7, background=[float(x) for x in base], fill=fill, ink=ink,
                 grain=float(rng.uniform(0.0, 0.3)))  # fmt: skip


def _roughness_texture(rng: np.random.Generator, r: float, size: int) -> TextureSpec:
    """Roughness around ``r``: smooth variation, or scratches rougher (or polished) than the rest."""
    seed = _seed(rng)
    if rng.random() < 0.6:
        d = float(rng.uniform(0.05, 0.25))
        lo, hi = max(r - d, 0.0), min(r + d, 1.0)
        return _spec("noise", (0,), (1.0,), seed=seed, size=size, base=int(rng.integers(2, 9)), low=lo, high=hi)
    worn = float(np.clip(r + rng.choice([-1, 1]) * rng.uniform(0.15, 0.4), 0.02, 1.0))
    return _spec("wear", (0,), (1.0,), seed=seed, size=size, amount=float(rng.uniform(0.05, 0.3)),
                 axis=str(rng.choice(["u", "v"])), low=r, high=worn)  # fmt: skip


def random_material_textures(
    rng: np.random.Generator,
    material_kind: str,
    *,
    albedo: Sequence[float] | None = None,
    roughness: float | None = None,
    tables: Sequence[str] = (),
    size: int = 256,
) -> MaterialTextures:
    """Seeded procedural textures for an asset without materials: the variation of an artist's object.

    Slots by kind: base colour for every kind (noise, stripes, or decals and labels around
    ``albedo``); roughness variation (smooth, or scratches) for the analytic kinds; for
    ``pplastic`` and ``conductor`` in about a third of the draws a metallic mask (painted and bare
    metal side by side: segments, or worn paint over metal); a mild normal map in about a third of
    the draws; for ``measured`` with ``tables`` a segment weights texture mixing them.

    Args:
        rng: the generator every choice and pattern seed is drawn from.
        material_kind: ``"pplastic"``, ``"conductor"``, ``"diffuse"`` or ``"measured"``.
        albedo: the base colour (linear RGB in [0, 1], at most 0.9 used); drawn when None.
        roughness: the base roughness in [0, 1]; drawn when None.
        tables: ``measured`` only: the extra pBRDF tables (at most ``MAX_TABLES - 1``) mixed by
            segments after the material's own table.
        size: texture side in texels.

    Returns:
        MaterialTextures of ``procedural:`` TextureSpecs (params hold each seed); all values in
        [0, 1]. A material's constant albedo/roughness/metallic should be set to the textures'
        means (:func:`.textures.texture_mean`).

    Example:
        >>> t = random_material_textures(np.random.default_rng(0), "pplastic", size=32)
        >>> t.albedo.procedural, t.roughness.channels
        (True, (0,))
    """
    kinds = ("pplastic", "conductor", "diffuse", "measured")
    if material_kind not in kinds:
        raise ValueError(f"material_kind must be one of {list(kinds)}, got {material_kind!r}")
    if tables and material_kind != "measured" or len(tables) > MAX_TABLES - 1:
        raise ValueError(f"tables: only 'measured' mixes tables, at most {MAX_TABLES - 1} extra; got {list(tables)}")
    base = np.minimum(rng.uniform(0.05, 0.9, 3) if albedo is None else np.asarray(albedo, np.float64), 0.9)
    r = float(rng.uniform(0.05, 0.8) if roughness is None else roughness)
    kw: dict[str, Any] = {"albedo": _albedo_texture(rng, base, size)}
    if material_kind != "measured":
        kw["roughness"] = _roughness_texture(rng, r, size)
    if material_kind in ("pplastic", "conductor") and rng.random() < 0.35:
        seed = _seed(rng)
        if rng.random() < 0.5:
            kw["metallic"] = _spec("segments", (0,), (1.0,), seed=seed, size=size, count=2,
                                   softness=float(rng.uniform(0.0, 0.01)))  # fmt: skip
        else:  # paint worn off the metal beneath
            kw["metallic"] = _spec("wear", (0,), (1.0,), seed=seed, size=size, amount=float(rng.uniform(0.05, 0.3)))
    if rng.random() < 0.3:
        kw["normal"] = _spec("normal", (0, 1, 2), (1.0, 1.0, 1.0), seed=_seed(rng), size=size,
                             depth=float(rng.uniform(0.003, 0.015)), base=int(rng.integers(4, 17)))  # fmt: skip
    if tables:
        n = len(tables)
        kw["tables"] = tuple(tables)
        kw["weights"] = _spec("segments", range(n), (1.0,) * n, seed=_seed(rng), size=size, count=n + 1,
                              softness=float(rng.uniform(0.002, 0.01)))  # fmt: skip
    return MaterialTextures(**kw)


def textured_material(
    rng: np.random.Generator, material: MaterialSpec, library: Sequence[MaterialSpec] = (), *, size: int = 256
) -> MaterialSpec:
    """``material`` with seeded procedural textures (:func:`random_material_textures`) and their means as constants.

    A ``measured`` material mixes its table with one or two other tables of ``library`` (when
    it holds others) by segments; its constants become the weighted means of the tables' fitted
    Disney values. Analytic materials keep their kind; their albedo, roughness and metallic
    become the textures' means.

    Args:
        rng: the generator every choice is drawn from.
        material: the untextured material.
        library: the pBRDF table materials the mixture may draw from (:func:`.scenegen.load_material_library`).
        size: texture side in texels.

    Returns:
        The textured material (same name and kind).
    """
    others = [m for m in library if m.table != material.table] if material.kind == "measured" else []
    extra = []
    if others:
        for i in rng.choice(len(others), size=min(len(others), int(rng.integers(1, 3))), replace=False):
            extra.append(others[int(i)])
    tex = random_material_textures(rng, material.kind, albedo=material.albedo, roughness=material.roughness,
                                   tables=[m.table for m in extra], size=size)  # fmt: skip
    albedo = np.asarray(texture_mean(tex.albedo), np.float64) if tex.albedo is not None else np.asarray(material.albedo)
    rough = texture_mean(tex.roughness)[0] if tex.roughness is not None else material.roughness
    metal = texture_mean(tex.metallic)[0] if tex.metallic is not None else material.metallic
    if extra:  # the mixture's mean: weights of the extra tables, the rest on the own table
        w = np.asarray(texture_mean(tex.weights), np.float64)
        w = np.concatenate([[max(1.0 - w.sum(), 0.0)], w])
        mats = [material, *extra]
        scale = albedo / np.maximum(np.asarray(material.albedo, np.float64), 1e-6)  # the albedo texture's darkening
        albedo = w @ np.array([m.albedo for m in mats], np.float64) * np.minimum(scale, 1.0)
        rough = float(w @ np.array([m.roughness for m in mats]))
        metal = float(w @ np.array([m.metallic for m in mats]))
    return replace(material, albedo=tuple(float(a) for a in np.clip(albedo, 0.0, 1.0)), roughness=float(rough),
                   metallic=float(np.clip(metal, 0.0, 1.0)), textures=tex)  # fmt: skip
