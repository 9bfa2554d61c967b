"""Asset files below the mesh pipeline: glTF containers, the per-material tagged scene, MTL statements.

:func:`read_gltf` parses a ``.gltf`` (JSON) or ``.glb`` (binary container) into the document and
the GLB's binary chunk; :func:`buffer_view` and :func:`image_bytes` resolve what the document
refers to (the binary chunk, ``data:`` URIs, files beside the document); :func:`glb_bytes`
writes a GLB back. :func:`tagged_scene` loads a glTF or OBJ file with trimesh so that every
geometry holds one material's triangles with their UVs (:func:`.assets.load_part`);
:func:`clean_uvs` checks those UVs. :func:`mtl_libs`, :func:`mtl_statements` and :func:`mtl_names`
read the MTL files an OBJ names.

Convention (UVs): OpenGL's, ``v`` up (:mod:`.textures`); trimesh's glTF reader turns glTF's ``v``
down into that (``v = 1 - v_gltf``).

Every failure is one ``ValueError`` line that starts with the file's name.
"""

from __future__ import annotations

import base64
import copy
import io
import json
import os
import struct
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import numpy as np

try:
    import trimesh
except ModuleNotFoundError:  # Blender's Python: only the mesh loaders need trimesh
    trimesh = None

__all__ = [
    "PART_TAG",
    "UV_LIMIT",
    "buffer_view",
    "clean_uvs",
    "glb_bytes",
    "image_bytes",
    "item",
    "mtl_libs",
    "mtl_names",
    "mtl_statements",
    "read_gltf",
    "tagged_document",
    "tagged_scene",
    "texcoord_of",
    "texcoord_sets",
    "texture_infos",
]

#: Key of a tagged mesh's ``extras`` (trimesh copies it into the geometry's metadata): ``[material, mesh, primitive]``.
PART_TAG = "pbrdf_part"
#: Largest UV magnitude :func:`clean_uvs` keeps as it is (float32 still resolves 1e-4 of a texture repeat there).
UV_LIMIT = 1024.0
_GLB_MAGIC, _JSON, _BIN = b"glTF", 0x4E4F534A, 0x004E4942
_FLOAT = 5126  # glTF componentType FLOAT


def read_gltf(path: str | os.PathLike, name: str | None = None) -> tuple[dict, bytes | None]:
    """The JSON document of a glTF 2.0 file and, for a GLB, its binary chunk.

    Args:
        path: a ``.gltf`` or ``.glb`` file.
        name: the file's name in errors (default: the path).

    Returns:
        ``(document, binary chunk or None)``.

    Raises:
        ValueError: ``"<name>: cannot read mesh: <reason>"`` (bad magic, container version, JSON).
    """
    path = Path(path)
    name = str(path) if name is None else name
    raw = path.read_bytes()
    try:
        binary = None
        if path.suffix.lower() == ".glb":
            if raw[:4] != _GLB_MAGIC or len(raw) < 20:
                raise ValueError("not a GLB file (bad magic)")
            container = struct.unpack_from("<I", raw, 4)[0]
            if container != 2:
                raise ValueError(f"unsupported GLB container version {container} (glTF 2.0 only; re-export it)")
            length, kind = struct.unpack_from("<II", raw, 12)
            if kind != _JSON:
                raise ValueError("GLB without a JSON chunk")
            doc = json.loads(raw[20 : 20 + length].decode("utf-8"))
            at = 20 + length + (-length % 4)
            if at + 8 <= len(raw):
                blen, bkind = struct.unpack_from("<II", raw, at)
                binary = raw[at + 8 : at + 8 + blen] if bkind == _BIN else None
        else:
            doc = json.loads(raw.decode("utf-8-sig"))
    except (ValueError, UnicodeDecodeError, struct.error) as e:
        raise ValueError(f"{name}: cannot read mesh: {e}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{name}: cannot read mesh: the glTF JSON is not an object")
    return doc, binary


