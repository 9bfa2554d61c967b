"""Textured materials as polarization-aware Mitsuba BSDFs for one colour channel of the mono passes.

A material with :class:`.textures.MaterialTextures` becomes a tree of Mitsuba's polarized plugins
whose textures are ``bitmap`` lookups of :mod:`.texel_grid`'s arrays (one channel's plane each,
``raw``, data flipped so that row 0 of the image is at ``v = 1``, ``to_uv`` the grid's
``KHR_texture_transform``):

* ``pplastic``: ``pplastic`` with a ``diffuse_reflectance`` bitmap (the base colour) and an
  ``alpha`` bitmap (``max(roughness^2, MIN_ALPHA)``). With a ``metallic`` texture it is the
  ``blendbsdf`` of that dielectric and a ``roughconductor`` whose real index is
  :data:`pbrdf.polar.fresnel.METAL_N` and whose extinction ``k`` is solved per texel and channel so that
  its normal-incidence reflectance is the base colour (:func:`pbrdf.polar.fresnel.conductor_extinction`).
* ``conductor``: ``roughconductor`` with the material's ``eta`` and, with an albedo texture, ``k``
  solved per texel from it; with a ``metallic`` texture blended with a ``pplastic`` (IOR 1.5).
* ``measured``: the tables (the material's and ``textures.tables``) mixed per texel by nested
  ``blendbsdf`` (each level's weight is the rest's share), each table as :mod:`.table_bsdf`; an
  albedo texture adds a zero BSDF to the mixture, with weight ``1 - sum_i w_i s_i``, which
  scales table ``i`` by ``s_i = min(1, albedo / a_i)``. Tables on non-uniform grids are
  ``measured_polarized`` instead (the scene is then rebuilt per channel). Roughness and metallic textures do not
  change a table (its reflectance is measured); they are not rendered.
* ``diffuse``: ``diffuse`` with a ``reflectance`` bitmap (depolarizing, as untextured).

A normal map wraps the tree in Mitsuba's ``normalmap`` (the map's xy scaled by ``normal_scale``
and renormalized in :mod:`.texel_grid`). Every wrapper used (``blendbsdf``, ``normalmap``) keeps
the nested BSDFs' Mueller matrices: docs/textured_rendering.md says why each choice is physical.

Between colour channels only bitmap data, constants and table data change
(:func:`channel_updates`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from pbrdf.polar.fresnel import METAL_N, conductor_extinction

from . import texel_grid as tg

if TYPE_CHECKING:
    from .spec import MaterialSpec

__all__ = ["DIELECTRIC_IOR", "bitmap", "bsdf_dict", "channel_updates", "has_textures"]

#: IOR of the dielectric a ``metallic`` texture mixes into a ``conductor`` material (which has none).
DIELECTRIC_IOR = 1.5

#: Marks a tree that changes with the channel only by a rebuild (``measured_polarized`` has no parameters).
REBUILD = "<rebuild>"
#: Per-channel value of a parameter: a float, or an ``(H, W)`` plane on the material's grid.
_Value = Callable[[int], Any]


def has_textures(material: MaterialSpec) -> bool:
    """Whether the material has any texture (or a table mixture) to render."""
    t = material.textures
    return t is not None and bool(t.slots())


def bitmap(plane: NDArray, to_uv: NDArray) -> dict:
    """A ``raw`` bilinear Mitsuba ``bitmap`` of an ``(H, W)`` or ``(H, W, C)`` plane (row 0 at the top)."""
    import mitsuba as mi  # noqa: PLC0415

    data = np.asarray(plane, dtype=np.float32)
    data = data[..., None] if data.ndim == 2 else data
    return {
        "type": "bitmap", "data": mi.TensorXf(np.ascontiguousarray(np.flipud(data))), "raw": True,
        "filter_type": "bilinear", "wrap_mode": "repeat", "to_uv": mi.ScalarTransform3f(np.asarray(to_uv).tolist()),
    }  # fmt: skip


class _Tree:
    """Builds one channel's BSDF dict and records which parameters change with the channel."""

    def __init__(self, grid: tg.MaterialGrid, channel: int) -> None:
        self.grid = grid
        self.channel = channel
        self.varying: list[tuple[str, _Value]] = []  # (parameter key below the BSDF, value of a channel)

    def leaf(self, key: str, value: _Value, *, varies: bool) -> Any:
        """A texture parameter: a bitmap for a plane, a float for a constant."""
        v = value(self.channel)
        if isinstance(v, np.ndarray) and v.ndim >= 2:
            if varies:
                self.varying.append((f"{key}.data", value))
            return bitmap(v, self.grid.to_uv)
        if varies:
            self.varying.append((f"{key}.value", value))
        return float(v)

    def data(self, key: str, value: _Value) -> None:
        """A non-texture parameter that changes with the channel (a table's data)."""
        self.varying.append((key, value))


