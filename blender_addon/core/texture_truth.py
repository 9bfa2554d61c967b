"""Ground-truth material maps of textured scenes, from exactly what was rendered.

The truth pass renders a stand-in of the scene: the same meshes (with their UVs), the same
sensor, crop, film filter (box), sampler, ``spp`` and seed as the first colour pass, so the same
pixel sample positions, with every object's BSDF a ``diffuse`` whose reflectance is one
quantity of :func:`.texel_grid.realized` as a bitmap on the material's grid (the arrays the
render looked up) or a constant for untextured materials. Mitsuba's ``aov`` integrator reports
that reflectance (``ab:albedo``) at each sample's hit and the film averages it over the pixel, as
it averages the Stokes images; dividing by the pixel's coverage (the film's alpha) gives the
mean over the samples that hit an object. One pass per scalar quantity (albedo R, G, B,
roughness, metallic), switched by parameter updates, compiled once per process and texture size.

The normal-mapped shading normal: the first pass also averages the hit's UV, ``dp_du`` and
shading normal over the pixel; the tangent-space normal map is looked up at the mean UV and
turned into the frame Mitsuba's ``normalmap`` builds (``s`` = ``dp_du`` orthogonalized against
the shading normal ``n``, ``t = n x s``). An approximation of the per-sample mean where the frame
or the map varies within a pixel (silhouettes, UV seams, map detail finer than a pixel).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from . import mitsuba_scene as ms
from . import texel_grid as tg
from .textured_bsdf import bitmap, has_textures

if TYPE_CHECKING:
    from .passes import RenderSettings
    from .spec import SceneSpec

__all__ = ["QUANTITIES", "needs_truth_pass", "truth_pass"]

#: The scalar quantities of the truth pass, in pass order.
QUANTITIES = ("albedo_r", "albedo_g", "albedo_b", "roughness", "metallic")
_FULL_AOVS = "ab:albedo,uv:uv,du:dp_du,nn:sh_normal"
_INTEGRATORS: dict[tuple[str, str], object] = {}


def needs_truth_pass(spec: SceneSpec) -> bool:
    """Whether some object's material has textures (else per-object constants are the truth)."""
    materials = {m.name: m for m in spec.materials}
    return any(has_textures(materials[o.material]) for o in spec.objects)


def _integrator(aovs: str):
    """The ``aov`` integrator around a path of depth 1 (its alpha is the coverage), one per variant."""
    import mitsuba as mi  # noqa: PLC0415

    key = (mi.variant(), aovs)
    if key not in _INTEGRATORS:
        _INTEGRATORS[key] = mi.load_dict({"type": "aov", "aovs": aovs, "integrator": {"type": "path", "max_depth": 1}})
    return _INTEGRATORS[key]


def _stacks(spec: SceneSpec) -> list[tuple[NDArray | None, NDArray | None, NDArray]]:
    """Per object: the ``(H, W, 5)`` quantity planes and the grid's ``to_uv`` (textured), else None, and 5 constants."""
    materials = {m.name: m for m in spec.materials}
    out = []
    for obj in spec.objects:
        m = materials[obj.material]
        consts = np.array([*m.albedo, m.roughness, m.metallic], np.float32)
        if not has_textures(m):
            out.append((None, None, consts))
            continue
        grid = tg.material_grid(m)
        real = tg.realized(m, grid)
        h, w = grid.shape
        albedo = np.broadcast_to(np.asarray(real["albedo"], np.float32), (h, w, 3))
        planes = [albedo[..., c] for c in range(3)]
        planes += [np.broadcast_to(np.asarray(real[k], np.float32), (h, w)) for k in ("roughness", "metallic")]
        out.append((np.stack(planes, axis=-1), grid.to_uv, consts))
    return out


def truth_pass(
    spec: SceneSpec, meshes: list, window: ms.CropWindow, settings: RenderSettings, names: list[str], seed: int
) -> tuple[dict[str, NDArray[np.float32]], NDArray[np.float32], NDArray[np.float32], float]:
    """Render the material maps of a textured scene (see the module docstring).

    Args:
        spec: the scene.
        meshes: :func:`.passes.world_meshes` with ``uvs=True``.
        window: the crop window rendered.
        settings: the render settings (``spp``, ``sampler``).
        names: Mitsuba shape names of ``spec.objects``.
        seed: the first colour pass's seed (the same sample positions).

    Returns:
        ``(truth, aovs, coverage, seconds)``: ``truth`` with ``albedo (H, W, 3)``, ``roughness``,
        ``metallic`` (0 where no sample hit) and ``uv (H, W, 2)`` (the pixel's mean UV);
        ``aovs (H, W, 8)`` the pixel means of UV, ``dp_du`` and the shading normal (world), for
        :func:`mapped_normals`; the coverage; the seconds spent.
    """
    import time  # noqa: PLC0415

    import mitsuba as mi  # noqa: PLC0415

    t0 = time.perf_counter()
    stacks = _stacks(spec)
    objects = {}
    for name, mesh, (planes, to_uv, consts) in zip(names, meshes, stacks, strict=True):
        refl = bitmap(planes[..., 0], to_uv) if planes is not None else float(consts[0])
        v, f, n = mesh[:3]
        uv = mesh[4] if len(mesh) > 4 else None
        bsdf = mi.load_dict({"type": "diffuse", "reflectance": refl})
        objects[name] = ms.mesh_from_arrays(name, v, f, {"bsdf": bsdf}, normals=n, uvs=uv)
    sensor = ms.sensor_dict(spec.rig.camera, window, settings.spp, sampler=settings.sampler)
    sensor["film"]["pixel_format"] = "luminance_alpha"
    scene = mi.load_dict({"type": "scene", "sensor": sensor, **objects})
    params = mi.traverse(scene)
    w, h = window.size
    values = np.zeros((h, w, len(QUANTITIES)), np.float32)
    for q in range(len(QUANTITIES)):
        if q > 0:
            updates = {}
            for name, (planes, _, consts) in zip(names, stacks, strict=True):
                if planes is None:
                    updates[f"{name}.bsdf.reflectance.value"] = float(consts[q])
                else:
                    data = np.ascontiguousarray(np.flipud(planes[..., q])[..., None], dtype=np.float32)
                    updates[f"{name}.bsdf.reflectance.data"] = mi.TensorXf(data)
            params.update(updates)
        integ = _integrator(_FULL_AOVS if q == 0 else "ab:albedo")
        img = np.asarray(mi.render(scene, integrator=integ, seed=seed, spp=settings.spp))
        # Layout: [Y, A, albedo x3 (equal in mono), (uv x2, dp_du x3, sh_normal x3 in the first pass)].
        if q == 0:
            coverage = img[..., 1].copy()
            aovs = img[..., 5:13].copy()
        values[..., q] = img[..., 2]
    safe = np.where(coverage > 0, coverage, 1.0)
    values /= safe[..., None]
    aovs /= safe[..., None]
    truth = {"albedo": values[..., :3], "roughness": values[..., 3], "metallic": values[..., 4], "uv": aovs[..., :2]}
    return truth, aovs, coverage, time.perf_counter() - t0


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