def glb_bytes(doc: dict, binary: bytes | None) -> bytes:
    """A GLB container holding ``doc`` and the binary chunk (padded to 4 bytes as the format asks).

    >>> import tempfile
    >>> doc = {"asset": {"version": "2.0"}}
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = Path(folder) / "a.glb"
    ...     _ = path.write_bytes(glb_bytes(doc, b"xyz"))
    ...     read_gltf(path) == (doc, b"xyz\\x00")  # the binary chunk padded to 4 bytes
    True
    """
    js = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    js += b" " * (-len(js) % 4)
    chunks = struct.pack("<II", len(js), _JSON) + js
    if binary is not None:
        binary = binary + b"\0" * (-len(binary) % 4)
        chunks += struct.pack("<II", len(binary), _BIN) + binary
    return _GLB_MAGIC + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def _uri_bytes(uri: str, base: Path, name: str, what: str) -> bytes:
    if uri.startswith("data:"):
        try:
            head, _, data = uri.partition(",")
            return base64.b64decode(data, validate=True) if head.endswith(";base64") else unquote(data).encode()
        except ValueError as e:
            raise ValueError(f"{name}: {what}: bad data URI: {e}") from None
    file = base / unquote(uri)
    try:
        return file.read_bytes()
    except FileNotFoundError:
        raise ValueError(f"{name}: {what}: file not found: {file}") from None
    except OSError as e:
        raise ValueError(f"{name}: {what}: cannot read {file}: {e.strerror or e}") from None


def item(doc: dict, key: str, index: Any, name: str, what: str = "") -> dict:
    """Entry ``index`` of the document's list ``key`` (``"textures"``, ``"images"``, ...), checked.

    Raises:
        ValueError: ``"<name>: [<what>: ]<texture> index 5 out of range (the file has 1)"``, or not an object.
    """
    items = doc.get(key) or []
    where = f"{what}: " if what else ""
    if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(items):
        raise ValueError(f"{name}: {where}{key[:-1]} index {index!r} out of range (the file has {len(items)})")
    entry = items[index]
    if not isinstance(entry, dict):
        raise ValueError(f"{name}: {where}{key[:-1]} {index} is not a JSON object")
    return entry


def buffer_view(doc: dict, binary: bytes | None, index: int, base: Path, name: str) -> bytes:
    """The bytes of buffer view ``index`` (the GLB chunk, a ``data:`` URI or a file in ``base``)."""
    what = f"bufferView {index}"
    view = item(doc, "bufferViews", index, name, what)
    buf = item(doc, "buffers", view.get("buffer"), name, what)
    data = _uri_bytes(buf["uri"], base, name, what) if "uri" in buf else binary
    if data is None:
        raise ValueError(f"{name}: {what}: buffer {view.get('buffer')} has no data (no GLB binary chunk)")
    start, length = int(view.get("byteOffset", 0)), int(view.get("byteLength", -1))
    if start < 0 or length < 0 or start + length > len(data):
        raise ValueError(f"{name}: {what}: bytes {start}..{start + length} outside its buffer of {len(data)}")
    return data[start : start + length]


def image_bytes(doc: dict, binary: bytes | None, index: int, base: Path, name: str) -> tuple[bytes, Path | None]:
    """The encoded bytes of image ``index`` and the file they come from (None when embedded).

    Raises:
        ValueError: an index out of range, a missing or unreadable file, a bad buffer view.
    """
    what = f"image {index}"
    img = item(doc, "images", index, name)
    if "bufferView" in img:
        return buffer_view(doc, binary, img["bufferView"], base, name), None
    uri = img.get("uri")
    if not isinstance(uri, str) or not uri:
        raise ValueError(f"{name}: {what}: neither a uri nor a bufferView")
    return _uri_bytes(uri, base, name, f"{what} ({uri[:40]})"), None if uri.startswith("data:") else base / unquote(uri)


