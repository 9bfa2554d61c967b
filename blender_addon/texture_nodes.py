"""Textured materials in Blender: :class:`~.core.textures.MaterialTextures` <-> Image Texture nodes.

:func:`add_texture_nodes` builds what a spec's textures mean (the scene builder and
:func:`.build_spec.build_from_spec` call it); :func:`textures_from_nodes` reads such a node setup
back (:func:`.export_spec.material_spec_from_blender`). Node setups, per Principled input:

* ``Base Color``, ``Roughness``, ``Metallic``: an Image Texture's ``Color`` (three channels; a
  grey image for a scalar), its ``Alpha`` (channel 3) or one output of a Separate Color node
  (RGB mode) fed by it (glTF's roughness = G, metallic = B), optionally times a constant (Math
  Multiply for a scalar, Mix Color Multiply with factor 1 for a colour): the texture's factor.
* ``Normal``: a Normal Map node (tangent space, ``Strength`` = ``normal_scale``) fed as above.
* Image vector: nothing (the active UV map), a UV Map node or Texture Coordinate's ``UV``,
  optionally through a Mapping node (Point type, rotation about z only): ``KHR_texture_transform``
  (:func:`mapping_of` and :func:`transform_of` convert it).
* Images: a file texture loads the file (``sRGB`` for an sRGB colour texture, ``Non-Color``
  otherwise); a procedural one becomes a packed float image of :func:`.core.textures.texture_array`
  (its factor and channels baked in), so a saved .blend is self-contained. A colour image's
  ``Color`` into a scalar input is Blender's luminance of it: exported as its red channel, which
  is exact for the grey images this module builds.

Exported images: a file on disk keeps its path; a packed or generated image is written once into
the export's texture folder under its content hash (atomically). Anything else linked into those
inputs (procedural Blender textures, mixes, colour ramps) exports the constant with one warning.
Blender's Normal Map ``Strength`` blends the mapped normal with the surface normal where glTF
scales the map's x and y: the two agree at 1 and differ a little elsewhere.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import bpy
import numpy as np

from .core.textures import MaterialTextures, TextureSpec, texture_array
from .images import image_from_array

__all__ = [
    "IMAGE_KEY",
    "SIGNATURE_KEY",
    "UV_LAYER",
    "add_texture_nodes",
    "mapping_of",
    "node_signature",
    "textures_from_nodes",
    "transform_of",
]

#: The UV layer the add-on's meshes carry (and the UV Map / Normal Map nodes name).
UV_LAYER = "UVMap"
#: Material custom property: JSON of :func:`node_signature` right after :func:`add_texture_nodes`.
SIGNATURE_KEY = "pdir_texture_nodes"
#: Image custom property marking the images :func:`add_texture_nodes` made or loaded (removed with their materials).
IMAGE_KEY = "pdir_texture"
_INPUTS = {"albedo": "Base Color", "roughness": "Roughness", "metallic": "Metallic", "normal": "Normal"}
_RGB = ("Red", "Green", "Blue")
_SUFFIX = {b"\x89PNG": ".png", b"\xff\xd8\xff": ".jpg", b"v/1\x01": ".exr"}


# --------------------------------------------------------------------------- KHR_texture_transform <-> Mapping


def mapping_of(tex: TextureSpec) -> tuple[tuple[float, float], float, tuple[float, float]]:
    """A texture's ``KHR_texture_transform`` as a Point Mapping node's (location xy, rotation z, scale xy).

    The Mapping node maps ``p -> L + R_z(rot) (S p)`` on Blender's UVs (OpenGL's, v up): the node
    is :meth:`~.core.textures.TextureSpec.uv_matrix` decomposed (``L`` its translation, ``S`` the
    texture's scale, which flipping v leaves alone), so the two follow one convention by construction.

    Example:
        >>> mapping_of(TextureSpec("a.png", offset=(0.5, 0.25)))
        ((0.5, -0.25), 0.0, (1.0, 1.0))
    """
    m = tex.uv_matrix()
    sx = tex.scale[0] if tex.scale[0] != 0.0 else 1.0
    rot = math.atan2(m[1, 0] / sx, m[0, 0] / sx)
    return (float(m[0, 2]) + 0.0, float(m[1, 2]) + 0.0), rot + 0.0, tex.scale


def transform_of(location, rotation: float, scale) -> dict[str, Any]:
    """Inverse of :func:`mapping_of`: ``{"offset", "rotation", "scale"}`` of a TextureSpec.

    Example:
        >>> transform_of((0.5, -0.25), 0.0, (1.0, 1.0))
        {'offset': (0.5, 0.25), 'rotation': 0.0, 'scale': (1.0, 1.0)}
    """
    scale = (float(scale[0]), float(scale[1]))
    # The sign uv_matrix gives a rotation (the mapping is linear in it), then the offset (affine in it).
    turn = mapping_of(TextureSpec("probe.png", rotation=0.5))[1] / 0.5
    rot = float(rotation) / turn
    zero = mapping_of(TextureSpec("probe.png", rotation=rot, scale=scale))[0]
    unit = mapping_of(TextureSpec("probe.png", offset=(1.0, 1.0)))[0]  # offset's effect: +-1 per axis
    off = tuple((float(location[i]) - zero[i]) * (1.0 if unit[i] > 0 else -1.0) + 0.0 for i in range(2))
    return {"offset": off, "rotation": rot + 0.0, "scale": scale}


# --------------------------------------------------------------------------- spec -> nodes


def _procedural_image(tex: TextureSpec) -> bpy.types.Image:
    """A packed float image of the texture's values (factor and channels applied), reused by content."""
    key = hashlib.sha1(json.dumps(tex.to_dict(), sort_keys=True).encode()).hexdigest()[:12]
    name = f"PDIR {tex.source.partition(':')[2]} {key}"
    img = bpy.data.images.get(name)
    if img is not None:
        return img
    # Linear values as texture_array gives them (one channel: grey), packed as a float EXR.
    img = image_from_array(name, texture_array(tex), colorspace="Non-Color", pack=True)
    img[IMAGE_KEY] = True
    return img


def _file_image(tex: TextureSpec) -> bpy.types.Image:
    path = str(Path(tex.source).resolve())
    space = "sRGB" if tex.colorspace == "srgb" and Path(path).suffix.lower() != ".exr" else "Non-Color"
    for img in bpy.data.images:
        if img.source == "FILE" and bpy.path.abspath(img.filepath) == path and img.colorspace_settings.name == space:
            return img
    if not os.path.isfile(path):
        raise ValueError(f"{tex.source}: texture file not found")
    img = bpy.data.images.load(path, check_existing=False)
    img.colorspace_settings.name = space
    img[IMAGE_KEY] = True
    return img


class _Builder:
    """Adds nodes to a material's tree, laid out in columns left of the BSDF."""

    def __init__(self, mat: bpy.types.Material, bsdf: bpy.types.Node) -> None:
        self.nodes, self.links, self.bsdf = mat.node_tree.nodes, mat.node_tree.links, bsdf
        self.row = 0

    def node(self, kind: str, column: int, **attrs) -> bpy.types.Node:
        n = self.nodes.new(kind)
        n.location = (self.bsdf.location.x - 250 * column, self.bsdf.location.y - 260 * self.row)
        for k, v in attrs.items():
            setattr(n, k, v)
        return n

    def slot(self, slot: str, tex: TextureSpec, normal_scale: float) -> None:
        img = self.node("ShaderNodeTexImage", 4)
        img.image = _procedural_image(tex) if tex.procedural else _file_image(tex)
        uv = self.node("ShaderNodeUVMap", 6, uv_map=UV_LAYER)
        vector = uv.outputs["UV"]
        if (tex.offset, tex.rotation, tex.scale) != ((0.0, 0.0), 0.0, (1.0, 1.0)):
            mapping = self.node("ShaderNodeMapping", 5, vector_type="POINT")
            loc, rot, scale = mapping_of(tex)
            mapping.inputs["Location"].default_value = (*loc, 0.0)
            mapping.inputs["Rotation"].default_value = (0.0, 0.0, rot)
            mapping.inputs["Scale"].default_value = (*scale, 1.0)
            self.links.new(vector, mapping.inputs["Vector"])
            vector = mapping.outputs["Vector"]
        self.links.new(vector, img.inputs["Vector"])
        # A procedural image holds exactly the texture's values: channel 0 (grey) or all three.
        channels = ((0, 1, 2) if len(tex.channels) == 3 else (0,)) if tex.procedural else tex.channels
        out = self.channels(img, channels)
        if not tex.procedural and any(f != 1.0 for f in tex.factor):
            out = self.multiply(out, tex.factor)
        if slot == "normal":
            nmap = self.node("ShaderNodeNormalMap", 1, space="TANGENT", uv_map=UV_LAYER)
            nmap.inputs["Strength"].default_value = normal_scale
            self.links.new(out, nmap.inputs["Color"])
            out = nmap.outputs["Normal"]
        self.links.new(out, self.bsdf.inputs[_INPUTS[slot]])
        self.row += 1

    def channels(self, img: bpy.types.Node, channels: tuple[int, ...]) -> bpy.types.NodeSocket:
        if channels == (0, 1, 2):
            return img.outputs["Color"]
        if channels == (3,):
            return img.outputs["Alpha"]
        sep = self.node("ShaderNodeSeparateColor", 3, mode="RGB")
        self.links.new(img.outputs["Color"], sep.inputs["Color"])
        pick = [img.outputs["Alpha"] if c == 3 else sep.outputs[_RGB[c]] for c in channels]
        if len(pick) == 1:
            return pick[0]
        comb = self.node("ShaderNodeCombineColor", 2, mode="RGB")
        for sock, name in zip(pick, _RGB, strict=True):
            self.links.new(sock, comb.inputs[name])
        return comb.outputs["Color"]

    def multiply(self, out: bpy.types.NodeSocket, factor: tuple[float, ...]) -> bpy.types.NodeSocket:
        if len(factor) == 1:
            math_node = self.node("ShaderNodeMath", 2, operation="MULTIPLY")
            self.links.new(out, math_node.inputs[0])
            math_node.inputs[1].default_value = factor[0]
            return math_node.outputs["Value"]
        mix = self.node("ShaderNodeMix", 2, data_type="RGBA", blend_type="MULTIPLY")
        mix.inputs["Factor"].default_value = 1.0
        self.links.new(out, _sock(mix.inputs, "A_Color"))
        _sock(mix.inputs, "B_Color").default_value = (*factor, 1.0)
        return _sock(mix.outputs, "Result_Color")


def add_texture_nodes(mat: bpy.types.Material, bsdf: bpy.types.Node, textures: MaterialTextures) -> None:
    """Feed ``bsdf``'s Base Color, Roughness, Metallic and Normal from ``textures`` (see the module docstring).

    Mixtures of pBRDF tables (``tables``, ``weights``) have no Blender preview: they stay in the
    material's stored spec only. The material gets :data:`SIGNATURE_KEY` (edit detection).

    Raises:
        ValueError: a texture file that does not exist, or a procedural texture that cannot be built.
    """
    b = _Builder(mat, bsdf)
    for slot in _INPUTS:
        tex = getattr(textures, slot)
        if tex is not None:
            b.slot(slot, tex, textures.normal_scale)
    mat[SIGNATURE_KEY] = json.dumps(node_signature(bsdf), sort_keys=True)


# --------------------------------------------------------------------------- nodes -> spec


@dataclass
class _Found:
    """One textured input read from the nodes."""

    image: bpy.types.Image
    channels: tuple[int, ...]
    factor: tuple[float, ...] | None
    transform: dict
    strength: float = 1.0
    note: str = ""  # exported, but not exactly what Blender shows

    def signature(self) -> dict:
        img = self.image
        return {"image": img.name, "file": img.filepath, "space": img.colorspace_settings.name,
                "packed": img.packed_file is not None, "channels": list(self.channels),
                "factor": None if self.factor is None else list(self.factor), "strength": self.strength,
                **{k: list(v) if isinstance(v, tuple) else v for k, v in self.transform.items()}}  # fmt: skip


def _sock(sockets, identifier: str) -> bpy.types.NodeSocket:
    """A socket by identifier (the Mix node's sockets share names across data types)."""
    return next(s for s in sockets if s.identifier == identifier)


def _link(sock: bpy.types.NodeSocket) -> bpy.types.NodeLink | None:
    return sock.links[0] if sock.is_linked and sock.links else None


def _vector(img_node: bpy.types.Node) -> dict | str:
    """The image's UV transform (``{}`` for none), or why it is not one."""
    link = _link(img_node.inputs["Vector"])
    if link is None:
        return {}
    node = link.from_node
    transform: dict = {}
    if node.type == "MAPPING":
        ins = node.inputs
        if node.vector_type != "POINT" or any(ins[k].is_linked for k in ("Location", "Rotation", "Scale")):
            return f"a {node.vector_type.lower()} Mapping node (or one with linked inputs)"
        rot = ins["Rotation"].default_value
        if abs(rot[0]) > 1e-6 or abs(rot[1]) > 1e-6:
            return "a Mapping node rotating about x or y"
        transform = transform_of(ins["Location"].default_value[:2], rot[2], ins["Scale"].default_value[:2])
        link = _link(ins["Vector"])
        if link is None:
            return "a Mapping node without UV input"
        node = link.from_node
    if node.type == "UVMAP" or (node.type == "TEX_COORD" and link.from_socket.name == "UV"):
        return transform
    return f"image coordinates from {node.type}"


def _walk(sock: bpy.types.NodeSocket, width: int) -> _Found | str | None:
    """What feeds a BSDF input: None (unlinked), a :class:`_Found`, or why it is not exported."""
    link = _link(sock)
    if link is None:
        return None
    strength = 1.0
    node, out = link.from_node, link.from_socket
    if width == 3 and sock.name == "Normal":
        if node.type != "NORMAL_MAP" or node.space != "TANGENT" or node.inputs["Strength"].is_linked:
            return f"normal from {node.type} (only a tangent-space Normal Map node is exported)"
        strength = float(node.inputs["Strength"].default_value)
        link = _link(node.inputs["Color"])
        if link is None:
            return "a Normal Map node without image"
        node, out = link.from_node, link.from_socket
    factor = None
    if node.type == "MATH" and node.operation == "MULTIPLY" and not node.use_clamp and width == 1:
        linked = [s for s in node.inputs[:2] if s.is_linked]
        if len(linked) == 1:
            factor = (float(next(s for s in node.inputs[:2] if not s.is_linked).default_value),)
            node, out = linked[0].links[0].from_node, linked[0].links[0].from_socket
    elif node.type == "MIX" and node.data_type == "RGBA" and node.blend_type == "MULTIPLY" and width == 3:
        a, b, fac = (_sock(node.inputs, k) for k in ("A_Color", "B_Color", "Factor_Float"))
        if not fac.is_linked and fac.default_value == 1.0 and not node.clamp_result and a.is_linked != b.is_linked:
            src, const = (a, b) if a.is_linked else (b, a)
            factor = tuple(float(x) for x in const.default_value[:3])
            node, out = src.links[0].from_node, src.links[0].from_socket
    channels: tuple[int, ...] = (0, 1, 2) if width == 3 else (0,)
    if node.type == "SEPARATE_COLOR" and node.mode == "RGB" and width == 1:
        channels = (_RGB.index(out.name),)
        link = _link(node.inputs["Color"])
        if link is None or link.from_socket.name != "Color":
            return "a Separate Color node without image"
        node, out = link.from_node, link.from_socket
    if node.type != "TEX_IMAGE" or node.image is None:
        return f"{node.type} node"
    if out.name == "Alpha":
        if width != 1 or channels != (0,):
            return "an image's alpha into a colour"
        channels = (3,)
    transform = _vector(node)
    if isinstance(transform, str):
        return transform
    note = f"image extension {node.extension} is exported as REPEAT (the spec's UVs wrap)"
    return _Found(node.image, channels, factor, transform, strength, "" if node.extension == "REPEAT" else note)


def node_signature(bsdf: bpy.types.Node) -> dict:
    """What feeds the textured inputs, as JSON values (image names, channels, factors, transforms)."""
    out = {}
    for slot, name in _INPUTS.items():
        found = _walk(bsdf.inputs[name], 1 if slot in ("roughness", "metallic") else 3)
        if found is not None:
            out[slot] = found if isinstance(found, str) else found.signature()
    return out


def _image_file(img: bpy.types.Image, texture_dir: Path) -> str:
    """A file holding the image: its own file, or the packed/generated pixels written once under their hash."""
    if img.source == "FILE" and Path(bpy.path.abspath(img.filepath)).is_file():
        return str(Path(bpy.path.abspath(img.filepath)).resolve())
    if img.packed_file is not None:
        data = bytes(img.packed_file.data)
        suffix = next((s for magic, s in _SUFFIX.items() if data.startswith(magic)), None)
        if suffix is None:
            raise ValueError(f"image {img.name!r}: packed {img.file_format} images are not exported (PNG, JPEG, EXR)")
        return str(_write_once(texture_dir, img.name, suffix, data, lambda p: p.write_bytes(data)))
    if img.source == "FILE":
        raise ValueError(f"image {img.name!r}: file {bpy.path.abspath(img.filepath)} not found (and not packed)")
    if img.source != "GENERATED":
        raise ValueError(f"image {img.name!r}: {img.source.lower()} images are not exported")
    px = np.empty(len(img.pixels), np.float32)
    img.pixels.foreach_get(px)
    fmt = "OPEN_EXR" if img.is_float else "PNG"

    def save(p: Path) -> None:
        old = img.file_format
        img.file_format = fmt
        try:
            img.save(filepath=str(p))
        finally:
            img.file_format = old

    return str(_write_once(texture_dir, img.name, ".exr" if img.is_float else ".png", px.tobytes(), save))


def _write_once(folder: Path, name: str, suffix: str, content: bytes, write) -> Path:
    """``folder/<name>-<hash><suffix>``, written by ``write(tmp)`` then renamed unless it exists."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in Path(name).stem)
    path = folder / f"{safe}-{hashlib.sha1(content).hexdigest()[:12]}{suffix}"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{path.stem}.{os.getpid()}.tmp{suffix}"
        try:
            write(tmp)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
    return path.resolve()


def textures_from_nodes(
    bsdf: bpy.types.Node, texture_dir: str | os.PathLike, warnings: list[str], where: str
) -> tuple[MaterialTextures | None, set[str]]:
    """The textures a Principled BSDF's node setup shows (see the module docstring).

    Args:
        bsdf: a Principled BSDF node.
        texture_dir: where packed and generated images are written (created when needed).
        warnings: gets one line per linked input that is not exported.
        where: the material, for the warnings.

    Returns:
        ``(MaterialTextures or None, the BSDF input names read as textures)``.
    """
    kw: dict[str, Any] = {}
    for slot, name in _INPUTS.items():
        found = _walk(bsdf.inputs[name], 1 if slot in ("roughness", "metallic") else 3)
        if found is None:
            continue
        if isinstance(found, str):
            warnings.append(f"{where}: input {name!r} is fed by {found}; its constant is exported")
            continue
        if found.note:
            warnings.append(f"{where}: input {name!r}: {found.note}")
        try:
            source = _image_file(found.image, Path(texture_dir))
        except ValueError as e:
            warnings.append(f"{where}: input {name!r}: {e}; its constant is exported")
            continue
        srgb = found.image.colorspace_settings.name == "sRGB" and not source.lower().endswith(".exr")
        kw[slot] = TextureSpec(source, channels=found.channels, factor=found.factor,
                               colorspace="srgb" if srgb else "linear", **found.transform)  # fmt: skip
        if slot == "normal":
            kw["normal_scale"] = found.strength
    return (MaterialTextures(**kw) if kw else None), {_INPUTS[s] for s in kw if s in _INPUTS}
