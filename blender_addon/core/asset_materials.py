"""Materials an asset file brings: glTF 2.0 metallic-roughness and OBJ's MTL as :class:`.spec.MaterialSpec`.

:func:`read_materials` turns every material of a glTF/GLB file (or of the MTL files an OBJ names)
into a MaterialSpec whose ``textures`` (:class:`.textures.MaterialTextures`) hold the base
colour, roughness, metallic and normal maps, and whose Disney values are the texture means.
What the engine does not model is left out with one note line per topic (the caller records
them in the sample's sidecar); what it cannot read raises one ``ValueError`` line naming the file.

Convention (glTF 2.0, section 3.9):
    * base colour = ``baseColorFactor * srgb_to_linear(baseColorTexture)`` (alpha ignored);
      roughness = ``roughnessFactor * G``, metallic = ``metallicFactor * B`` of
      ``metallicRoughnessTexture`` (linear); the factors default to 1.
    * ``normalTexture`` is a tangent-space map with its ``scale``; ``KHR_texture_transform`` of
      each texture is kept (:class:`.textures.TextureSpec`), ``KHR_materials_ior`` sets the
      dielectric's index (default 1.5).
    * Kind: ``pplastic`` (the dielectric) with ``textures.metallic`` when a metallic texture
      mixes in metal per texel; without a metallic texture a ``metallicFactor`` of 1 is a
      ``conductor`` whose complex index gives the base colour at normal incidence
      (:func:`_metal`); a factor strictly between 0 and 1 is rounded to 0 or 1 (noted).
    * MTL: ``Kd`` is the (linear) base-colour factor, ``map_Kd`` its sRGB texture (the two
      multiply, as the MTL format says), ``-o``/``-s`` become a texture transform, ``Pr``/``Pm``
      set roughness/metallic (default 0.5/0); ``Ka``, ``illum``, ``Tf`` and ``sharpness`` are
      ignored silently (no effect on an opaque surface without ambient light), everything else
      (``Ks``, ``Ns``, ``d``, bump maps, ...) is noted and ignored.

Fallbacks and errors (issue 26, bad input):
    * A texture on a UV set other than the material's one (glTF ``texCoord``; a material whose
      textures all use set 1 reads set 1) is dropped, its factor kept, with a note.
    * ``alphaMode`` MASK (with its ``alphaCutoff``) and BLEND render opaque, noted; samplers
      other than REPEAT render as REPEAT, noted.
    * Embedded images (GLB buffer views, ``data:`` URIs) are written once into
      :func:`image_cache_dir` under their content hash, so every reader of a
      :class:`.textures.TextureSpec` gets a plain PNG/JPEG file.
    * ValueError: a missing or unreadable image, a texture or image index out of range, an
      image that is not PNG/JPEG, an extension in ``extensionsRequired`` the engine does not
      support, integer (quantised) UVs of a textured material.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbrdf.io.atomic import atomic_write_bytes
from pbrdf.io.errors import one_line
from pbrdf.polar.fresnel import METAL_N, conductor_extinction

from . import asset_io, assets
from .spec import MaterialSpec
from .textures import MaterialTextures, TextureSpec, texture_array

__all__ = [
    "ACCEPTED_EXTENSIONS",
    "AssetMaterials",
    "AssetPart",
    "AssetParts",
    "asset_parts",
    "image_cache_dir",
    "read_materials",
    "usable_textured_assets",
]

#: glTF extensions read (or harmless to leave out) and therefore accepted in ``extensionsRequired``.
ACCEPTED_EXTENSIONS = ("KHR_texture_transform", "KHR_materials_emissive_strength", "KHR_materials_ior")
_REPEAT = 10497
_WRAP_NAMES = {33071: "CLAMP_TO_EDGE", 33648: "MIRRORED_REPEAT"}


@dataclass(frozen=True)
class AssetMaterials:
    """The materials of one asset file and what was read differently from it.

    Attributes:
        file: the asset file.
        materials: one MaterialSpec per material, by index (glTF ``materials`` order, MTL ``newmtl`` order).
        notes: one line per topic left out or changed (ignored extensions, alpha modes, ...).
    """

    file: str
    materials: tuple[MaterialSpec, ...]
    notes: tuple[str, ...] = ()


def image_cache_dir() -> Path:
    """Where embedded images are written: ``gltf-images/`` in ``$PBRDF_CACHE``, else ``$XDG_CACHE_HOME/pbrdf``."""
    root = os.environ.get("PBRDF_CACHE") or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pbrdf"
    return Path(root) / "gltf-images"


def _image_kind(data: bytes) -> str | None:
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return ".png"
    return ".jpg" if data[:3] == b"\xff\xd8\xff" else None


class _Notes:
    """Note lines by topic, each listing the materials it concerns."""

    def __init__(self) -> None:
        self.topics: dict[str, list[str]] = defaultdict(list)

    def add(self, topic: str, material: str | None = None) -> None:
        items = self.topics[topic]
        if material is not None and material not in items:
            items.append(material)

    def lines(self, most: int = 6) -> tuple[str, ...]:
        def which(m: list[str]) -> str:
            return ", ".join(m[:most]) + (f", +{len(m) - most} more" if len(m) > most else "")

        return tuple(f"{t} (materials {which(m)})" if m else t for t, m in self.topics.items())


@dataclass
class _Reader:
    """What reading one file's materials shares: the file, its images and the notes."""

    path: Path
    name: str
    doc: dict = field(default_factory=dict)
    binary: bytes | None = None
    notes: _Notes = field(default_factory=_Notes)
    files: dict[int, str] = field(default_factory=dict)
    means: dict[tuple, NDArray] = field(default_factory=dict)

    def image_file(self, index: int) -> str:
        """A PNG/JPEG file holding image ``index`` (embedded ones extracted into :func:`image_cache_dir`)."""
        if index not in self.files:
            data, file = asset_io.image_bytes(self.doc, self.binary, index, self.path.parent, self.name)
            kind = _image_kind(data)
            if kind is None:
                raise ValueError(f"{self.name}: image {index} ({file or 'embedded'}): not a PNG or JPEG file")
            if file is None or file.suffix.lower() not in (".png", ".jpg", ".jpeg"):
                file = image_cache_dir() / f"{hashlib.sha256(data).hexdigest()[:24]}{kind}"
                if not (file.is_file() and file.stat().st_size == len(data)):
                    file.parent.mkdir(parents=True, exist_ok=True)
                    atomic_write_bytes(file, data)
            self.files[index] = str(file)
        return self.files[index]

    def mean(self, tex: TextureSpec) -> NDArray[np.float64]:
        """The texture's mean value over its image, per channel (images read once)."""
        key = (tex.source, tex.channels, tex.colorspace)
        if key not in self.means:
            unit = TextureSpec(tex.source, tex.channels, (1.0,) * len(tex.channels), tex.colorspace)
            try:
                self.means[key] = texture_array(unit).reshape(-1, len(tex.channels)).mean(axis=0, dtype=np.float64)
            except (ValueError, OSError) as e:
                raise ValueError(f"{self.name}: texture image {tex.source}: {one_line(e)}") from None
        return self.means[key] * np.asarray(tex.factor)


