"""An independent .glb reader, a validator-like check and a test prediction for the glTF tests (numpy, Pillow).

Written from the glTF 2.0 specification, not from :mod:`pbrdf.io.gltf`: the container layout
(header, JSON chunk, BIN chunk), accessors read through their buffer views, and the rules a
validator checks for the files we write (required fields, counts, lengths, 4-byte alignment,
min/max that match the data, unit normals and tangents, indices in range).
"""

from __future__ import annotations

import io
import json
import struct

import numpy as np
from PIL import Image

from pbrdf.sensor.projection import pixel_rays

_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_DTYPES = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}


def read_glb(data: bytes) -> tuple[dict, bytes]:
    """``(json document, BIN chunk bytes)`` of a .glb, checking the container's layout."""
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_len % 4 == 0
    doc = json.loads(data[20 : 20 + json_len])
    off = 20 + json_len
    bin_len, bin_type = struct.unpack_from("<II", data, off)
    assert bin_type == 0x004E4942 and bin_len % 4 == 0 and off + 8 + bin_len == len(data)
    return doc, data[off + 8 : off + 8 + bin_len]


def accessor(doc: dict, blob: bytes, index: int) -> np.ndarray:
    """The data of accessor ``index``: ``(count, components)`` (or ``(count,)`` for SCALAR)."""
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    n = _COMPONENTS[acc["type"]]
    dtype = np.dtype(_DTYPES[acc["componentType"]])
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    assert view.get("byteStride", n * dtype.itemsize) == n * dtype.itemsize  # tightly packed (we write no stride)
    out = np.frombuffer(blob, dtype, acc["count"] * n, start).reshape(-1, n)
    return out[:, 0] if acc["type"] == "SCALAR" else out


def image(doc: dict, blob: bytes, texture_index: int) -> np.ndarray:
    """The decoded ``(H, W, C)`` uint8 PNG of texture ``texture_index``."""
    img = doc["images"][doc["textures"][texture_index]["source"]]
    view = doc["bufferViews"][img["bufferView"]]
    png = blob[view.get("byteOffset", 0) : view.get("byteOffset", 0) + view["byteLength"]]
    assert img["mimeType"] == "image/png" and png[:8] == b"\x89PNG\r\n\x1a\n"
    a = np.asarray(Image.open(io.BytesIO(png)))
    return a[..., None] if a.ndim == 2 else a


