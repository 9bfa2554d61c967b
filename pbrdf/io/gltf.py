"""A glTF 2.0 binary (.glb) of one textured mesh and one camera: json, struct, numpy (and Pillow for PNGs).

Written from the glTF 2.0 specification (Khronos, 2021, sections 4.4 "Binary glTF Layout" and
3.6-3.9), for the reconstruction asset (:mod:`pbrdf.data.gltf_asset`) that any engine opens:
one mesh primitive with POSITION, NORMAL, TANGENT, TEXCOORD_0 and uint32 indices, one
metallic-roughness material with a base-colour, a metallic-roughness and a normal texture
(PNGs embedded in the binary chunk; linear filtering, clamp-to-edge), ``alphaMode`` MASK,
single-sided, and an optional perspective camera. Both nodes sit at the scene's origin with no
transform, so the mesh's coordinates are the camera's frame.

Layout: a 12-byte header (magic ``glTF``, version 2, total length), the JSON chunk (padded with
spaces to 4 bytes), then the BIN chunk (padded with zeros). Every buffer view starts on a 4-byte
boundary; vertex attributes are tightly packed float32 (no ``byteStride``), one view each.
Accessors carry ``min``/``max`` (required for POSITION, given for all). The file is written
atomically (:func:`pbrdf.io.atomic.atomic_write_bytes`).

Convention (glTF): right-handed, +y up, a camera looks down its local -z; UV ``(0, 0)`` is the
top-left corner of an image; a normal texture holds ``0.5 + 0.5 n`` of a tangent-space normal
``n`` with bitangent ``B = cross(N, T.xyz) * T.w``; base colour is sRGB, the rest linear;
metallic-roughness reads roughness from G and metallic from B.

Example: a single-triangle file starts with the magic and version 2:

    >>> import struct
    >>> tri = GlbMesh(np.eye(3), np.tile([0.0, 0.0, 1.0], (3, 1)), np.tile([1.0, 0.0, 0.0, 1.0], (3, 1)),
    ...               np.zeros((3, 2)), np.array([[0, 1, 2]]))
    >>> png = encode_png(np.zeros((1, 1, 3), np.uint8))
    >>> data = glb_bytes(tri, GlbMaterial(png, png, png))
    >>> struct.unpack_from("<4sII", data)[:2], len(data) % 4
    ((b'glTF', 2), 0)
"""

from __future__ import annotations

import io
import json
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.io.atomic import atomic_write_bytes

__all__ = ["GlbMesh", "GlbMaterial", "GlbCamera", "encode_png", "glb_document", "glb_bytes", "write_glb"]

_MAGIC, _VERSION = 0x46546C67, 2  # "glTF" little-endian
_JSON_CHUNK, _BIN_CHUNK = 0x4E4F534A, 0x004E4942  # "JSON", "BIN\0"
_FLOAT, _UINT32 = 5126, 5125  # accessor componentType
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963  # bufferView target
_LINEAR, _CLAMP_TO_EDGE = 9729, 33071  # sampler filter and wrap
_UNIT_TOL = 1e-3  # |‖n‖ - 1| allowed for NORMAL and TANGENT.xyz (the validator warns past a few 1e-4)


@dataclass(frozen=True)
class GlbMesh:
    """One indexed triangle mesh (converted to float32 / uint32 when written).

    Attributes:
        positions: ``(N, 3)`` vertex positions in m.
        normals: ``(N, 3)`` unit vertex normals.
        tangents: ``(N, 4)`` unit tangent xyz along increasing u and handedness ``w = +-1``.
        uvs: ``(N, 2)`` TEXCOORD_0, glTF convention (``(0, 0)`` the image's top-left corner).
        indices: ``(F, 3)`` vertex indices, counter-clockwise seen from the front.
    """

    positions: ArrayLike
    normals: ArrayLike
    tangents: ArrayLike
    uvs: ArrayLike
    indices: ArrayLike


@dataclass(frozen=True)
class GlbMaterial:
    """The textures (PNG bytes) of a metallic-roughness material with alpha MASK.

    Attributes:
        base_color_png: sRGB RGB(A) base colour; alpha is coverage, cut at ``alpha_cutoff``.
        metallic_roughness_png: linear; roughness in G, metallic in B.
        normal_png: linear ``0.5 + 0.5 n`` tangent-space normals.
        alpha_cutoff: the MASK threshold.
        name: the material's name.
    """

    base_color_png: bytes
    metallic_roughness_png: bytes
    normal_png: bytes
    alpha_cutoff: float = 0.5
    name: str = "material"


