"""Ground-truth material maps of textured scenes, from exactly what was rendered.

The truth pass renders a stand-in of the scene: the same meshes (with their UVs), the same
sensor, crop, film filter (box), sampler, ``spp`` and seed as the first colour pass, so the same
pixel sample positions (tested: the coverage is the same, sample for sample), with every
object's BSDF a ``diffuse`` whose reflectance is a bitmap of :func:`.texel_grid.realized` on the
material's grid (the arrays the render looked up), or of the constants for untextured materials.
Mitsuba's ``aov`` integrator reports that reflectance (``ab:albedo``) at each sample's hit and
the film averages it over the pixel, as it averages the Stokes images. It runs in the RGB variant
of the same backend (:func:`rgb_variant`), three quantities per pass: the albedo, then
roughness, metallic and a constant 1 whose pixel mean is the coverage; the mean over the samples
that hit an object is the ratio. Two passes, switched by parameter updates, compiled once per
process and texture size.

The normal-mapped shading normal: the first pass also averages the hit's UV, ``dp_du`` and
shading normal over the pixel; the tangent-space normal map is looked up at the mean UV and
turned into the frame Mitsuba's ``normalmap`` builds (``s`` = ``dp_du`` orthogonalized against
the shading normal ``n``, ``t = n x s``). An approximation of the per-sample mean where the frame
or the map varies within a pixel (silhouettes, UV seams, map detail finer than a pixel).
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from . import mitsuba_scene as ms
from . import texel_grid as tg
from .textured_bsdf import bitmap, has_textures

if TYPE_CHECKING:
    from .passes import RenderSettings
    from .spec import SceneSpec

__all__ = ["PASSES", "mapped_normals", "needs_truth_pass", "rgb_variant", "truth_pass"]

#: The two passes: an RGB albedo pass, and roughness, metallic and a constant 1 (the coverage).
PASSES = (("albedo_r", "albedo_g", "albedo_b"), ("roughness", "metallic", "coverage"))
#: Side of the bitmap an untextured material's constants become: Dr.Jit compiles a 1-texel bitmap
#: (or a float) into other kernels than a larger one, a bitmap's size and values into none.
CONSTANT_TEXELS = 2
_FULL_AOVS = "ab:albedo,uv:uv,du:dp_du,nn:sh_normal"
_INTEGRATORS: dict[tuple[str, str], object] = {}


def needs_truth_pass(spec: SceneSpec) -> bool:
    """Whether some object's material has textures (else per-object constants are the truth)."""
    materials = {m.name: m for m in spec.materials}
    return any(has_textures(materials[o.material]) for o in spec.objects)


def rgb_variant(variant: str) -> str:
    """The RGB variant of the truth pass beside a mono-polarized one (same backend).

    >>> rgb_variant("llvm_ad_mono_polarized"), rgb_variant("cuda_ad_mono_polarized")
    ('llvm_ad_rgb', 'cuda_ad_rgb')
    """
    return variant.replace("mono_polarized", "rgb")


def _integrator(aovs: str):
    """The ``aov`` integrator, one per variant and AOV list (its kernels are reused)."""
    import mitsuba as mi  # noqa: PLC0415

    key = (mi.variant(), aovs)
    if key not in _INTEGRATORS:
        _INTEGRATORS[key] = mi.load_dict({"type": "aov", "aovs": aovs})
    return _INTEGRATORS[key]


def _stacks(spec: SceneSpec) -> list[tuple[NDArray, NDArray]]:
    """Per object: ``(H, W, 6)`` planes (albedo RGB, roughness, metallic, 1) and their ``to_uv``.

    An untextured material's constants are a :data:`CONSTANT_TEXELS`-square plane:
    every object is then the same ``diffuse`` of a bitmap, whose kernels one compile serves.
    """
    materials = {m.name: m for m in spec.materials}
    out = []
    for obj in spec.objects:
        m = materials[obj.material]
        if not has_textures(m):
            consts = np.array([*m.albedo, m.roughness, m.metallic, 1.0], np.float32)
            out.append((np.broadcast_to(consts, (CONSTANT_TEXELS, CONSTANT_TEXELS, 6)), np.eye(3)))
            continue
        grid = tg.material_grid(m)
        real = tg.realized(m, grid)
        h, w = grid.shape
        planes = np.empty((h, w, 6), np.float32)
        planes[..., :3] = np.asarray(real["albedo"], np.float32)
        planes[..., 3] = np.asarray(real["roughness"], np.float32)
        planes[..., 4] = np.asarray(real["metallic"], np.float32)
        planes[..., 5] = 1.0
        out.append((planes, grid.to_uv))
    return out