def _texture_transform(info: dict) -> dict:
    tt = (info.get("extensions") or {}).get("KHR_texture_transform") or {}
    return {k: tt[k] for k in ("offset", "rotation", "scale") if k in tt}


def _gltf_material(r: _Reader, k: int, m: dict, texcoord: int) -> MaterialSpec:
    """One glTF material as a MaterialSpec (textures, means, kind); notes go to ``r.notes``."""
    label = f"{k} {m.get('name')!r}" if m.get("name") else str(k)
    pbr = m.get("pbrMetallicRoughness") or {}
    try:
        base = np.asarray(pbr.get("baseColorFactor", [1.0] * 4), dtype=np.float64)[:3]
        rough_f, metal_f = float(pbr.get("roughnessFactor", 1.0)), float(pbr.get("metallicFactor", 1.0))
        if base.shape != (3,) or not np.all(np.isfinite([*base, rough_f, metal_f])):
            raise ValueError(f"non-finite or malformed factors {base.tolist()}, {rough_f}, {metal_f}")
    except (TypeError, ValueError) as e:
        raise ValueError(f"{r.name}: material {label}: {one_line(e)}") from None
    if np.any((base < 0) | (base > 1)) or not (0 <= rough_f <= 1 and 0 <= metal_f <= 1):
        r.notes.add("factors outside [0, 1] clipped", label)
        base, rough_f, metal_f = np.clip(base, 0, 1), min(max(rough_f, 0.0), 1.0), min(max(metal_f, 0.0), 1.0)
    slots: dict[str, TextureSpec] = {}
    want = {"albedo": [((0, 1, 2), tuple(base), "srgb", "albedo")],
            "mr": [((1,), (rough_f,), "linear", "roughness"), ((2,), (metal_f,), "linear", "metallic")],
            "normal": [((0, 1, 2), (1.0, 1.0, 1.0), "linear", "normal")]}  # fmt: skip
    for key, info in asset_io.texture_infos(m).items():
        if asset_io.texcoord_of(info) != texcoord:
            r.notes.add(
                f"textures on UV set {asset_io.texcoord_of(info)} dropped (one UV set per material; factor kept)", label
            )
            continue
        tex = asset_io.item(r.doc, "textures", info.get("index"), r.name, f"material {label}")
        if "source" not in tex:
            exts = sorted(tex.get("extensions") or {})
            raise ValueError(f"{r.name}: material {label}: texture {info['index']} has no PNG/JPEG source ({exts})")
        where = f"material {label}"
        sampler = {} if "sampler" not in tex else asset_io.item(r.doc, "samplers", tex["sampler"], r.name, where)
        for wrap in {sampler.get("wrapS", _REPEAT), sampler.get("wrapT", _REPEAT)} - {_REPEAT}:
            r.notes.add(f"sampler wrap {_WRAP_NAMES.get(wrap, wrap)} rendered as REPEAT", label)
        file = r.image_file(tex["source"])
        for channels, factor, space, slot in want[key]:
            try:
                slots[slot] = TextureSpec(file, channels, factor, space, **_texture_transform(info))
            except ValueError as e:
                raise ValueError(f"{r.name}: material {label}: {one_line(e)}") from None
    albedo = r.mean(slots["albedo"]) if "albedo" in slots else base
    rough = float(r.mean(slots["roughness"])[0]) if "roughness" in slots else rough_f
    metal = float(r.mean(slots["metallic"])[0]) if "metallic" in slots else metal_f
    if "metallic" not in slots and metal not in (0.0, 1.0):
        metal_was, metal = metal, float(metal >= 0.5)
        r.notes.add(f"metallicFactor {metal_was:.3g} without a texture rounded to {metal:g}", label)
    normal_scale = float((m.get("normalTexture") or {}).get("scale", 1.0)) if "normal" in slots else 1.0
    textures = MaterialTextures(**slots, normal_scale=normal_scale) if slots else None
    _note_unmodelled(r, m, label)
    name = f"{r.path.stem}_{k}" + (f"_{m['name']}" if isinstance(m.get("name"), str) and m["name"] else "")
    albedo = tuple(float(a) for a in np.clip(albedo, 0, 1))
    rough = min(max(rough, 0.0), 1.0)
    if "metallic" not in slots and metal == 1.0:
        return _metal(name, albedo, rough, textures)
    ior = (m.get("extensions") or {}).get("KHR_materials_ior", {}).get("ior", 1.5)
    ior = float(ior) if isinstance(ior, (int, float)) and ior > 0 else 1.5
    return MaterialSpec(name, "pplastic", albedo, rough, min(max(metal, 0.0), 1.0), ior=ior, textures=textures)


