"""The "Reconstruct Capture" button: a capture folder -> the network's maps -> a relightable asset.

``pdir.reconstruct_capture`` runs ``headless/infer.py`` on a capture folder in the project's
Python (a subprocess: torch never loads into Blender; which Python and where the script comes
from is :mod:`.core.reconstruct_job`'s rule, the same as the polarized render's), then imports
the predicted maps with :func:`.pbr_import.import_pbr_maps`: a relief mesh from
``<name>_depth.exr`` (default) or a flat card, with a Principled BSDF reading the maps.

Invoked from the panel it runs modal: a window-manager timer polls the process, the cursor shows
the progress and the status bar the stage; ESC or the panel's Cancel button stops the process
and removes what it wrote. Called as ``bpy.ops.pdir.reconstruct_capture(...)`` from a script
(or without a window, as in ``blender -b``) it runs synchronously in :meth:`execute`. Every
failure (bad folder, no suitable Python, the script's ``error: ...`` line, missing maps, the
import) is one ``ERROR`` report line and ``{'CANCELLED'}``.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import bpy
from bpy.app.handlers import persistent
from bpy.props import BoolProperty, EnumProperty, FloatProperty, PointerProperty, StringProperty

from pbrdf.io.errors import one_line

from . import prefs
from .core import reconstruct_job
from .pbr_import import ImportOptions, PBRImportWarning, import_pbr_maps
from .render_operator import PYTHON_ENV, external_python
from .ui import SidebarPanel

__all__ = [
    "CLASSES",
    "PDIR_OT_reconstruct_cancel",
    "PDIR_OT_reconstruct_capture",
    "PDIR_PT_reconstruct",
    "PDIR_ReconstructSettings",
    "reconstruction_python",
    "running_job",
]

_REPO_ROOT = reconstruct_job.repository_root(Path(__file__).resolve().parent)
_MESH_ITEMS = (
    ("RELIEF", "Relief", "A mesh displaced by the depth integrated from the predicted normals"),
    ("CARD", "Card", "A flat card facing the camera (no depth map; faster)"),
)
# The one job in flight (modal), and whether its cancellation was asked for from the panel.
_job: reconstruct_job.ReconstructJob | None = None
_cancel_requested = False


def running_job() -> reconstruct_job.ReconstructJob | None:
    """The reconstruction running in the background (modal), if any."""
    return _job


def reconstruction_python(context: bpy.types.Context | None = None) -> Path:
    """The Python that runs the network: the preference or ``$PDIR_PYTHON``, else Blender's own when it can.

    Raises:
        RuntimeError: none can (the message says how to set one); ValueError: ``$PDIR_PYTHON`` is no file.
    """
    python = external_python(context)
    if python is not None:
        return python
    if prefs.importable(*reconstruct_job.PACKAGES):
        return Path(sys.executable)
    missing = [n for n in reconstruct_job.PACKAGES if not prefs.importable(n)]
    raise RuntimeError(
        f"Reconstruction runs the network in the project's Python (Blender's lacks {', '.join(missing)}): set its "
        f".venv/bin/python in the add-on preferences or ${PYTHON_ENV}"
    )


def _abspath(path: str) -> str:
    return bpy.path.abspath(path.strip()) if path.strip() else ""


def _new_job(op: PDIR_OT_reconstruct_capture, context: bpy.types.Context) -> reconstruct_job.ReconstructJob:
    """The job for the operator's settings (ValueError / RuntimeError with one line when they cannot work)."""
    capture = reconstruct_job.check_capture_folder(_abspath(op.capture_dir))
    out = _abspath(op.output_dir) or reconstruct_job.default_output_dir(capture)
    checkpoint = _abspath(op.checkpoint) or None
    if checkpoint is not None and not Path(checkpoint).is_file():
        raise ValueError(f"{checkpoint}: no such checkpoint file (leave it empty for the shipped model)")
    return reconstruct_job.ReconstructJob(
        reconstruction_python(context), capture, out, card=op.mesh == "CARD", checkpoint=checkpoint,
        repo_root=_REPO_ROOT, distance=op.distance or None, refine=op.refine,
    )  # fmt: skip


def _modal_possible(context: bpy.types.Context) -> bool:
    """Whether timer events will come: a window and an event loop (not ``blender -b`` or the bpy wheel)."""
    return context.window is not None and not bpy.app.background


