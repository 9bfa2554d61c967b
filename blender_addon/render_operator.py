"""The "Export and Render" panel: operators ``pdir.export_scene`` and ``pdir.render_polarized``.

:func:`render_polarized` exports the scene (:func:`.export_spec.export_scene`) and renders its
polarized capture with Mitsuba along one of two routes:

- In Blender's Python, when mitsuba, drjit, scipy and trimesh import there (install them
  with ``<blender python> -m pip install mitsuba scipy trimesh``): the exported spec goes
  through :func:`.core.generate.render_sample` in-process.
- Otherwise through an external Python that has them (the add-on preference "Python with
  Mitsuba", or the environment variable ``PDIR_PYTHON``, e.g. the project's
  ``.venv/bin/python``): ``python -m headless.render --scene scene.json --npz ...`` in a
  subprocess (run from the repository when the add-on sits in a checkout; otherwise that
  Python needs the project installed, ``pip install -e .``), then the sample's ``.npz`` is
  read back (numpy only).
- Neither: the operator fails with a one-line how-to (:func:`how_to_get_mitsuba`).

Both routes give the same sample for the same seeds. :func:`load_images` turns the sample into
float images (:data:`IMAGE_NAMES`): the nine maps ``PDIR R_unpol`` ... ``PDIR B_CP`` (grey),
the Stokes images ``PDIR S0`` ... ``PDIR S3`` (RGB = the three colour channels) and
``PDIR mask``.

Convention (images):
    Row 0 of a sample is the top of the image, Blender's pixel row 0 is the bottom: rows are
    flipped on the way in, so ``PDIR S1`` read back with ``pixels.foreach_get`` and flipped is
    ``sample["stokes"][..., :, 1]``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np
from bpy.props import BoolProperty, IntProperty, PointerProperty, StringProperty
from numpy.typing import NDArray

from . import prefs
from .core.spec import SceneSpec
from .export_spec import export_scene
from .ui import SidebarPanel

__all__ = [
    "CLASSES",
    "IMAGE_NAMES",
    "INPROCESS_PACKAGES",
    "PYTHON_ENV",
    "PDIR_ExportSettings",
    "PDIR_OT_export_scene",
    "PDIR_OT_render_polarized",
    "PDIR_PT_export",
    "external_python",
    "how_to_get_mitsuba",
    "load_images",
    "render_polarized",
]

_MAP_NAMES = ("R_unpol", "G_unpol", "B_unpol", "R_LP", "G_LP", "B_LP", "R_CP", "G_CP", "B_CP")
#: Names of the images :func:`load_images` creates.
IMAGE_NAMES = (*(f"PDIR {n}" for n in _MAP_NAMES), *(f"PDIR S{k}" for k in range(4)), "PDIR mask")
#: Python packages the in-process render needs in Blender's Python.
INPROCESS_PACKAGES = ("mitsuba", "drjit", "scipy", "trimesh")
#: Environment variable naming an external Python with mitsuba (after the add-on preference).
PYTHON_ENV = "PDIR_PYTHON"
_REPO_ROOT = Path(__file__).resolve().parents[1]


def external_python(context: bpy.types.Context | None = None) -> Path | None:
    """The external Python with mitsuba: the add-on preference, else ``$PDIR_PYTHON``; None if unset."""
    try:
        path = prefs.external_python(context)
    except AttributeError:  # no preferences in this context
        path = None
    if path is None and os.environ.get(PYTHON_ENV, "").strip():
        env = Path(os.environ[PYTHON_ENV].strip())
        if not env.is_file():
            raise ValueError(f"{PYTHON_ENV}={env}: no such file")
        path = env
    return path


def how_to_get_mitsuba() -> str:
    """One line saying how to make the polarized render available."""
    missing = [n for n in INPROCESS_PACKAGES if not prefs.importable(n)]
    return (
        f"Mitsuba rendering needs {', '.join(missing)}: run '{sys.executable} -m pip install {' '.join(missing)}', "
        f"or set a Python that has them (the project's .venv/bin/python) in the add-on preferences or ${PYTHON_ENV}"
    )


def _render_subprocess(python: Path, spec_path: Path, out: Path, resolution: int, spp: int, noise: bool) -> dict:
    if out.exists():
        if not ((out / "manifest.json").exists() or (out / "samples").exists() or not any(out.iterdir())):
            raise ValueError(f"{out}: exists and is not a render folder of the add-on; choose another output folder")
        shutil.rmtree(out)
    spec = SceneSpec.load(spec_path)
    cmd = [str(python), "-m", "headless.render", "--scene", str(spec_path), "--out", str(out), "--count", "1",
           "--seed", str(spec.seed), "--resolution", str(resolution), "--spp", str(spp), "--keep-stokes", "--npz",
           "--quiet"]  # fmt: skip
    if not noise:
        cmd.append("--no-noise")
    cwd = _REPO_ROOT if (_REPO_ROOT / "headless" / "render.py").is_file() else None
    env = dict(os.environ)
    if cwd is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(cwd), env.get("PYTHONPATH", "")]))
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        lines = [ln.strip() for ln in (proc.stderr + "\n" + proc.stdout).splitlines() if ln.strip()]
        why = [ln for ln in lines if ln.startswith(("error:", "sample 0:"))] or lines[-1:] or ["no output"]
        raise RuntimeError(f"external render failed ({python}): {why[0]}")
    with np.load(out / "arrays" / "000000.npz") as data:
        return {k: data[k] for k in data.files if k not in ("map_names", "metadata")}


def render_polarized(
    scene: bpy.types.Scene,
    out_dir: str | os.PathLike,
    *,
    resolution: int = 128,
    spp: int = 16,
    noise: bool = True,
    route: str = "auto",
    context: bpy.types.Context | None = None,
) -> tuple[dict[str, NDArray], str]:
    """Export ``scene`` and render its polarized capture.

    Args:
        scene: the scene (a rig and objects fully in the camera view).
        out_dir: output folder: ``scene/`` (the export) and, for the subprocess route,
            ``polarized/`` (the dataset sample and its ``.npz``).
        resolution: sample size R (maps R x R).
        spp: samples per pixel per colour pass.
        noise: simulate sensor noise.
        route: ``"auto"``, ``"inprocess"`` or ``"subprocess"`` (see the module docstring).
        context: for the add-on preferences.

    Returns:
        ``(sample, route)``: the dataset sample (``maps (R, R, 9)``, ``stokes (R, R, 3, 4)``,
        ``mask (R, R)``, ground truth, ...) and the route taken, ``"inprocess"`` or
        ``"subprocess"``.

    Raises:
        RuntimeError: no way to run Mitsuba (the message says how to get one) or a failed
            external render.
        ValueError: an invalid scene (objects out of view, ...).
    """
    out = Path(out_dir)
    spec = export_scene(scene, out / "scene", xml=False)
    if prefs.importable("trimesh"):  # else the external Python checks it (meshes need trimesh)
        spec.validate()
    if route == "auto":
        if prefs.importable(*INPROCESS_PACKAGES):
            route = "inprocess"
        elif external_python(context) is not None:
            route = "subprocess"
        else:
            raise RuntimeError(how_to_get_mitsuba())
    if route == "inprocess":
        from .core import generate, render, scenegen  # noqa: PLC0415

        settings = render.RenderSettings(resolution=resolution, spp=spp, noise=noise)
        sample, _, _ = generate.render_sample(
            spec, settings, sample_seed=scenegen.sample_seed(spec.seed, 0), noise=noise, keep_stokes=True
        )
        return sample, route
    if route == "subprocess":
        python = external_python(context)
        if python is None:
            raise RuntimeError(how_to_get_mitsuba())
        return _render_subprocess(
            python, out / "scene" / "scene.json", out / "polarized", resolution, spp, noise
        ), route
    raise ValueError(f"route must be 'auto', 'inprocess' or 'subprocess', got {route!r}")


def _image(name: str, rgb: NDArray) -> bpy.types.Image:
    """A float image ``name`` (Non-Color) holding ``rgb (H, W, 3)``, row 0 at the top."""
    h, w = rgb.shape[:2]
    img = bpy.data.images.get(name)
    if img is not None and (tuple(img.size) != (w, h) or not img.is_float):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = rgb[::-1]  # Blender's pixel row 0 is the bottom
    img.pixels.foreach_set(rgba.ravel())
    img.update()
    img.pack()  # generated pixels would be lost on save otherwise
    return img


def load_images(sample: dict[str, NDArray]) -> list[bpy.types.Image]:
    """Create (or update) the images of :data:`IMAGE_NAMES` from a rendered sample.

    Args:
        sample: ``maps (H, W, 9)`` -> one grey image per map; ``stokes (H, W, 3, 4)`` (optional)
            -> ``PDIR S0`` ... ``PDIR S3`` with the colour channels as RGB; ``mask (H, W)`` ->
            ``PDIR mask``.

    Returns:
        The float images (Non-Color, packed), in :data:`IMAGE_NAMES` order.
    """
    maps = np.asarray(sample["maps"], dtype=np.float32)
    out = [_image(f"PDIR {n}", np.repeat(maps[..., i : i + 1], 3, axis=-1)) for i, n in enumerate(_MAP_NAMES)]
    if "stokes" in sample:
        stokes = np.asarray(sample["stokes"], dtype=np.float32)
        out += [_image(f"PDIR S{k}", stokes[..., :, k]) for k in range(4)]
    mask = np.asarray(sample["mask"], dtype=np.float32)
    out.append(_image("PDIR mask", np.repeat(mask[..., None], 3, axis=-1)))
    return out


def _default_dir() -> str:
    return "//pdir_export" if bpy.data.filepath else str(Path(bpy.app.tempdir or "/tmp") / "pdir_export")


class PDIR_ExportSettings(bpy.types.PropertyGroup):
    """Settings of the export and polarized-render operators."""

    output_dir: StringProperty(
        name="Output", description="Folder for the exported scene and renders ('//' = next to the .blend file)",
        subtype="DIR_PATH", default="//pdir_export",
    )  # fmt: skip
    resolution: IntProperty(
        name="Resolution", description="Size of the rendered maps in pixels (even)", default=128, min=8, max=4096,
        step=2,
    )  # fmt: skip
    spp: IntProperty(name="Samples", description="Samples per pixel per colour pass", default=16, min=1, max=4096)
    noise: BoolProperty(name="Sensor Noise", description="Simulate the camera's sensor noise", default=True)


def _out_dir(context: bpy.types.Context) -> Path:
    settings = getattr(context.scene, "pdir_export", None)
    raw = settings.output_dir.strip() if settings is not None else ""
    if not raw or (raw.startswith("//") and not bpy.data.filepath):
        raw = _default_dir()
    return Path(bpy.path.abspath(raw))


class PDIR_OT_export_scene(bpy.types.Operator):
    """Export the scene to a scene spec (JSON), PLY meshes and a Mitsuba XML preview scene."""

    bl_idname = "pdir.export_scene"
    bl_label = "Export Scene"
    bl_options = {"REGISTER"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Export into the output folder of the panel."""
        out = _out_dir(context)
        warnings: list[str] = []
        try:
            spec = export_scene(context.scene, out, warnings=warnings)
        except (ValueError, OSError, RuntimeError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        for w in warnings[:5]:
            self.report({"WARNING"}, w)
        xml = " + scene.xml" if (out / "scene.xml").exists() else ""
        self.report({"INFO"}, f"Exported {len(spec.objects)} objects, {len(spec.lights)} lights to {out}{xml}")
        return {"FINISHED"}


class PDIR_OT_render_polarized(bpy.types.Operator):
    """Render the polarized capture of the scene with Mitsuba and load the nine maps and Stokes images."""

    bl_idname = "pdir.render_polarized"
    bl_label = "Render Polarized Capture"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Export, render (in-process or through the external Python) and create the images."""
        settings = getattr(context.scene, "pdir_export", None)
        resolution = settings.resolution if settings is not None else 128
        if resolution % 2:
            resolution += 1
        try:
            sample, route = render_polarized(
                context.scene, _out_dir(context), resolution=resolution,
                spp=settings.spp if settings is not None else 16,
                noise=settings.noise if settings is not None else True, context=context,
            )  # fmt: skip
            images = load_images(sample)
        except (ValueError, OSError, RuntimeError, NotImplementedError) as e:
            self.report({"ERROR"}, str(e).splitlines()[0] if str(e) else type(e).__name__)
            return {"CANCELLED"}
        where = "in Blender" if route == "inprocess" else "with the external Python"
        self.report({"INFO"}, f"Rendered {resolution}x{resolution} {where}: {len(images)} images 'PDIR ...'")
        return {"FINISHED"}


class PDIR_PT_export(SidebarPanel, bpy.types.Panel):
    """Export to Mitsuba and render the polarized capture."""

    bl_label = "Export and Render"
    bl_idname = "PDIR_PT_export"
    bl_parent_id = "PDIR_PT_main"
    bl_order = 2

    def draw(self, context: bpy.types.Context) -> None:
        """Settings and the two buttons."""
        layout = self.layout
        settings = getattr(context.scene, "pdir_export", None)
        if settings is not None:
            layout.prop(settings, "output_dir")
        layout.operator(PDIR_OT_export_scene.bl_idname, icon="EXPORT")
        if settings is not None:
            col = layout.column(align=True)
            col.prop(settings, "resolution")
            col.prop(settings, "spp")
            col.prop(settings, "noise")
        layout.operator(PDIR_OT_render_polarized.bl_idname, icon="RENDER_STILL")
        if not prefs.importable(*INPROCESS_PACKAGES):
            try:
                python = external_python(context)
            except ValueError as e:
                layout.label(text=str(e), icon="ERROR")
                return
            if python is None:
                layout.label(text="Mitsuba missing: see the add-on preferences", icon="ERROR")


CLASSES = (PDIR_ExportSettings, PDIR_OT_export_scene, PDIR_OT_render_polarized, PDIR_PT_export)


def register_extra() -> None:
    """Attach the settings to every scene as ``scene.pdir_export``."""
    bpy.types.Scene.pdir_export = PointerProperty(type=PDIR_ExportSettings)


def unregister_extra() -> None:
    """Remove ``scene.pdir_export``."""
    del bpy.types.Scene.pdir_export