def validate(doc: dict, blob: bytes) -> list[str]:
    """What a validator would report for the files we write (an empty list: none)."""
    issues = []
    for key in ("asset", "scenes", "nodes", "meshes", "accessors", "bufferViews", "buffers", "materials"):
        if key not in doc:
            issues.append(f"{key}: missing")
    if doc.get("asset", {}).get("version") != "2.0":
        issues.append("asset.version: not 2.0")
    if len(doc["buffers"]) != 1 or "uri" in doc["buffers"][0] or doc["buffers"][0]["byteLength"] > len(blob):
        issues.append("buffers: a GLB has one buffer without uri, within the BIN chunk")
    for i, view in enumerate(doc["bufferViews"]):
        off = view.get("byteOffset", 0)
        if off % 4 or off + view["byteLength"] > doc["buffers"][0]["byteLength"]:
            issues.append(f"bufferViews[{i}]: offset {off} not 4-aligned or past the buffer")
    for i, acc in enumerate(doc["accessors"]):
        view = doc["bufferViews"][acc["bufferView"]]
        size = _COMPONENTS[acc["type"]] * np.dtype(_DTYPES[acc["componentType"]]).itemsize
        if acc["count"] * size > view["byteLength"] - acc.get("byteOffset", 0):
            issues.append(f"accessors[{i}]: count {acc['count']} does not fit its bufferView")
        data = accessor(doc, blob, i).reshape(acc["count"], -1)
        for bound, fn in (("min", np.min), ("max", np.max)):
            if bound not in acc or not np.array_equal(np.asarray(acc[bound], data.dtype), fn(data, axis=0)):
                issues.append(f"accessors[{i}].{bound}: missing or not the data's")
    n_images = len(doc.get("images", []))
    for prim in (p for m in doc["meshes"] for p in m["primitives"]):
        att = prim["attributes"]
        counts = {k: doc["accessors"][v]["count"] for k, v in att.items()}
        if "POSITION" not in att or len(set(counts.values())) != 1:
            issues.append(f"primitive attributes: POSITION missing or counts differ: {counts}")
        if doc["accessors"][prim["indices"]]["count"] % 3:
            issues.append("indices: count not a multiple of 3")
        idx = accessor(doc, blob, prim["indices"])
        if idx.max() >= counts["POSITION"]:
            issues.append("indices: out of range")
        for key, width in (("NORMAL", 3), ("TANGENT", 3)):
            if key in att:
                vec = accessor(doc, blob, att[key])
                if np.abs(np.linalg.norm(vec[:, :width], axis=1) - 1).max() > 5e-4:
                    issues.append(f"{key}: not unit length")
        if "TANGENT" in att and not np.all(np.abs(accessor(doc, blob, att["TANGENT"])[:, 3]) == 1):
            issues.append("TANGENT.w: not +-1")
    for tex in doc.get("textures", []):
        if not 0 <= tex["source"] < n_images or not 0 <= tex.get("sampler", 0) < len(doc.get("samplers", [{}])):
            issues.append("textures: source or sampler out of range")
    for cam in doc.get("cameras", []):
        p = cam.get("perspective", {})
        if cam.get("type") != "perspective" or not (0 < p.get("yfov", 0) < np.pi and p.get("znear", 0) > 0):
            issues.append("cameras: not a valid perspective camera")
    return issues


def attributes(doc: dict, blob: bytes) -> tuple[dict, np.ndarray]:
    """``({attribute: (N, C) float64}, faces (F, 3))`` of the first mesh primitive."""
    att = doc["meshes"][0]["primitives"][0]["attributes"]
    idx = accessor(doc, blob, doc["meshes"][0]["primitives"][0]["indices"]).reshape(-1, 3)
    return {k: accessor(doc, blob, v).astype(np.float64) for k, v in att.items()}, idx


def texel_interpolation(uv: np.ndarray, faces: np.ndarray, attrs: dict, th: int, tw: int) -> tuple[np.ndarray, dict]:
    """Per texel centre of a ``th x tw`` texture: the vertex attributes interpolated over the triangle covering it.

    Barycentric in UV space (glTF: texel ``(i, j)``'s centre is ``((j + 0.5) / tw, (i + 0.5) / th)``).

    Returns:
        ``(covered (th, tw) bool, {name: (th, tw, C)})``.
    """
    tx = uv[faces] * [tw, th] - 0.5  # triangle corners in texel-index units (texel centres at integers)
    lo = np.ceil(tx.min(1) - 1e-4).astype(int)
    span = (np.floor(tx.max(1) + 1e-4).astype(int) - lo + 1).max(0)
    oy, ox = np.mgrid[0 : span[1], 0 : span[0]]
    cand = lo[:, None, :] + np.stack([ox.ravel(), oy.ravel()], -1)[None]  # (F, S, 2) texel (col, row)
    a, b, c = (tx[:, i][:, None, :] for i in range(3))
    v0, v1, q = b - a, c - a, cand - a
    den = v0[..., 0] * v1[..., 1] - v0[..., 1] * v1[..., 0]
    l1 = (q[..., 0] * v1[..., 1] - q[..., 1] * v1[..., 0]) / den
    l2 = (v0[..., 0] * q[..., 1] - v0[..., 1] * q[..., 0]) / den
    bary = np.stack([1 - l1 - l2, l1, l2], -1)
    inside = (bary >= -1e-4).all(-1) & (cand >= 0).all(-1) & (cand[..., 0] < tw) & (cand[..., 1] < th)
    f_idx, s_idx = np.nonzero(inside)
    col, row = cand[f_idx, s_idx, 0], cand[f_idx, s_idx, 1]
    covered = np.zeros((th, tw), bool)
    covered[row, col] = True
    out = {}
    for name, values in attrs.items():
        interp = np.einsum("kc,kcd->kd", bary[f_idx, s_idx], values[faces[f_idx]])
        grid = np.zeros((th, tw, values.shape[1]))
        grid[row, col] = interp
        out[name] = grid
    return covered, out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def shading_normals(doc: dict, blob: bytes) -> tuple[np.ndarray, np.ndarray]:
    """``(covered (th, tw) bool, n (th, tw, 3))``: the shading normal a viewer rebuilds at each normal-map texel centre.

    ``n = T x + B y + N z`` with ``(x, y, z)`` the decoded texel and T, N the exported vertex
    attributes interpolated over the triangle covering the texel centre, each normalised (as
    viewers do), ``B = cross(N, T) w`` (glTF 2.0, 3.7.2.1).
    """
    attrs, faces = attributes(doc, blob)
    ts = image(doc, blob, doc["materials"][0]["normalTexture"]["index"]) / 255.0 * 2 - 1
    covered, f = texel_interpolation(attrs["TEXCOORD_0"], faces, attrs, *ts.shape[:2])
    normal, tangent = _unit(f["NORMAL"]), _unit(f["TANGENT"][..., :3])
    bitangent = np.cross(normal, tangent) * np.sign(f["TANGENT"][..., 3:])
    return covered, _unit(tangent * ts[..., :1] + bitangent * ts[..., 1:2] + normal * ts[..., 2:])