def _start_job(op: PDIR_OT_reconstruct_capture, context: bpy.types.Context):
    """Check the settings and start the process; None (after one ERROR report) when that fails."""
    try:
        job = _new_job(op, context)
        job.start()
    except (ValueError, OSError, RuntimeError) as e:
        op.report({"ERROR"}, one_line(e))
        return None
    return job


def _finish(op: PDIR_OT_reconstruct_capture, context: bpy.types.Context, job) -> set[str]:
    """Report a failed or cancelled job, or import its maps; the operator's return value."""
    if job.state == "cancelled":
        op.report({"WARNING"}, f"Reconstruction of {job.name} cancelled; nothing written")
        return {"CANCELLED"}
    if job.state != "done":
        op.report({"ERROR"}, one_line(f"Reconstruction of {job.name} failed: {job.error}"))
        return {"CANCELLED"}
    for line in reconstruct_job.warning_lines(job.stderr):  # the capture's warnings, as a terminal shows them
        op.report({"WARNING"}, one_line(line))
    relief = not job.card
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PBRImportWarning)
        try:
            options = ImportOptions(use_depth=relief, normal_space="OBJECT" if relief else "TANGENT")
            obj = import_pbr_maps(context, job.outputs, options, name=job.name)
        except (ValueError, OSError) as e:
            op.report({"ERROR"}, one_line(f"Reconstructed {job.name}, but the import failed: {e}"))
            return {"CANCELLED"}
    for w in caught:
        if issubclass(w.category, PBRImportWarning):
            op.report({"WARNING"}, one_line(w.message))
    obj["pdir_capture"] = str(job.capture)
    what = f"relief mesh, {len(obj.data.vertices)} vertices" if relief else "card"
    op.report({"INFO"}, f"Reconstructed {job.name} in {job.elapsed:.0f} s: {obj.name!r} ({what}); maps in {job.out}")
    return {"FINISHED"}


class _ReconstructProperties:
    """The reconstruction's settings, declared once for the panel's property group and the operator."""

    capture_dir: StringProperty(
        name="Capture", description="Capture folder: raw HDR brackets plus capture.json", subtype="DIR_PATH"
    )
    output_dir: StringProperty(
        name="Output",
        description="Folder for the predicted maps (empty: '<capture>_reconstruction' beside the capture folder)",
        subtype="DIR_PATH",
    )
    mesh: EnumProperty(name="Mesh", description="What the maps are imported as", items=_MESH_ITEMS, default="RELIEF")
    checkpoint: StringProperty(
        name="Model", description="A model.pt checkpoint (empty: the shipped model)", subtype="FILE_PATH"
    )
    distance: FloatProperty(
        name="Distance (m)", min=0.0, max=3.0, default=0.0, precision=3,
        description="Object distance from the camera in metres (a tape measure; 0: capture.json's distance_m, "
        "else 0.75 m and a lighting-aware model's albedo is relative)",
    )  # fmt: skip
    refine: BoolProperty(
        name="Refine against the capture",
        description="Fit each object's albedo scale so the re-rendered maps match the capture (about 1 s more). "
        "Refines when the distance is known (Distance above, else capture.json's distance_m) and the capture is "
        "calibrated; otherwise the network's maps are kept",
        default=True,
    )


class PDIR_ReconstructSettings(_ReconstructProperties, bpy.types.PropertyGroup):
    """The panel's reconstruction settings (``scene.pdir_reconstruct``), passed to the operator."""