def _note_unmodelled(r: _Reader, m: dict, label: str) -> None:
    mode = m.get("alphaMode", "OPAQUE")
    if mode == "MASK":
        r.notes.add(f"alphaMode MASK (alphaCutoff {float(m.get('alphaCutoff', 0.5)):g}) rendered opaque", label)
    elif mode == "BLEND":
        r.notes.add("alphaMode BLEND rendered opaque", label)
    if "occlusionTexture" in m:
        r.notes.add("occlusionTexture (baked shadowing) ignored", label)
    if "emissiveTexture" in m or any(m.get("emissiveFactor") or []):
        r.notes.add("emission not modelled, ignored", label)
    for ext in sorted(set(m.get("extensions") or {}) - set(ACCEPTED_EXTENSIONS)):
        r.notes.add(f"{ext} not modelled, ignored", label)


def _gltf_materials(path: Path, name: str) -> AssetMaterials | None:
    doc, binary = asset_io.read_gltf(path, name)
    required = doc.get("extensionsRequired") or []
    for ext in required if isinstance(required, list) else []:
        if ext not in ACCEPTED_EXTENSIONS:
            raise ValueError(f"{name}: extensionsRequired names {ext}, which the engine does not support")
    mats = doc.get("materials") or []
    if not isinstance(mats, list) or not mats:
        return None
    r = _Reader(path, name, doc, binary)
    texcoord = asset_io.texcoord_sets(doc)
    out = []
    for k, m in enumerate(mats):
        if not isinstance(m, dict):
            raise ValueError(f"{name}: material {k} is not a JSON object")
        out.append(_gltf_material(r, k, m, texcoord[k]))
    for ext in doc.get("extensionsUsed") or []:
        if ext not in ACCEPTED_EXTENSIONS and not any(ext in t for t in r.notes.topics) and "draco" not in ext:
            r.notes.add(f"{ext} not modelled, ignored")
    return AssetMaterials(name, tuple(out), r.notes.lines())