def truth_pass(
    spec: SceneSpec, meshes: list, window: ms.CropWindow, settings: RenderSettings, names: list[str], seed: int
) -> tuple[dict[str, NDArray[np.float32]], NDArray[np.float32], NDArray[np.float32], float]:
    """Render the material maps of a textured scene (see the module docstring).

    Renders in the RGB variant of the current mono-polarized one (:func:`rgb_variant`: three
    quantities per pass) and switches back.

    Args:
        spec: the scene.
        meshes: :func:`.passes.world_meshes` with ``uvs=True``.
        window: the crop window rendered.
        settings: the render settings (``spp``, ``sampler``).
        names: Mitsuba shape names of ``spec.objects``.
        seed: the first colour pass's seed (the same sample positions).

    Returns:
        ``(truth, aovs, coverage, seconds)``: ``truth`` with ``albedo (H, W, 3)``, ``roughness``,
        ``metallic`` (0 where no sample hit), ``uv (H, W, 2)`` (the pixel's mean UV) and
        ``coverage``;
        ``aovs (H, W, 8)`` the pixel means of UV, ``dp_du`` and the shading normal (world), for
        :func:`mapped_normals`; the coverage; the seconds spent.
    """
    import time  # noqa: PLC0415

    import mitsuba as mi  # noqa: PLC0415

    t0 = time.perf_counter()
    variant = mi.variant()
    with warnings.catch_warnings():
        # Each switch re-imports Mitsuba's Python integrators, re-applying @drjit.syntax (about 0.1 s);
        # after ~70 textured scenes in one process Dr.Jit warns of the count. Harmless: nothing here
        # uses those integrators, and the memory stays flat (docs/measurements/next_data.md).
        warnings.filterwarnings("ignore", message="The AST-transforming decorator", category=RuntimeWarning)
        mi.set_variant(rgb_variant(variant))
        try:
            images = _render_passes(mi, spec, meshes, window, settings, names, seed)
        finally:
            mi.set_variant(variant)
    first, second = images
    coverage = second[..., 2].copy()
    safe = np.where(coverage > 0, coverage, 1.0)[..., None]
    values = np.concatenate([first[..., :3], second[..., :2]], axis=-1) / safe
    aovs = first[..., 3:11] / safe
    truth = {"albedo": values[..., :3], "roughness": values[..., 3], "metallic": values[..., 4], "uv": aovs[..., :2],
             "coverage": coverage}  # fmt: skip
    return truth, aovs, coverage, time.perf_counter() - t0


def _render_passes(mi, spec, meshes, window, settings, names, seed) -> list[NDArray[np.float32]]:
    """The two stand-in renders (:data:`PASSES`), each ``(H, W, C)`` of pixel sums over samples / spp."""
    stacks = _stacks(spec)
    objects = {}
    for name, mesh, (planes, to_uv) in zip(names, meshes, stacks, strict=True):
        uv = mesh[4] if len(mesh) > 4 else None
        bsdf = mi.load_dict({"type": "diffuse", "reflectance": bitmap(planes[..., :3], to_uv)})
        objects[name] = ms.mesh_from_arrays(name, mesh[0], mesh[1], {"bsdf": bsdf}, normals=mesh[2], uvs=uv)
    sensor = ms.sensor_dict(spec.rig.camera, window, settings.spp, sampler=settings.sampler)
    sensor["film"]["pixel_format"] = "rgb"
    scene = mi.load_dict({"type": "scene", "sensor": sensor, **objects})
    params = mi.traverse(scene)
    out = []
    for p in range(len(PASSES)):
        if p > 0:
            updates = {}
            for name, (planes, _) in zip(names, stacks, strict=True):
                data = np.ascontiguousarray(np.flipud(planes[..., 3 * p : 3 * p + 3]), dtype=np.float32)
                updates[f"{name}.bsdf.reflectance.data"] = mi.TensorXf(data)
            params.update(updates)
        integ = _integrator(_FULL_AOVS if p == 0 else "ab:albedo")
        out.append(np.asarray(mi.render(scene, integrator=integ, seed=seed, spp=settings.spp), dtype=np.float32))
    return out


def mapped_normals(
    spec: SceneSpec, aovs: NDArray, object_index: NDArray, normal: NDArray, mask: NDArray
) -> NDArray[np.float32]:
    """The camera-frame shading normals with each normal-mapped object's map applied.

    Args:
        spec: the scene.
        aovs: ``(H, W, 8)`` from :func:`truth_pass` (pixel means of UV, ``dp_du``, shading normal).
        object_index: ``(H, W)`` object per pixel (-1 background).
        normal: ``(H, W, 3)`` camera-frame shading normals of the render (flipped toward the
            camera on the back of two-sided objects, :func:`.passes.aov_result`).
        mask: pixels that carry ground truth.

    Returns:
        ``(H, W, 3)`` unit normals, ``normal`` where no normal map applies. On a back face seen of a
        two-sided object the map's normal is mirrored through the surface, as ``twosided`` mirrors
        the BSDF's frame.
    """
    materials = {m.name: m for m in spec.materials}
    out = np.array(normal, dtype=np.float32, copy=True)
    w2c = np.asarray(spec.rig.camera.world_to_camera(), dtype=np.float64)[:3, :3]
    for i, obj in enumerate(spec.objects):
        mat = materials[obj.material]
        if not has_textures(mat):
            continue
        grid = tg.material_grid(mat)
        sel = mask & (object_index == i)
        if grid.normal is None or not sel.any():
            continue
        uv, du, nn = aovs[sel][:, 0:2], aovs[sel][:, 2:5], aovs[sel][:, 5:8]
        n = nn / np.maximum(np.linalg.norm(nn, axis=-1, keepdims=True), 1e-12)
        s = du - n * np.sum(n * du, axis=-1, keepdims=True)
        s /= np.maximum(np.linalg.norm(s, axis=-1, keepdims=True), 1e-12)
        t = np.cross(n, s)
        tex_uv = np.concatenate([uv, np.ones_like(uv[:, :1])], axis=-1) @ grid.to_uv.T
        local = tg.sample_bilinear(grid.normal, tex_uv[:, :2])
        local /= np.maximum(np.linalg.norm(local, axis=-1, keepdims=True), 1e-12)
        world = local[:, :1] * s + local[:, 1:2] * t + local[:, 2:3] * n
        cam, n_cam = world @ w2c.T, n @ w2c.T
        back = np.sum(n_cam * out[sel], axis=-1) < 0  # the render flipped this normal: a back face
        cam[back] -= 2 * np.sum(cam[back] * n_cam[back], axis=-1, keepdims=True) * n_cam[back]
        out[sel] = cam / np.maximum(np.linalg.norm(cam, axis=-1, keepdims=True), 1e-12)
    return out
