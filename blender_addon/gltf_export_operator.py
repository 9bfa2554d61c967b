"""The "Export glTF" button: the active reconstruction's maps as one glTF 2.0 asset (.glb) for any engine.

``pdir.export_gltf`` runs ``headless/export_gltf.py`` (``python -m headless.export_gltf``) in the
project's Python, the one the reconstruction uses
(:func:`.reconstruct_operator.reconstruction_python`: Blender's own Python has neither OpenEXR
nor Pillow), on the map files the active object was imported from (its ``pdir_source``, written
by :func:`.pbr_import.import_pbr_maps` and so by "Reconstruct Capture"). The file holds what
``headless/infer.py --gltf`` writes (:mod:`pbrdf.data.gltf_asset`): the relief mesh when the
object was imported with its depth map, else a card; base colour with the mask as alpha,
metallic-roughness, a tangent-space normal map and the capture camera. The export runs
synchronously (its times: docs/measurements/gltf.md); a failure is one ``ERROR`` report line and
``{'CANCELLED'}``, with nothing written. Sequences are refused (``infer.py --gltf`` writes one .glb per frame).
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import bpy
from bpy.props import StringProperty
from bpy_extras.io_utils import ExportHelper

from pbrdf.io.errors import one_line

from .core import reconstruct_job
from .reconstruct_operator import reconstruction_python
from .ui import SidebarPanel

__all__ = ["CLASSES", "PDIR_OT_export_gltf", "PDIR_PT_export_gltf", "export_command", "source_files"]

#: The module run with ``python -m``.
SCRIPT_MODULE = "headless.export_gltf"
_REPO_ROOT = reconstruct_job.repository_root(Path(__file__).resolve().parent)
_TIMEOUT_S = 600  # a full-frame relief takes seconds; a hung Python must not hold Blender for ever


def source_files(obj) -> list[Path]:
    """The map files an imported reconstruction came from; ValueError (one line) when it cannot be exported."""
    if obj is None or "pdir_source" not in obj:
        raise ValueError("select an object made by Import PBR Maps or Reconstruct Capture")
    if int(obj.get("pdir_frames", 1)) > 1:
        raise ValueError(f"{obj.name}: a sequence; headless/infer.py --gltf writes one .glb per frame")
    files = [Path(p) for p in str(obj["pdir_source"]).split(", ")]
    missing = [p for p in files if not p.is_file()]
    if missing:
        raise ValueError(f"{missing[0]}: the map file {obj.name!r} was imported from is gone")
    return files


def export_command(python: str | os.PathLike, files: list[Path], out: str | os.PathLike, *, card: bool) -> list[str]:
    """The command that writes ``out`` from the map ``files``.

    Example:
        >>> " ".join(export_command("py", [Path("a_normal.exr")], "a.glb", card=True))
        'py -m headless.export_gltf --input a_normal.exr --out a.glb --quiet --card'
    """
    cmd = [str(python), "-m", SCRIPT_MODULE, "--input", *(str(f) for f in files), "--out", str(out), "--quiet"]
    return cmd + (["--card"] if card else [])


def _run(cmd: list[str]) -> str:
    """Run the export; its summary line, or ValueError with the script's error line."""
    env = dict(os.environ)
    if _REPO_ROOT is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(_REPO_ROOT), env.get("PYTHONPATH", "")]))
    proc = subprocess.run(cmd, cwd=_REPO_ROOT, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                          encoding="utf-8", errors="replace", timeout=_TIMEOUT_S, check=False)  # fmt: skip
    if proc.returncode:
        raise ValueError(reconstruct_job.error_line(proc.stderr.splitlines(), proc.returncode))
    return proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else "wrote the asset"


class PDIR_OT_export_gltf(bpy.types.Operator, ExportHelper):
    """Export the active reconstruction as one glTF 2.0 file (.glb): mesh, PBR textures, normal map, camera."""

    bl_idname = "pdir.export_gltf"
    bl_label = "Export glTF Asset"
    filename_ext = ".glb"
    filter_glob: StringProperty(default="*.glb", options={"HIDDEN"})

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        """An active object made by the PBR import (or the reconstruction)."""
        obj = context.active_object
        return obj is not None and "pdir_source" in obj

    def invoke(self, context: bpy.types.Context, event) -> set[str]:
        """Propose ``<object name>.glb`` beside its maps."""
        if not self.filepath:
            first = str(context.active_object["pdir_source"]).split(", ")[0]
            self.filepath = str(Path(first).parent / f"{context.active_object.name}.glb")
        return ExportHelper.invoke(self, context, event)

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Run the export in the project's Python; one report line either way."""
        obj = context.active_object
        try:
            files = source_files(obj)
            card = "depth" not in str(obj.get("pdir_maps", "")).split(",")
            out = Path(bpy.path.abspath(self.filepath))
            line = _run(export_command(reconstruction_python(context), files, out, card=card))
        except (ValueError, OSError, RuntimeError, subprocess.TimeoutExpired) as e:
            self.report({"ERROR"}, one_line(f"glTF export of {getattr(obj, 'name', 'nothing')} failed: {e}"))
            return {"CANCELLED"}
        self.report({"INFO"}, one_line(line))
        return {"FINISHED"}


class PDIR_PT_export_gltf(SidebarPanel, bpy.types.Panel):
    """The export button, inside the "Reconstruct Capture" panel."""

    bl_label = "Export glTF"
    bl_idname = "PDIR_PT_export_gltf"
    bl_parent_id = "PDIR_PT_reconstruct"

    def draw(self, context: bpy.types.Context) -> None:
        """The button (greyed out without a reconstructed object selected)."""
        self.layout.operator(PDIR_OT_export_gltf.bl_idname, icon="EXPORT")
        if not PDIR_OT_export_gltf.poll(context):
            self.layout.label(text="Select a reconstructed (imported) object", icon="INFO")


CLASSES = (PDIR_OT_export_gltf, PDIR_PT_export_gltf)