# --------------------------------------------------------------------------- OBJ + MTL

_MTL_READ = {"kd", "map_kd", "pr", "pm"}  # lower case: MTL keywords are matched case-insensitively
_MTL_SILENT = {"ka", "illum", "tf", "sharpness"}  # no effect on an opaque surface without ambient light
_MAP_ARGS = {"-o": 3, "-s": 3, "-t": 3, "-mm": 2, "-bm": 1, "-boost": 1, "-texres": 1, "-clamp": 1, "-blendu": 1,
             "-blendv": 1, "-cc": 1, "-imfchan": 1, "-type": 1}  # fmt: skip


def _map_kd(value: str, base: Path, label: str, r: _Reader) -> tuple[str, dict]:
    """``map_Kd [options] file`` -> (file, KHR_texture_transform fields)."""
    tokens, opts, i = value.split(), {}, 0
    while i < len(tokens) and tokens[i] in _MAP_ARGS:
        opt, n = tokens[i], _MAP_ARGS[tokens[i]]
        args = []
        for t in tokens[i + 1 : i + 1 + n]:
            if not re.fullmatch(r"[-+]?[\d.]+(e[-+]?\d+)?", t, re.I) and opt in ("-o", "-s", "-t", "-mm"):
                break
            args.append(t)
        opts[opt], i = args, i + 1 + len(args)
    for opt in sorted(set(opts) - {"-o", "-s"}):
        r.notes.add(f"map_Kd option {opt} ignored", label)
    file = base / " ".join(tokens[i:]).replace("\\", "/")
    o = [float(x) for x in opts.get("-o", [])] + [0.0, 0.0]
    s = [float(x) for x in opts.get("-s", [])] + [1.0, 1.0]  # an absent v defaults to 1, as MTL says
    # MTL's uv' = s uv + o in OpenGL UVs (v up) is glTF's offset (o_u, 1 - s_v - o_v), scale s (v down).
    tt = {"offset": (o[0], 1.0 - s[1] - o[1]), "scale": (s[0], s[1])} if "-o" in opts or "-s" in opts else {}
    return str(file), tt


