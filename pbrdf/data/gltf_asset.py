"""A prediction as a glTF 2.0 asset: relief mesh (or card), PBR textures, tangent-space normal map, camera.

:func:`build_asset` turns predicted maps (:func:`pbrdf.data.predictions.write_predictions`'s
``pred``) into the parts of a .glb (:mod:`pbrdf.io.gltf`), checked and encoded in memory;
:func:`write_asset` writes it (``headless/infer.py --gltf`` builds before it writes any file),
:func:`write_gltf_asset` does both.
What the file holds:

* Mesh: with a depth map, the relief mesh of :func:`pbrdf.geometry.relief.relief_mesh` (the same
  triangles as the Blender import) over the mask grown by one pixel, the maps extended two pixels
  past the mask (:func:`pbrdf.geometry.relief.extend_maps`); without one (``--card``), a flat quad
  facing the camera at ``distance`` that covers the textures' pixels. Vertices are in the camera
  frame (x right, y up, looking down -z), which is glTF's frame: the mesh node and the camera
  node both sit at the origin. Vertex normals are the mesh's own (area-weighted face normals);
  tangents follow increasing u, orthogonalised against the normal, with handedness ``w`` so that
  ``B = cross(N, T) w`` points up the image (glTF normal maps: +Y up).
* Textures, cropped to the mask's bounding box plus two pixels, one texel per capture pixel; UVs
  put every relief vertex on its texel's centre: base colour (sRGB albedo, the mask as alpha,
  ``alphaMode`` MASK at 0.5, so the surface is cut where the mask's pixels end), metallic-roughness
  (linear: roughness in G, metallic in B, R = 1), and the normal map. No value is converted: the
  predicted roughness is already perceptual roughness with GGX ``alpha = r^2``
  (:func:`pbrdf.brdf.disney.roughness_to_alpha`), which is glTF's (and Blender's Principled) meaning,
  and the albedo is the Disney base colour, glTF's ``baseColor`` (the F0 of a metal, the diffuse
  colour of a dielectric, whose F0 is 0.04 in both at the default specular 0.5).
* Normal map: at each texel, the predicted camera-space normal ``n`` in the exported frame
  interpolated there, ``n_ts = (T.n, B.n, N.n)``, stored as ``0.5 + 0.5 n_ts`` in 8 bits. On a
  relief every texel of the mesh is a vertex, so the frame is the vertex's own; on the card the
  frame is the same everywhere (``T = x, B = y, N = z``: ``n_ts`` is ``n``). A viewer that
  interpolates the exported TANGENT and NORMAL rebuilds ``n`` at the texels (to 8-bit rounding);
  TANGENT is exported so the result does not depend on a viewer's MikkTSpace.
* Camera: glTF perspective cameras are symmetric about their axis, so a principal point off the
  image centre cannot be written. The camera is the symmetric frustum around the optical axis
  that just holds the whole capture image: ``yfov = 2 atan(hy / fy)``,
  ``aspectRatio = (hx / fx) / (hy / fy)`` with ``hx = max(cx, W - cx)``, ``hy = max(cy, H - cy)``.
  The mesh keeps its exact rays, so rendering that camera at ``2 hx x 2 hy`` pixels shows capture
  pixel ``(u, v)`` at ``(u + hx - cx, v + hy - cy)``: no offset, only a wider frame when the
  principal point is off-centre (exactly the capture's frame when it is centred). The camera's
  ``extras`` hold ``K``, the capture size, that viewport size and the offset.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.data.capture_meta import DEFAULT_DISTANCE_M
from pbrdf.geometry.relief import dilate, extend_maps, relief_mesh
from pbrdf.io.gltf import GlbCamera, GlbMaterial, GlbMesh, encode_png, write_glb

__all__ = [
    "GltfAsset",
    "build_asset",
    "capture_camera",
    "write_asset",
    "write_gltf_asset",
    "linear_to_srgb",
    "vertex_frames",
]

#: Near and far planes of the exported camera, m (the rig works at 0.5 - 1 m; room to move around).
ZNEAR, ZFAR = 0.01, 100.0
_MAPS = ("normal", "albedo", "roughness", "metallic")
_MARGIN = 2  # texture pixels past the mask's box: the two extended rings


@dataclass(frozen=True)
class GltfAsset:
    """The parts of one .glb (:func:`pbrdf.io.gltf.write_glb`) and where its textures lie in the capture.

    Attributes:
        mesh: the relief mesh or the card.
        material: base colour, metallic-roughness and normal PNGs.
        camera: the capture camera.
        box: ``(y0, x0, y1, x1)`` the capture pixels the textures hold (texel ``(i, j)`` is pixel
            ``(y0 + i, x0 + j)``).
        extras: what the asset's ``extras`` record.
    """

    mesh: GlbMesh
    material: GlbMaterial
    camera: GlbCamera
    box: tuple[int, int, int, int]
    extras: dict[str, Any]


def linear_to_srgb(x: ArrayLike) -> NDArray:
    """The sRGB transfer function (IEC 61966-2-1) of linear values in [0, 1].

    Example:
        >>> round(float(linear_to_srgb(0.21586)), 4)  # linear mid-grey
        0.502
    """
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def vertex_frames(vertices: NDArray, faces: NDArray, uvs: NDArray) -> tuple[NDArray, NDArray]:
    """Unit vertex normals ``(N, 3)`` and glTF tangents ``(N, 4)`` of a triangle mesh with glTF UVs.

    Normals: the sum of the adjacent faces' ``cross(e1, e2)`` (area-weighted). Tangents: the
    adjacent faces' ``dP/du`` weighted by their UV area, minus its component along the normal;
    ``w = +1`` where ``cross(N, T)`` points along ``-dP/dv`` (up the image: glTF's v runs down).
    A vertex without faces gets ``N = +z``; a degenerate tangent the camera's x (or y) made
    orthogonal to ``N``.

    Example: a camera-facing triangle, u to the right, v down the image:

        >>> n, t = vertex_frames(np.array([[0.0, 0, -1], [1, 0, -1], [0, 1, -1]]), np.array([[0, 1, 2]]),
        ...                      np.array([[0.0, 1.0], [1.0, 1.0], [0.0, 0.0]]))
        >>> n[0].tolist(), t[0].tolist()
        ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 1.0])
    """
    p = vertices[faces]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    uv = uvs[faces]
    du1, du2 = uv[:, 1, 0] - uv[:, 0, 0], uv[:, 2, 0] - uv[:, 0, 0]
    dv1, dv2 = uv[:, 1, 1] - uv[:, 0, 1], uv[:, 2, 1] - uv[:, 0, 1]
    sign = np.sign(du1 * dv2 - du2 * dv1)[:, None]  # dP/du, dP/dv times the UV area (2x), no division
    dp_du = sign * (e1 * dv2[:, None] - e2 * dv1[:, None])
    dp_dv = sign * (e2 * du1[:, None] - e1 * du2[:, None])
    n, corners = len(vertices), faces.T.ravel()  # each face's value goes to its three corners
    acc = {
        key: np.stack([np.bincount(corners, np.tile(per_face[:, c], 3), minlength=n) for c in range(3)], axis=1)
        for key, per_face in (("n", np.cross(e1, e2)), ("t", dp_du), ("b", dp_dv))
    }
    normal = _unit(acc["n"], np.array([0.0, 0.0, 1.0]))
    tangent = acc["t"] - normal * (acc["t"] * normal).sum(1, keepdims=True)
    for axis in np.eye(3)[:2]:  # degenerate (no faces, or dP/du along N): the camera's x, else y, minus its N part
        bad = np.linalg.norm(tangent, axis=1) <= 1e-9 * np.linalg.norm(acc["t"], axis=1) + 1e-30
        tangent[bad] = axis - normal[bad] * (normal[bad] @ axis)[:, None]
    tangent = _unit(tangent, np.array([1.0, 0.0, 0.0]))
    w = np.where((np.cross(normal, tangent) * -acc["b"]).sum(1) < 0, -1.0, 1.0)
    return normal, np.concatenate([tangent, w[:, None]], axis=1)


def _unit(v: NDArray, fallback: NDArray) -> NDArray:
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(norm > 1e-30, v / np.where(norm > 1e-30, norm, 1.0), fallback)


def _checked(pred: Mapping[str, NDArray], intrinsics: ArrayLike) -> tuple[NDArray, NDArray]:
    """``(mask (H, W) bool, K (3, 3))``; ValueError naming the first bad map."""
    if "mask" not in pred:
        raise ValueError("pred: mask: missing")
    h, w = np.shape(pred["mask"])[:2]
    for key in (*_MAPS, "depth"):
        if key not in pred:
            if key == "depth":
                continue
            raise ValueError(f"pred: {key}: missing")
        a = np.asarray(pred[key])
        if a.ndim != 3 or a.shape[:2] != (h, w) or not np.all(np.isfinite(a)):
            raise ValueError(f"pred: {key}: expected a finite ({h}, {w}, C) map, got {a.shape}")
    k = np.asarray(intrinsics, dtype=np.float64)
    if k.shape != (3, 3) or not np.all(np.isfinite(k)) or not (k[0, 0] > 0 and k[1, 1] > 0):
        raise ValueError(f"intrinsics: expected a pinhole K (3, 3) with positive focal lengths, got {k.tolist()}")
    mask = np.asarray(pred["mask"])[..., 0] > 0.5
    if not mask.any():
        raise ValueError("pred: mask: empty, nothing to export")
    if "depth" in pred and not np.all(np.asarray(pred["depth"])[..., 0][mask] > 0):
        raise ValueError("pred: depth: must be positive on the mask")
    return mask, k


def build_asset(
    pred: Mapping[str, NDArray], intrinsics: ArrayLike, *, distance: float = DEFAULT_DISTANCE_M, max_jump: float = 0.05
) -> GltfAsset:
    """The glTF asset of a prediction (see the module docstring for what it holds).

    Args:
        pred: ``{"normal": (H, W, 3) unit camera-space, "albedo": (H, W, 3) linear, "roughness",
            "metallic", "mask": (H, W, 1), optional "depth": (H, W, 1) m along the axis}``
            (``headless/infer.py``'s maps); no depth: a card.
        intrinsics: ``K (3, 3)`` of the maps' grid.
        distance: the card's distance in m (unused with a depth map).
        max_jump: the relief's largest relative depth step inside a triangle.

    Raises:
        ValueError: one line naming the bad map, or a depth map that gives no triangle.
    """
    mask, k = _checked(pred, intrinsics)
    ys, xs = np.nonzero(mask)
    y0, x0 = max(int(ys.min()) - _MARGIN, 0), max(int(xs.min()) - _MARGIN, 0)
    y1, x1 = min(int(ys.max()) + 1 + _MARGIN, mask.shape[0]), min(int(xs.max()) + 1 + _MARGIN, mask.shape[1])
    crop = (slice(y0, y1), slice(x0, x1))
    inside = mask[crop]
    maps = {key: np.asarray(pred[key], dtype=np.float32)[crop] for key in (*_MAPS, "depth") if key in pred}
    maps = {key: v[..., 0] if key == "depth" else v for key, v in maps.items()}
    maps.update(extend_maps(maps, inside))
    k_crop = k.copy()
    k_crop[0, 2] -= x0
    k_crop[1, 2] -= y0
    th, tw = inside.shape
    if "depth" in maps:
        vertices, faces, pixels = relief_mesh(maps["depth"], dilate(inside), k_crop, max_jump=max_jump)
        if len(faces) == 0:
            raise ValueError(
                f"pred: depth: gives no triangle inside the mask (each crosses a depth step over {max_jump:.0%}); "
                "a card (no depth) needs none"
            )
        used = np.unique(faces)  # drop vertices no triangle uses
        remap = np.zeros(len(vertices), np.int64)
        remap[used] = np.arange(len(used))
        vertices, faces, pixels = vertices[used], remap[faces], pixels[used]
        uvs = np.stack([(pixels[:, 1] + 0.5) / tw, (pixels[:, 0] + 0.5) / th], axis=1)
    else:
        u, v = np.array([0.0, tw, 0.0, tw]), np.array([0.0, 0.0, th, th])  # top-left, top-right, bottom-...
        rays = np.stack([(u - k_crop[0, 2]) / k_crop[0, 0], -(v - k_crop[1, 2]) / k_crop[1, 1], -np.ones(4)], 1)
        vertices, faces = rays * distance, np.array([[2, 3, 1], [2, 1, 0]])
        uvs = np.stack([u / tw, v / th], axis=1)
    normals, tangents = vertex_frames(vertices, faces, uvs)
    normal_png = encode_png(_bake_normals(maps["normal"], normals, tangents, None if "depth" not in maps else pixels))
    mesh = GlbMesh(vertices, normals, tangents, uvs, faces)
    material = GlbMaterial(_base_color(maps["albedo"], inside), _metallic_roughness(maps), normal_png)
    extras = {"generator": "pbrdf.data.gltf_asset", "mesh": "relief" if "depth" in maps else "card",
              "texture_box_rows_cols": [y0, x0, y1, x1], "capture_size": [mask.shape[1], mask.shape[0]]}  # fmt: skip
    return GltfAsset(mesh, material, capture_camera(k, mask.shape), (y0, x0, y1, x1), extras)


def _bake_normals(normal: NDArray, normals: NDArray, tangents: NDArray, pixels: NDArray | None) -> NDArray:
    """``(h, w, 3)`` uint8 tangent-space normal map of camera-space ``normal (h, w, 3)`` in the vertex frames.

    ``pixels`` ``(N, 2)``: each vertex's texel (relief); None: one frame for every texel (card).
    Texels without a vertex (outside the relief, cut by alpha) hold the flat ``(0, 0, 1)``.
    """
    bitangents = np.cross(normals, tangents[:, :3]) * tangents[:, 3:]
    frame = np.stack([tangents[:, :3], bitangents, normals], axis=1)  # (N, 3, 3): rows T, B, N
    if pixels is None:
        n_ts = normal @ frame[0].T
    else:
        n_ts = np.zeros(normal.shape)
        n_ts[..., 2] = 1.0
        rows, cols = pixels[:, 0], pixels[:, 1]
        n_ts[rows, cols] = np.einsum("nij,nj->ni", frame, normal[rows, cols])
    n_ts /= np.maximum(np.linalg.norm(n_ts, axis=-1, keepdims=True), 1e-12)
    return np.rint((0.5 + 0.5 * n_ts) * 255).astype(np.uint8)


def _base_color(albedo: NDArray, inside: NDArray) -> bytes:
    rgb = np.rint(linear_to_srgb(albedo) * 255)
    return encode_png(np.concatenate([rgb, inside[..., None] * 255.0], axis=-1).astype(np.uint8))


def _metallic_roughness(maps: Mapping[str, NDArray]) -> bytes:
    g = np.rint(np.clip(maps["roughness"][..., 0], 0, 1) * 255)
    b = np.rint(np.clip(maps["metallic"][..., 0], 0, 1) * 255)
    return encode_png(np.stack([np.full_like(g, 255), g, b], axis=-1).astype(np.uint8))


def capture_camera(intrinsics: ArrayLike, shape: tuple[int, int]) -> GlbCamera:
    """The glTF camera of a capture of ``shape (H, W)`` with pinhole ``K``: the symmetric frustum holding its image.

    Example: a 64 x 48 capture with the principal point 4 px right of the centre gets a 72 px wide
    viewport; capture pixel ``(u, v)`` is viewport pixel ``(u, v)`` there:

        >>> cam = capture_camera([[80.0, 0, 36], [0, 80.0, 24], [0, 0, 1]], (48, 64))
        >>> round(math.degrees(cam.yfov), 3), cam.aspect_ratio
        (33.398, 1.5)
        >>> cam.extras["viewport_px"], cam.extras["capture_offset_px"]
        ([72.0, 48.0], [0.0, 0.0])
    """
    k = np.asarray(intrinsics, dtype=np.float64)
    h, w = shape
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    hx, hy = max(cx, w - cx), max(cy, h - cy)
    extras = {
        "intrinsics": k.tolist(), "capture_size": [int(w), int(h)], "viewport_px": [float(2 * hx), float(2 * hy)],
        "capture_offset_px": [float(hx - cx), float(hy - cy)],
        "note": "capture pixel (u, v) is viewport pixel (u, v) + capture_offset_px at viewport_px and fx, fy",
    }  # fmt: skip
    return GlbCamera(2 * math.atan(hy / fy), float((hx / fx) / (hy / fy)), ZNEAR, ZFAR, "capture camera", extras)


def write_asset(path: str | os.PathLike, asset: GltfAsset, *, name: str = "reconstruction") -> Path:
    """Write a built asset to ``path`` (.glb) atomically; ``name`` names its mesh, node and scene.

    Raises:
        OSError: one line naming ``path`` and why it cannot be written (same type; nothing left behind).
    """
    try:
        return write_glb(path, asset.mesh, asset.material, asset.camera, name=name, extras=asset.extras)
    except OSError as exc:
        blocked = next((p for p in Path(path).parents if p.exists()), None)  # mkdir's "File exists" says little
        reason = f"{blocked} is a file, not a folder" if blocked and not blocked.is_dir() else exc.strerror or exc
        raise type(exc)(f"{path}: cannot write the glTF file: {reason}") from exc


def write_gltf_asset(
    path: str | os.PathLike, pred: Mapping[str, NDArray], intrinsics: ArrayLike, *,
    distance: float = DEFAULT_DISTANCE_M, name: str = "reconstruction",
) -> Path:  # fmt: skip
    """Build (:func:`build_asset`) and write (:func:`write_asset`) ``path`` (.glb) atomically; returns the path.

    Raises:
        ValueError: bad maps (one line; nothing written).
        OSError: the file cannot be written (nothing left behind).
    """
    return write_asset(path, build_asset(pred, intrinsics, distance=distance), name=name)