def tagged_document(doc: dict, texcoord: dict[int, int] | None = None) -> dict:
    """A copy of ``doc`` that trimesh loads with every primitive's material and UVs.

    Every primitive becomes a mesh of its own (a node holding a mesh of several primitives gets a
    child node per primitive) whose ``extras`` hold :data:`PART_TAG` ``[material, mesh, primitive]``
    (material -1: none); materials are replaced by empty ones (trimesh keeps ``TEXCOORD_0`` only for
    a primitive with a material) and images dropped (nothing is decoded).

    Args:
        doc: the glTF document (left unchanged).
        texcoord: per material, the ``TEXCOORD_<n>`` set its textures use; that set is given to
            trimesh as ``TEXCOORD_0``.
    """
    texcoord = texcoord or {}
    out = {k: copy.deepcopy(v) for k, v in doc.items() if k not in ("images", "textures", "samplers", "materials")}
    n_mat = len(doc.get("materials") or [])
    out["materials"] = [{} for _ in range(n_mat + 1)]  # the last: primitives without a material
    meshes: list[dict] = []
    per_mesh: list[list[int]] = []
    for i, mesh in enumerate(doc.get("meshes") or []):
        ids = []
        for j, prim in enumerate(mesh.get("primitives") or []):
            p = copy.deepcopy(prim)
            mat = p.get("material")
            key = mat if isinstance(mat, int) and 0 <= mat < n_mat else -1
            attrs = p.get("attributes") or {}
            uv = attrs.get(f"TEXCOORD_{texcoord.get(key, 0)}")
            if uv is not None:
                attrs["TEXCOORD_0"] = uv
            p["material"] = key if key >= 0 else n_mat
            ids.append(len(meshes))
            meshes.append({"name": f"pbrdf_{i}_{j}", "primitives": [p], "extras": {PART_TAG: [key, i, j]}})
        per_mesh.append(ids)
    out["meshes"] = meshes
    nodes = out.get("nodes") or []
    for node in list(nodes):
        if not isinstance(node, dict) or "mesh" not in node:
            continue
        m = node.pop("mesh")
        ids = per_mesh[m] if isinstance(m, int) and 0 <= m < len(per_mesh) else []
        if len(ids) == 1:
            node["mesh"] = ids[0]
            continue
        node.pop("weights", None)
        node["children"] = list(node.get("children") or []) + list(range(len(nodes), len(nodes) + len(ids)))
        nodes.extend({"mesh": k} for k in ids)
    return out


def texcoord_of(info: dict) -> int:
    """The UV set a textureInfo reads (``KHR_texture_transform``'s ``texCoord`` overrides its own)."""
    tt = (info.get("extensions") or {}).get("KHR_texture_transform") or {}
    return int(tt.get("texCoord", info.get("texCoord", 0)))


def texture_infos(m: dict) -> dict[str, dict]:
    """The textureInfos of a material the engine reads, by slot."""
    pbr = m.get("pbrMetallicRoughness") or {}
    infos = {
        "albedo": pbr.get("baseColorTexture"),
        "mr": pbr.get("metallicRoughnessTexture"),
        "normal": m.get("normalTexture"),
    }
    return {k: v for k, v in infos.items() if isinstance(v, dict)}


def texcoord_sets(doc: dict) -> dict[int, int]:
    """Per glTF material, the UV set (``TEXCOORD_<n>``) its textures are read with: 0, or the one all of them use."""
    out = {}
    for k, m in enumerate(doc.get("materials") or []):
        sets = {texcoord_of(i) for i in texture_infos(m).values()} if isinstance(m, dict) else set()
        out[k] = next(iter(sets)) if len(sets) == 1 else 0
    return out


def _check_uv_accessors(doc: dict, sets: dict[int, int], name: str) -> None:
    """Refuse integer (quantised) UVs: trimesh reads them without their normalisation."""
    accessors = doc.get("accessors") or []
    for i, mesh in enumerate(doc.get("meshes") or []):
        for j, p in enumerate(mesh.get("primitives") or []):
            mat = p.get("material")
            t = sets.get(mat, 0) if isinstance(mat, int) else 0
            a = (p.get("attributes") or {}).get(f"TEXCOORD_{t}")
            if isinstance(a, int) and 0 <= a < len(accessors) and accessors[a].get("componentType", _FLOAT) != _FLOAT:
                raise ValueError(f"{name}: mesh {i} primitive {j}: integer (quantised) UVs are not supported")