def _channel_plane(grid_plane: NDArray | None, constant) -> _Value:
    if grid_plane is None:
        return lambda c: float(np.asarray(constant, np.float64).reshape(-1)[c if np.size(constant) > 1 else 0])
    return lambda c: grid_plane[..., c] if grid_plane.ndim == 3 else grid_plane


def _alpha(grid: tg.MaterialGrid, material: MaterialSpec) -> _Value:
    from .mitsuba_scene import MIN_ALPHA  # noqa: PLC0415

    r = grid.roughness if grid.roughness is not None else material.roughness
    a = np.maximum(np.square(r, dtype=np.float32), MIN_ALPHA)
    return lambda c: a


def _plastic(t: _Tree, key: str, material: MaterialSpec, albedo: _Value, ior: float) -> dict:
    return {
        "type": "pplastic", "diffuse_reflectance": t.leaf(f"{key}.diffuse_reflectance", albedo, varies=True),
        "specular_reflectance": 1.0, "int_ior": float(ior), "ext_ior": 1.0,
        "alpha": t.leaf(f"{key}.alpha", _alpha(t.grid, material), varies=False), "distribution": "ggx",
    }  # fmt: skip


def _metal(t: _Tree, key: str, material: MaterialSpec, eta: _Value, k: _Value) -> dict:
    return {
        "type": "roughconductor", "eta": t.leaf(f"{key}.eta", eta, varies=True),
        "k": t.leaf(f"{key}.k", k, varies=True),
        "alpha": t.leaf(f"{key}.alpha", _alpha(t.grid, material), varies=False), "distribution": "ggx",
    }  # fmt: skip


def _metal_k(albedo: _Value, eta: _Value) -> _Value:
    """``k`` per texel whose normal-incidence reflectance is the base colour."""

    def k(c: int):
        a, n = albedo(c), eta(c)
        out = conductor_extinction(a, n)[0].astype(np.float32)
        return out if np.ndim(a) >= 2 else float(out)

    return k


def _blend(t: _Tree, key: str, weight: NDArray, first, second) -> dict:
    """``blendbsdf``: ``(1 - weight) first + weight second``; ``first``/``second`` build from their key."""
    return {
        "type": "blendbsdf", "weight": t.leaf(f"{key}.weight", lambda c: weight, varies=False),
        "bsdf_0": first(f"{key}.bsdf_0"), "bsdf_1": second(f"{key}.bsdf_1"),
    }  # fmt: skip


def _analytic(t: _Tree, key: str, material: MaterialSpec) -> dict:
    grid = t.grid
    albedo = _channel_plane(grid.albedo, material.albedo)
    if material.kind == "diffuse":
        return {"type": "diffuse", "reflectance": t.leaf(f"{key}.reflectance", albedo, varies=True)}
    if material.kind == "pplastic":
        eta = _channel_plane(None, METAL_N)
        k = _metal_k(albedo, eta)
        ior = float(material.ior)
    else:
        eta = _channel_plane(None, material.eta)
        k = _metal_k(albedo, eta) if grid.albedo is not None else _channel_plane(None, material.k)
        ior = DIELECTRIC_IOR
    if grid.metallic is not None:
        return _blend(t, key, grid.metallic, lambda k_: _plastic(t, k_, material, albedo, ior),
                      lambda k_: _metal(t, k_, material, eta, k))  # fmt: skip
    if material.kind == "pplastic":
        return _plastic(t, key, material, albedo, ior)
    return _metal(t, key, material, eta, k)


