"""One relighting job in a fresh Blender session: predicted maps -> asset, relit frames, ``.blend``.

The body of ``headless/relight.py`` (which runs it in its own process: bpy never shares one with
torch or Mitsuba). :func:`relight_maps` empties the session, imports the maps as the
camera-parented Principled BSDF asset (:func:`blender_addon.pbr_import.import_pbr_maps`),
renders a point light orbiting it and one frame under a procedural sky or an HDR environment
with Cycles (:mod:`blender_addon.relight_operator`), and optionally saves the scene for artists: Cycles
with denoising, the world of the environment frame, the orbit light (at frame 1, keyframed over
the orbit; added even when no frame is rendered), the capture camera with the camera-parented
asset, and every image packed, so the ``.blend`` opens lit and self-contained anywhere. It
takes plain arguments only, so it runs the same from the bpy wheel and inside Blender.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import bpy
from mathutils import Vector

from pbrdf.io.atomic import atomic_folder

from . import pbr_import, relight_operator

__all__ = [
    "relight_maps",
    "relight_batch",
    "RelightJob",
    "relit_scene",
    "point_light_power",
    "ARTIST_SAMPLES",
    "SAMPLES",
    "SIZE",
    "DENOISE",
]

#: The orbit's target: an empty at the asset's centre.
ASSET_CENTRE_NAME = "PDIR Asset Centre"
#: Cycles samples of the saved ``.blend`` (with denoising), unless the relit frames used more.
ARTIST_SAMPLES = 128
#: The relit frames' defaults (``headless/relight.py`` and the demo): the cheapest measured setting whose
#: frames score a PSNR of 35 dB or more against a 1024-sample reference (docs/measurements/relight.md).
SAMPLES, SIZE, DENOISE = 4, 160, True


def point_light_power(radius: float, height: float, exposure: float = 1.0) -> float:
    """Point-light power (W) for a radiance of about ``0.5 * exposure`` off a 0.5 albedo facing the light.

    From ``L = rho / pi * P / (4 pi d^2)`` with ``d^2 = radius^2 + height^2``.

    Args:
        radius: orbit radius in metres.
        height: orbit height above the asset in metres.
        exposure: scale of the result.

    Returns:
        ``4 pi^2 d^2 * exposure``.
    """
    return 4.0 * math.pi**2 * (radius**2 + height**2) * exposure


def relight_maps(
    maps: str | os.PathLike,
    out: str | os.PathLike,
    *,
    name: str = "",
    frames: int = 8,
    size: int = SIZE,
    samples: int = SAMPLES,
    distance: float = 1.0,
    exposure: float = 1.0,
    hdr: str | os.PathLike | None = None,
    env_strength: float = 0.3,
    sun: bool = False,
    device: str = "CPU",
    denoise: bool = DENOISE,
    save_blend: bool = False,
) -> list[Path]:
    """Import predicted maps into an empty Blender session, relight, render and optionally save.

    Args:
        maps: folder with ``<name>_normal/_albedo/_roughness/_metallic/_mask.exr`` (any names the
            add-on's importer recognises), or one map file when ``name`` is empty.
        out: output folder (created if missing).
        name: map name prefix; empty for ``maps`` as one file.
        frames: point-light orbit frames; 0 renders nothing.
        size: longest side of the rendered frames in pixels.
        samples: Cycles samples per pixel.
        distance: asset plane distance from the camera in metres.
        exposure: point-light power scale.
        hdr: environment map (``.hdr``/``.exr``); None for a procedural sky.
        env_strength: environment strength.
        sun: give the procedural sky its sun disc (see :func:`blender_addon.relight_operator.add_environment`).
        device: Cycles device, ``"CPU"`` or ``"GPU"`` (falls back to the CPU).
        denoise: denoise the rendered frames (Cycles' OpenImageDenoise).
        save_blend: also save ``OUT/<name>.blend`` (asset, camera, orbit light, environment, Cycles,
            packed images; see the module docstring).

    Returns:
        The written files: ``point_NNNN.png`` per orbit frame, ``env_NNNN.png`` and the ``.blend``.

    Raises:
        FileNotFoundError: no ``<name>_*.exr`` maps in ``maps``.
        ValueError: ``frames < 0``, ``size < 8`` or ``samples < 1``.
    """
    if frames < 0 or size < 8 or samples < 1:
        raise ValueError(f"need frames >= 0, size >= 8 and samples >= 1, got {frames}, {size}, {samples}")
    out = Path(out)
    scene, obj, light = relit_scene(maps, name=name, frames=frames, size=size, distance=distance, exposure=exposure)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    render = {"device": device, "samples": samples, "denoise": denoise}
    if frames > 0:
        written += relight_operator.render_relit(scene, out, prefix="point_", **render)
    light.hide_render = True
    relight_operator.add_environment(scene, hdr_path=hdr, strength=env_strength, sun=sun)
    if frames > 0:
        written += relight_operator.render_relit(scene, out, frames=[scene.frame_start], prefix="env_", **render)
    light.hide_render = False
    if save_blend:
        _prepare_for_artists(scene, samples)
        written.append(_save_blend(out / f"{name or obj.name}.blend"))
    return written


@dataclass(frozen=True)
class RelightJob:
    """One asset of :func:`relight_batch`: its maps, output folder, name prefix and whether to save a ``.blend``.

    Attributes:
        maps: as :func:`relight_maps`'s ``maps``.
        out: as :func:`relight_maps`'s ``out``.
        name: as :func:`relight_maps`'s ``name``.
        save_blend: as :func:`relight_maps`'s ``save_blend``.
    """

    maps: Path
    out: Path
    name: str = ""
    save_blend: bool = False


def relight_batch(jobs: Iterable[RelightJob], **settings) -> Iterator[list[Path]]:
    """:func:`relight_maps` of each job in turn, in this one Blender session; yields each job's written files.

    One session for many assets spares each a process and bpy's start-up; every job begins from an
    empty session (:func:`relit_scene`), so its files are those of :func:`relight_maps` in a
    process of its own (tested).

    Args:
        jobs: the assets.
        **settings: :func:`relight_maps`'s keyword arguments other than ``name`` and ``save_blend``
            (``frames``, ``size``, ``samples``, ``denoise``, ...), shared by every job.

    Yields:
        Each job's written files, as :func:`relight_maps` returns them, once the job is done.
    """
    for job in jobs:
        yield relight_maps(job.maps, job.out, name=job.name, save_blend=job.save_blend, **settings)


def relit_scene(
    maps: str | os.PathLike, *, name: str = "", frames: int = 8, size: int = SIZE, distance: float = 1.0,
    exposure: float = 1.0,
):  # fmt: skip
    """Empty the session, import the maps as the camera-parented asset, size the frame, add the orbit light.

    Args:
        maps: as :func:`relight_maps`.
        name: as :func:`relight_maps`.
        frames: orbit frames (0 still keyframes a one-frame orbit, kept in a saved ``.blend``).
        size: longest side of the frame in pixels.
        distance: asset plane distance from the camera in metres.
        exposure: point-light power scale.

    Returns:
        ``(scene, asset object, point light object)``; nothing rendered yet.

    Raises:
        FileNotFoundError: no ``<name>_*.exr`` maps in ``maps``.
    """
    maps = Path(maps)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    files = sorted(maps.glob(f"{name}_*.exr")) if name else [maps]
    if name and not files:
        raise FileNotFoundError(f"{maps}: no {name}_*.exr maps")
    obj = pbr_import.import_pbr_maps(bpy.context, files, pbr_import.ImportOptions(distance=distance), name=name or None)
    scale = size / max(scene.render.resolution_x, scene.render.resolution_y)
    scene.render.resolution_x = max(round(scene.render.resolution_x * scale), 8)
    scene.render.resolution_y = max(round(scene.render.resolution_y * scale), 8)
    scene.render.film_transparent = False
    # Orbit in front of the asset's centre (its +z faces the camera); kept in the .blend even without frames.
    radius = height = 0.6 * distance
    power = point_light_power(radius, height, exposure)
    light = relight_operator.add_point_light_orbit(scene, _asset_centre(scene, obj), radius=radius, height=height,
                                                   frames=max(frames, 1), energy=power)  # fmt: skip
    return scene, obj, light


def _asset_centre(scene, obj):
    """An empty at the centre of ``obj``'s bounding box, with ``obj``'s axes (a child of ``obj``).

    The orbit circles its target's origin, and a relief mesh's origin is the camera (its object
    frame is the camera frame): around the mesh itself the light would circle the camera, about
    twice as far from the asset as :func:`point_light_power` assumes and closer to the view axis.
    """
    empty = bpy.data.objects.new(ASSET_CENTRE_NAME, None)
    scene.collection.objects.link(empty)
    empty.parent = obj
    empty.location = sum((Vector(corner) for corner in obj.bound_box), Vector()) / 8.0
    empty.empty_display_size = 0.05
    bpy.context.view_layer.update()
    return empty


def _prepare_for_artists(scene, samples: int) -> None:
    """Cycles (denoised, at least :data:`ARTIST_SAMPLES`), the first frame, every image packed.

    Images that are files (an HDR environment; the import's maps are packed already) are packed
    into the ``.blend``; image sequences cannot be packed and stay on disk.
    """
    scene.render.engine = "CYCLES"
    scene.cycles.samples = max(samples, ARTIST_SAMPLES)
    scene.cycles.use_adaptive_sampling = True
    scene.cycles.use_denoising = True
    scene.cycles.denoising_prefilter = "ACCURATE"  # Blender's default for final renders (the frames used FAST)
    scene.cycles.use_preview_denoising = True
    scene.frame_set(scene.frame_start)
    for image in bpy.data.images:
        if image.type == "IMAGE" and image.source in {"FILE", "GENERATED"} and image.packed_file is None:
            image.pack()


def _save_blend(path: Path) -> Path:
    """Save a copy of the session as ``path`` atomically; returns ``path``.

    The copy is saved under its final name into a staging folder beside ``path`` and moved into
    place (:func:`pbrdf.io.atomic.atomic_folder`, merging into the parent folder): Blender logs
    ``Saved copy as "<file name>"``, which thus names the final file and never a temporary one.
    """
    with atomic_folder(path.parent, merge=True) as staging:
        bpy.ops.wm.save_as_mainfile(filepath=str(staging / path.name), compress=True, copy=True)
    return path