@dataclass(frozen=True)
class GlbCamera:
    """A perspective camera (looking down its node's -z, +y up).

    Attributes:
        yfov: vertical field of view in radians, in (0, pi).
        aspect_ratio: viewport width / height.
        znear: near plane distance in m.
        zfar: far plane in m, or None (an infinite projection).
        name: the camera's (and its node's) name.
        extras: JSON-ready application data stored as the camera's ``extras``.
    """

    yfov: float
    aspect_ratio: float
    znear: float
    zfar: float | None = None
    name: str = "camera"
    extras: dict[str, Any] = field(default_factory=dict)


def encode_png(image: NDArray, *, compress_level: int = 1) -> bytes:
    """PNG bytes of an 8-bit ``(H, W, C)`` image (C = 1, 3 or 4), row 0 at the top.

    ``compress_level`` 1 (fast deflate): the maps are noisy, level 6 saves a few percent at several
    times the time.
    """
    from PIL import Image  # noqa: PLC0415

    a = np.asarray(image)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[-1] not in (1, 3, 4):
        raise ValueError(f"image: expected uint8 (H, W, 1|3|4), got {a.dtype} {a.shape}")
    buf = io.BytesIO()
    Image.fromarray(a[..., 0] if a.shape[-1] == 1 else a).save(buf, format="PNG", compress_level=compress_level)
    return buf.getvalue()


def _checked_mesh(mesh: GlbMesh) -> dict[str, NDArray]:
    """The mesh's arrays as float32 / uint32; ValueError naming the first bad field."""
    arrays = {}
    for name, cols in (("positions", 3), ("normals", 3), ("tangents", 4), ("uvs", 2)):
        a = np.asarray(getattr(mesh, name), dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != cols or not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: expected a finite (N, {cols}) array, got shape {a.shape}")
        arrays[name] = a
    n = len(arrays["positions"])
    if n == 0 or any(len(a) != n for a in arrays.values()):
        raise ValueError(f"positions, normals, tangents, uvs: need the same non-zero length, got {n} positions")
    for name, vec in (("normals", arrays["normals"]), ("tangents", arrays["tangents"][:, :3])):
        if np.abs(np.linalg.norm(vec, axis=1) - 1.0).max() > _UNIT_TOL:
            raise ValueError(f"{name}: xyz must be unit length")
    if not np.all(np.abs(arrays["tangents"][:, 3]) == 1.0):
        raise ValueError("tangents: w (handedness) must be +1 or -1")
    idx = np.asarray(mesh.indices)
    if idx.ndim != 2 or idx.shape[1] != 3 or len(idx) == 0 or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"indices: expected a non-empty integer (F, 3) array, got {idx.dtype} {idx.shape}")
    if idx.min() < 0 or idx.max() >= n:
        raise ValueError(f"indices: must lie in [0, {n}), got {idx.min()}..{idx.max()}")
    out = {k: v.astype(np.float32) for k, v in arrays.items()}
    out["indices"] = idx.astype(np.uint32).ravel()
    return out