def sphere_prediction(rng, k, h, w, *, bumps=True, centre=(0.03, -0.02, -0.9), radius=0.22) -> dict:
    """Predicted maps of a real sphere seen through ``k`` (``h x w``); ``bumps``: normals with detail the mesh lacks."""
    r = pixel_rays(k, h, w)
    d = r / np.linalg.norm(r, axis=-1, keepdims=True)
    c = np.asarray(centre)
    b = d @ c
    disc = b * b - (c @ c - radius**2)
    mask = disc > 0
    p = d * (b - np.sqrt(np.maximum(disc, 0)))[..., None]
    n = (p - c) / radius
    if bumps:  # tilt by up to ~17 degrees in a ripple pattern
        yy, xx = np.mgrid[0:h, 0:w]
        n = n + 0.3 * np.stack([np.sin(xx / 2.0), np.cos(yy / 3.0), np.zeros_like(xx, float)], -1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
    m = mask[..., None]
    return {
        "normal": np.where(m, n, 0).astype(np.float32),
        "albedo": np.where(m, rng.uniform(0, 1, (h, w, 3)), 0).astype(np.float32),
        "roughness": np.where(m, rng.uniform(0, 1, (h, w, 1)), 0).astype(np.float32),
        "metallic": np.where(m, rng.uniform(0, 1, (h, w, 1)), 0).astype(np.float32),
        "mask": m.astype(np.float32),
        "depth": np.where(m, -p[..., 2:], 0).astype(np.float32),
    }


def normal_map_error(doc: dict, blob: bytes, normal: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """How well the .glb's shading normals reproduce ``normal (H, W, 3)`` on ``mask (H, W)`` (capture grid).

    Returns:
        ``(covered, p99)``: the fraction of the mask's texels that a triangle covers, and the 99th
        percentile of the angle (deg) between the exported and the given normals there.
    """
    y0, x0, y1, x1 = doc["asset"]["extras"]["texture_box_rows_cols"]
    inside = np.asarray(mask, bool)[y0:y1, x0:x1]
    covered, n = shading_normals(doc, blob)
    on = inside & covered
    err = np.degrees(np.arccos(np.clip((n[on] * np.asarray(normal)[y0:y1, x0:x1][on]).sum(-1), -1, 1)))
    return float(on.sum() / max(inside.sum(), 1)), float(np.percentile(err, 99))