def tagged_scene(path: Path, name: str) -> trimesh.Scene:
    """The file as a trimesh scene whose every geometry holds one material's triangles with their UVs.

    Each geometry's ``metadata[PART_TAG][0]`` is its material index (-1: none): glTF primitives
    are tagged through :func:`tagged_document`, OBJ groups by their MTL material name.

    Raises:
        ValueError: a file type without materials, integer glTF UVs.
    """
    suffix = path.suffix.lower()
    if suffix in (".gltf", ".glb"):
        doc, binary = read_gltf(path, name)
        sets = texcoord_sets(doc)
        _check_uv_accessors(doc, sets, name)
        tagged = tagged_document(doc, sets)
        data = glb_bytes(tagged, binary) if suffix == ".glb" else json.dumps(tagged).encode("utf-8")
        resolver = trimesh.resolvers.FilePathResolver(str(path))
        return trimesh.load(io.BytesIO(data), file_type=suffix[1:], resolver=resolver, force="scene", process=False)
    if suffix == ".obj":
        scene = trimesh.load(path, file_type="obj", force="scene", process=False)
        names = mtl_names(path)
        for geom in scene.geometry.values():
            mname = getattr(getattr(getattr(geom, "visual", None), "material", None), "name", None)
            geom.metadata[PART_TAG] = [names.index(mname) if mname in names else -1]
        return scene
    raise ValueError(f"{name}: material selectors need a glTF/GLB or OBJ file, got {suffix!r}")


def clean_uvs(parts: list, name: str) -> list[str]:
    """Check the UVs of :class:`.assets.MeshPart` s in place: NaN/Inf raise, huge ones are shifted or wrapped.

    UVs within ``+-UV_LIMIT`` stay. Beyond, a part's UVs are shifted by the integer floor of their
    median (exact under REPEAT for a texture without a non-integer ``KHR_texture_transform``);
    still beyond, every UV is wrapped into [0, 1) (a triangle across a texture edge shows a seam).

    Returns:
        One note per part changed.

    Raises:
        ValueError: ``"<name>: N UV coordinates NaN or infinite (material K)"``.
    """
    notes = []
    for p in parts:
        if p.uvs is None:
            continue
        bad = int(np.sum(~np.isfinite(p.uvs).all(axis=1)))
        if bad:
            raise ValueError(
                f"{name}: {bad} UV coordinate{'s' if bad != 1 else ''} NaN or infinite (material {p.group})"
            )
        if np.abs(p.uvs).max(initial=0.0) <= UV_LIMIT:
            continue
        uv = p.uvs - np.floor(np.median(p.uvs, axis=0))
        how = "shifted by an integer"
        if np.abs(uv).max() > UV_LIMIT:
            uv, how = uv - np.floor(uv), "wrapped into [0, 1) per vertex"
        notes.append(f"UVs beyond +-{UV_LIMIT:g} {how} (material {p.group})")
        p.uvs = uv
    return notes


# --------------------------------------------------------------------------- OBJ + MTL


def mtl_libs(obj: Path) -> list[Path]:
    """The MTL files an OBJ names (``mtllib``), relative to its folder (Windows separators accepted)."""
    libs = []
    with open(obj, "rb") as f:
        for raw in f:
            if raw.lstrip().startswith(b"mtllib"):
                rest = raw.decode("utf-8", "replace").split(None, 1)[1:]
                if rest:
                    libs.append(obj.parent / rest[0].strip().replace("\\", "/"))
    return libs


def mtl_statements(mtl: Path) -> list[tuple[str, str]]:
    """``(keyword, rest of the line)`` of every statement of an MTL file (comments left out)."""
    out = []
    for line in mtl.read_text("utf-8", "replace").splitlines():
        parts = line.strip().split(None, 1)
        if parts and not parts[0].startswith("#"):
            out.append((parts[0], parts[1].strip() if len(parts) > 1 else ""))
    return out


def mtl_names(obj: str | os.PathLike) -> list[str]:
    """Material names of the MTL files an OBJ names (``newmtl`` order, first of equal names; missing files skipped)."""
    names: list[str] = []
    for lib in mtl_libs(Path(obj)):
        if lib.is_file():
            names += [v for k, v in mtl_statements(lib) if k.lower() == "newmtl" and v not in names]
    return names