class PDIR_OT_reconstruct_capture(_ReconstructProperties, bpy.types.Operator):
    """Predict normal, albedo, roughness, metallic and depth from a capture folder and import them as an asset."""

    bl_idname = "pdir.reconstruct_capture"
    bl_label = "Reconstruct Capture"
    bl_options = {"REGISTER", "UNDO"}

    _timer = None

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        """One reconstruction at a time."""
        return _job is None

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Reconstruct synchronously (scripts, background mode), then import."""
        job = _start_job(self, context)
        if job is None:
            return {"CANCELLED"}
        try:
            job.wait()
        except BaseException:  # KeyboardInterrupt in a script: stop the process, leave nothing behind
            job.cancel()
            raise
        return _finish(self, context, job)

    def invoke(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        """Start the process and poll it from a timer (ESC or the panel's Cancel stops it)."""
        global _job, _cancel_requested
        if not _modal_possible(context):
            return self.execute(context)
        job = _start_job(self, context)
        if job is None:
            return {"CANCELLED"}
        _job, _cancel_requested = job, False
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 100)
        self._status(context, f"Reconstructing {job.name}: starting (ESC to cancel)")
        return {"RUNNING_MODAL"}

    def modal(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        """Poll the process on timer events; cancel on ESC or the panel's Cancel button."""
        job = _job
        if job is None:  # cancelled from outside (a file load)
            self._end(context)
            return {"CANCELLED"}
        if event.type == "ESC" or _cancel_requested:
            job.cancel()
            self._end(context)
            return _finish(self, context, job)
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if job.poll() == "running":
            context.window_manager.progress_update(int(round(100 * job.fraction)))
            percent = f"{100 * job.fraction:.0f} %"
            self._status(context, f"Reconstructing {job.name}: {percent} - {job.stage} (ESC to cancel)")
            return {"RUNNING_MODAL"}
        self._end(context)
        return _finish(self, context, job)

    def cancel(self, context: bpy.types.Context) -> None:
        """Blender ends the operator (window closed, file loaded): stop the process."""
        if _job is not None:
            _job.cancel()
        self._end(context)

    def _status(self, context: bpy.types.Context, text: str | None) -> None:
        if context.workspace is not None:
            context.workspace.status_text_set(text)
        for window in context.window_manager.windows:
            for area in window.screen.areas:
                if area.type == "VIEW_3D":
                    area.tag_redraw()

    def _end(self, context: bpy.types.Context) -> None:
        global _job, _cancel_requested
        _job, _cancel_requested = None, False
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        self._status(context, None)


class PDIR_OT_reconstruct_cancel(bpy.types.Operator):
    """Stop the running reconstruction and remove what it wrote."""

    bl_idname = "pdir.reconstruct_cancel"
    bl_label = "Cancel Reconstruction"

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        """Only while a reconstruction runs."""
        return _job is not None

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Ask the modal operator to stop at its next event."""
        global _cancel_requested
        _cancel_requested = True
        return {"FINISHED"}


class PDIR_PT_reconstruct(SidebarPanel, bpy.types.Panel):
    """Reconstruct a capture folder with the network and import the maps."""

    bl_label = "Reconstruct Capture"
    bl_idname = "PDIR_PT_reconstruct"
    bl_parent_id = "PDIR_PT_main"
    bl_order = 3  # registered before "Import & Relight" (also 3), so drawn above it

    def draw(self, context: bpy.types.Context) -> None:
        """Settings and the button, or the running job's progress and Cancel."""
        layout = self.layout
        job = _job
        if job is not None:
            layout.label(text=f"{job.name}: {100 * job.fraction:.0f} %", icon="TIME")
            layout.label(text=job.stage)
            layout.operator(PDIR_OT_reconstruct_cancel.bl_idname, icon="CANCEL")
            return
        s = getattr(context.scene, "pdir_reconstruct", None)
        if s is None:
            return
        layout.prop(s, "capture_dir")
        layout.prop(s, "output_dir")
        layout.prop(s, "mesh", expand=True)
        layout.prop(s, "checkpoint")
        layout.prop(s, "distance")
        layout.prop(s, "refine")
        row = layout.row()
        row.enabled = bool(s.capture_dir.strip())
        op = row.operator(PDIR_OT_reconstruct_capture.bl_idname, icon="SHADING_TEXTURE")
        op.capture_dir, op.output_dir, op.mesh, op.checkpoint = s.capture_dir, s.output_dir, s.mesh, s.checkpoint
        op.distance = s.distance
        op.refine = s.refine
        try:
            reconstruction_python(context)
        except (RuntimeError, ValueError) as e:
            layout.label(text=one_line(e), icon="ERROR")


@persistent
def _cancel_on_load(*_args) -> None:
    """A file load ends modal operators: stop the process first and remove what it wrote."""
    global _job
    if _job is not None:
        _job.cancel()
        _job = None


CLASSES = (PDIR_ReconstructSettings, PDIR_OT_reconstruct_capture, PDIR_OT_reconstruct_cancel, PDIR_PT_reconstruct)


def register_extra() -> None:
    """Attach the settings to every scene as ``scene.pdir_reconstruct``; stop a running job on file load."""
    bpy.types.Scene.pdir_reconstruct = PointerProperty(type=PDIR_ReconstructSettings)
    if _cancel_on_load not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_cancel_on_load)


def unregister_extra() -> None:
    """Stop a running job, remove the handler and ``scene.pdir_reconstruct``."""
    _cancel_on_load()
    if _cancel_on_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_cancel_on_load)
    del bpy.types.Scene.pdir_reconstruct