def _mtl_materials(obj: Path, name: str) -> AssetMaterials | None:
    r = _Reader(obj, name)
    entries: dict[str, dict[str, str]] = {}
    bases: dict[str, Path] = {}
    for lib in asset_io.mtl_libs(obj):
        if not lib.is_file():
            r.notes.add(f"mtllib {lib.name} not found: its materials are left to the caller")
            continue
        current = None
        for key, value in asset_io.mtl_statements(lib):
            if key.lower() == "newmtl":
                current = value if value not in entries else None
                if current is not None:
                    entries[current], bases[current] = {}, lib.parent
            elif current is not None and key.lower() in _MTL_READ:
                entries[current][key.lower()] = value
            elif current is not None and key.lower() not in _MTL_SILENT:
                r.notes.add(f"MTL statement {key} not modelled, ignored", current or "''")
    if not entries:
        return None
    out = []
    for k, (mname, e) in enumerate(entries.items()):
        try:
            kd = [float(x) for x in e.get("kd", "").split()[:3]] or [1.0 if "map_kd" in e else 0.8] * 3
            kd = kd * 3 if len(kd) == 1 else kd
            rough, metal = float(e.get("pr", 0.5)), float(e.get("pm", 0.0))
            if len(kd) != 3 or not np.all(np.isfinite([*kd, rough, metal])):
                raise ValueError(f"bad Kd/Pr/Pm {e}")
            tex = None
            if "map_kd" in e:
                file, tt = _map_kd(e["map_kd"], bases[mname], mname, r)
                if not Path(file).is_file():
                    raise ValueError(f"map_Kd file not found: {file}")
                tex = TextureSpec(file, (0, 1, 2), tuple(np.clip(kd, 0, 1)), "srgb", **tt)
        except ValueError as err:
            raise ValueError(f"{name}: MTL material {mname!r}: {one_line(err)}") from None
        kd = tuple(float(x) for x in np.clip(kd, 0, 1))
        rough, metal = min(max(rough, 0.0), 1.0), float(metal >= 0.5)
        textures = None if tex is None else MaterialTextures(albedo=tex)
        albedo = np.asarray(kd) if tex is None else r.mean(tex)
        albedo = tuple(float(a) for a in np.clip(albedo, 0, 1))
        mat_name = f"{obj.stem}_{k}_{mname}"
        if metal == 1.0:
            out.append(_metal(mat_name, albedo, rough, textures))
        else:
            out.append(MaterialSpec(mat_name, "pplastic", albedo, rough, 0.0, textures=textures))
    return AssetMaterials(name, tuple(out), r.notes.lines())


# --------------------------------------------------------------------------- entry point

_CACHE: dict[tuple, AssetMaterials | None] = {}
_CACHE_SIZE = 32


def read_materials(path: str | os.PathLike) -> AssetMaterials | None:
    """The materials of a glTF/GLB file or of an OBJ's MTL files; None for a file without any (or PLY/STL/OFF).

    Results are cached per process (file path, size and modification time): treat them as read-only.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: one line ``"<file>: <reason>"`` (see the module's list of bad input).
    """
    path = Path(path)
    name = str(path)
    st = os.stat(path)
    key: Any = (name, st.st_mtime_ns, st.st_size, str(image_cache_dir()))
    if key in _CACHE:
        return _CACHE[key]
    suffix = path.suffix.lower()
    try:
        out = _gltf_materials(path, name) if suffix in (".gltf", ".glb") else None
        out = _mtl_materials(path, name) if suffix == ".obj" else out
    except ValueError as e:
        if str(e).startswith(name):
            raise
        raise ValueError(f"{name}: malformed material data: {one_line(e)}") from None
    except (AttributeError, TypeError, KeyError, IndexError) as e:  # JSON of the wrong types
        raise ValueError(f"{name}: malformed material data: {type(e).__name__}: {one_line(e)}") from None
    _CACHE[key] = out
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    return out