def _tables(t: _Tree, key: str, material: MaterialSpec, *, linear_light: bool) -> dict:
    """Nested ``blendbsdf`` over the tables (and a zero BSDF where an albedo texture scales them)."""
    from . import mitsuba_scene as ms  # noqa: PLC0415
    from . import table_bsdf  # noqa: PLC0415

    grid = t.grid
    table_bsdf.register()
    weights = grid.weights if grid.weights is not None else np.ones((*grid.shape, 1), np.float32)
    alpha = max(material.roughness**2, ms.MIN_ALPHA)
    parts: list[tuple[Callable[[str], dict], _Value]] = []
    if grid.albedo is not None:  # s_i = min(1, albedo / a_i): the rest of the unit weight goes to zero
        fitted = [tg.table_parameters(material, p)[0] for p in grid.tables]

        def scaled(i: int) -> _Value:
            a = np.maximum(fitted[i], 1e-6)
            return lambda c: weights[..., i] * np.minimum(1.0, grid.albedo[..., c] / a[c])

        comps = [scaled(i) for i in range(len(grid.tables))]
        parts.append((lambda k: {"type": "diffuse", "reflectance": 0.0},
                      lambda c: np.clip(1.0 - sum(f(c) for f in comps), 0.0, 1.0)))  # fmt: skip
    else:
        comps = [_plane_of(weights, i) for i in range(len(grid.tables))]

    def table(path: str) -> Callable[[str], dict]:
        def build(k: str) -> dict:
            wavelength = ms.CHANNEL_WAVELENGTHS_NM[t.channel]
            if not table_bsdf.uniform_axes(path):  # the plugin, rebuilt per channel (no parameters)
                t.data(REBUILD, lambda c: None)
                return {"type": "measured_polarized", "filename": str(path), "wavelength": wavelength,
                        "alpha_sample": ms.alpha_sample(alpha)}  # fmt: skip
            t.data(f"{k}.data", lambda c: table_bsdf.channel_matrices(path, ms.CHANNEL_WAVELENGTHS_NM[c])[0])
            return {
                "type": table_bsdf.PLUGIN, "filename": str(path), "wavelength": wavelength,
                "alpha_sample": max(alpha, ms.ALPHA_SAMPLE_LEVELS[0]), "linear_light": bool(linear_light),
            }  # fmt: skip

        return build

    parts += [(table(p), comps[i]) for i, p in enumerate(grid.tables)]
    return _mixture(t, key, parts)


def _plane_of(weights: NDArray, i: int) -> _Value:
    return lambda c: weights[..., i]


def _mixture(t: _Tree, key: str, parts: list[tuple[Callable[[str], dict], _Value]]) -> dict:
    """``sum_j w_j B_j`` as nested blends: level j blends ``B_j`` with the rest at the rest's share."""
    if len(parts) == 1:
        return parts[0][0](key)
    build, w0 = parts[0]
    rest = parts[1:]

    def share(c: int):
        head, tail = w0(c), sum(w(c) for _, w in rest)
        return np.where(head + tail > 0, tail / np.maximum(head + tail, 1e-12), 0.0).astype(np.float32)

    return {
        "type": "blendbsdf", "weight": t.leaf(f"{key}.weight", share, varies=True),
        "bsdf_0": build(f"{key}.bsdf_0"), "bsdf_1": _mixture(t, f"{key}.bsdf_1", rest),
    }  # fmt: skip


def _tree(material: MaterialSpec, channel: int, *, linear_light: bool) -> tuple[dict, list[tuple[str, _Value]]]:
    grid = tg.material_grid(material)
    t = _Tree(grid, channel)
    key = "nested_bsdf" if grid.normal is not None else ""
    if material.kind == "measured":
        d = _tables(t, key, material, linear_light=linear_light)
    else:
        d = _analytic(t, key, material)
    if grid.normal is not None:
        d = {"type": "normalmap", "normalmap": bitmap((grid.normal + 1.0) / 2.0, grid.to_uv), "bsdf": d}
    return d, [(k.lstrip("."), v) for k, v in t.varying]


def bsdf_dict(material: MaterialSpec, channel: int, *, linear_light: bool = False) -> dict:
    """The textured material's BSDF dict for colour channel ``channel`` (0, 1, 2).

    ``linear_light``: the tables skip their Mueller matrices' last column (:mod:`.table_bsdf`).
    """
    return _tree(material, channel, linear_light=linear_light)[0]


def _varying(material: MaterialSpec) -> list[tuple[str, _Value]]:
    """The parameters that change with the channel, cached per material and texture file version."""
    return _varying_cached(material, tg.material_grid(material))


@functools.lru_cache(maxsize=16)
def _varying_cached(material: MaterialSpec, grid: tg.MaterialGrid) -> list[tuple[str, _Value]]:
    return _tree(material, 0, linear_light=False)[1]


def channel_updates(material: MaterialSpec, channel: int, prefix: str) -> dict[str, Any] | None:
    """Scene-parameter updates (keys under ``prefix``, the BSDF's key) that switch the BSDF to ``channel``.

    None where the scene must be rebuilt: a table on a non-uniform grid (``measured_polarized``).
    """
    import mitsuba as mi  # noqa: PLC0415

    out: dict[str, Any] = {}
    varying = _varying(material)
    if any(key == REBUILD for key, _ in varying):
        return None
    for key, value in varying:
        v = value(channel)
        if key.endswith(".data") and isinstance(v, np.ndarray) and v.ndim == 2:
            v = mi.TensorXf(np.ascontiguousarray(np.flipud(v)[..., None], dtype=np.float32))
        elif isinstance(v, np.ndarray) and v.ndim == 4:  # a table's (Np, Nd, Nh, 16) matrices
            v = mi.Float(v.reshape(-1))
        else:
            v = float(v)
        out[f"{prefix}.{key}"] = v
    return out