class _Bin:
    """The BIN chunk under construction: buffer views appended on 4-byte boundaries."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.length = 0
        self.views: list[dict[str, Any]] = []

    def view(self, data: bytes, target: int | None = None) -> int:
        pad = (-self.length) % 4
        if pad:
            self.parts.append(b"\0" * pad)
            self.length += pad
        entry = {"buffer": 0, "byteOffset": self.length, "byteLength": len(data)}
        if target is not None:
            entry["target"] = target
        self.parts.append(data)
        self.length += len(data)
        self.views.append(entry)
        return len(self.views) - 1

    def data(self) -> bytes:
        return b"".join(self.parts) + b"\0" * ((-self.length) % 4)


def _accessor(bin_: _Bin, array: NDArray, kind: str, target: int) -> dict[str, Any]:
    """An accessor over a new buffer view of ``array`` (float32 rows or flat uint32), with min/max."""
    flat = array.ndim == 1
    return {
        "bufferView": bin_.view(np.ascontiguousarray(array).tobytes(), target),
        "componentType": _UINT32 if array.dtype == np.uint32 else _FLOAT,
        "count": int(len(array)),
        "type": kind,
        "min": [int(array.min())] if flat else array.min(axis=0).astype(float).tolist(),
        "max": [int(array.max())] if flat else array.max(axis=0).astype(float).tolist(),
    }


def glb_document(
    mesh: GlbMesh, material: GlbMaterial, camera: GlbCamera | None = None, *, name: str = "asset",
    extras: dict[str, Any] | None = None,
) -> tuple[dict[str, Any], bytes]:  # fmt: skip
    """The glTF JSON and the BIN chunk's bytes of one mesh (node 0) and its camera (node 1).

    Args:
        mesh: the triangles (checked: shapes, finite, unit normals and tangents, indices in range).
        material: its textures.
        camera: the capture camera, or None.
        name: the mesh's and its node's name.
        extras: JSON-ready data stored as the asset's ``extras``.

    Raises:
        ValueError: one line naming the bad field.
    """
    arrays = _checked_mesh(mesh)
    bin_ = _Bin()
    attributes, accessors = {}, []
    for key, arr, kind in (("POSITION", "positions", "VEC3"), ("NORMAL", "normals", "VEC3"),
                           ("TANGENT", "tangents", "VEC4"), ("TEXCOORD_0", "uvs", "VEC2")):  # fmt: skip
        attributes[key] = len(accessors)
        accessors.append(_accessor(bin_, arrays[arr], kind, _ARRAY_BUFFER))
    accessors.append(_accessor(bin_, arrays["indices"], "SCALAR", _ELEMENT_ARRAY_BUFFER))
    pngs = (("base colour", material.base_color_png), ("metallic roughness", material.metallic_roughness_png),
            ("normal", material.normal_png))  # fmt: skip
    images = [{"name": label, "mimeType": "image/png", "bufferView": bin_.view(png)} for label, png in pngs]
    nodes: list[dict[str, Any]] = [{"name": name, "mesh": 0}]
    doc: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "pdir pbrdf.io.gltf"},
        "scene": 0,
        "scenes": [{"name": name, "nodes": [0]}],
        "nodes": nodes,
        "meshes": [{"name": name, "primitives": [
            {"attributes": attributes, "indices": len(accessors) - 1, "material": 0, "mode": 4}]}],
        "materials": [{
            "name": material.name,
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicRoughnessTexture": {"index": 1},
                                     "metallicFactor": 1.0, "roughnessFactor": 1.0},
            "normalTexture": {"index": 2, "scale": 1.0},
            "alphaMode": "MASK", "alphaCutoff": float(material.alpha_cutoff), "doubleSided": False,
        }],
        "textures": [{"sampler": 0, "source": i} for i in range(3)],
        "samplers": [{"magFilter": _LINEAR, "minFilter": _LINEAR, "wrapS": _CLAMP_TO_EDGE, "wrapT": _CLAMP_TO_EDGE}],
        "images": images,
        "accessors": accessors,
        "bufferViews": bin_.views,
        "buffers": [{"byteLength": 0}],
    }  # fmt: skip
    if camera is not None:
        doc["cameras"] = [_camera_json(camera)]
        nodes.append({"name": camera.name, "camera": 0})
        doc["scenes"][0]["nodes"].append(1)
    if extras:
        doc["asset"]["extras"] = extras
    data = bin_.data()
    doc["buffers"][0]["byteLength"] = len(data)
    return doc, data


def _camera_json(camera: GlbCamera) -> dict[str, Any]:
    if not (0 < camera.yfov < np.pi and camera.aspect_ratio > 0 and camera.znear > 0):
        raise ValueError(
            f"camera: need 0 < yfov < pi, aspect_ratio > 0, znear > 0; got {camera.yfov}, "
            f"{camera.aspect_ratio}, {camera.znear}"
        )
    if camera.zfar is not None and not camera.zfar > camera.znear:
        raise ValueError(f"camera: zfar {camera.zfar} must exceed znear {camera.znear}")
    persp = {"yfov": float(camera.yfov), "aspectRatio": float(camera.aspect_ratio), "znear": float(camera.znear)}
    if camera.zfar is not None:
        persp["zfar"] = float(camera.zfar)
    out = {"name": camera.name, "type": "perspective", "perspective": persp}
    if camera.extras:
        out["extras"] = camera.extras
    return out


def glb_bytes(mesh: GlbMesh, material: GlbMaterial, camera: GlbCamera | None = None, **kwargs: Any) -> bytes:
    """The .glb file of :func:`glb_document`'s JSON and binary chunk (``kwargs``: its ``name``, ``extras``)."""
    doc, data = glb_document(mesh, material, camera, **kwargs)
    text = json.dumps(doc, separators=(",", ":"), allow_nan=False).encode("utf-8")
    text += b" " * ((-len(text)) % 4)
    total = 12 + 8 + len(text) + 8 + len(data)
    return b"".join([
        struct.pack("<III", _MAGIC, _VERSION, total),
        struct.pack("<II", len(text), _JSON_CHUNK), text,
        struct.pack("<II", len(data), _BIN_CHUNK), data,
    ])  # fmt: skip


def write_glb(path: str | os.PathLike, mesh: GlbMesh, material: GlbMaterial, camera: GlbCamera | None = None,
              **kwargs: Any) -> Path:  # fmt: skip
    """Write :func:`glb_bytes` to ``path`` atomically (everything is checked and encoded first); returns the path."""
    return atomic_write_bytes(Path(path), glb_bytes(mesh, material, camera, **kwargs))