# --------------------------------------------------------------------------- parts with their materials


@dataclass(frozen=True)
class AssetPart:
    """One material's share of an asset: an object of a scene.

    Attributes:
        mesh: the mesh reference ``"<file>#material=<K>"`` (:func:`.assets.load_part`).
        key: K, the material index (:data:`.assets.MATERIAL_NONE` for triangles without one).
        material: the file's material K, or None (no material: the caller picks one).
    """

    mesh: str
    key: int
    material: MaterialSpec | None


@dataclass(frozen=True)
class AssetParts:
    """The parts of an asset file, one per material with triangles, and the notes of its reading.

    Attributes:
        file: the asset file.
        parts: in material order (triangles without a material last).
        notes: one line per thing read differently from the file (the sample's sidecar records them).
    """

    file: str
    parts: tuple[AssetPart, ...]
    notes: tuple[str, ...] = ()


def asset_parts(path: str | os.PathLike, *, crease_deg: float | None = None) -> AssetParts | None:
    """A glTF/OBJ file as one part per material with its MaterialSpec; None for a file without materials.

    A scene holds a multi-material asset as one object per part, all at the asset's pose: the
    object index of the ground truth tells the parts apart, and each part gets its own UVs.

    Raises:
        FileNotFoundError: no such file.
        ValueError: one line ``"<file>: <reason>"``: unreadable materials or textures
            (:func:`read_materials`), a mesh the asset pipeline refuses, NaN UVs.
    """
    mats = read_materials(path)
    if mats is None:
        return None
    parts, notes, lost = [], list(mats.notes), []
    for k in assets.material_keys(path, crease_deg=crease_deg):
        material = mats.materials[k] if 0 <= k < len(mats.materials) else None
        ref = f"{path}#material={'none' if k == assets.MATERIAL_NONE else k}"
        mesh = assets.load_mesh(ref, crease_deg=crease_deg)
        if material is not None and material.textures is not None and not mesh.metadata["has_uv"]:
            lost.append(k)
        parts.append(AssetPart(ref, k, material))
        notes += [n for n in mesh.metadata["uv_notes"] if n not in notes]  # every part's, each once
    if lost:
        notes.append(f"textured materials {lost} have triangles without UVs (their textures read one texel there)")
    return AssetParts(str(path), tuple(parts), tuple(notes))


def usable_textured_assets(files: list[str | os.PathLike]) -> tuple[list[Path], dict[str, str]]:
    """:func:`.assets.usable_assets`, with every file's materials and parts read too (:func:`asset_parts`).

    Returns:
        ``(usable files in the given order, {file: the one-line reason})``.
    """
    ok, refused = assets.usable_assets(files)
    for f in list(ok):
        try:
            asset_parts(f)
        except (ValueError, OSError) as e:
            refused[str(f)] = one_line(e)
            ok.remove(f)
    return ok, refused


def _metal(name: str, albedo: tuple[float, ...], roughness: float, textures: MaterialTextures | None) -> MaterialSpec:
    """A conductor whose normal-incidence reflectance is the base colour: index ``METAL_N - ik`` per channel.

    The same metal a ``metallic`` texture mixes in (:func:`pbrdf.polar.fresnel.conductor_extinction`).
    """
    k, _ = conductor_extinction(np.asarray(albedo, np.float64))
    return MaterialSpec(name, "conductor", albedo, roughness, 1.0, eta=(METAL_N,) * 3, k=tuple(float(x) for x in k),
                        textures=textures)  # fmt: skip
