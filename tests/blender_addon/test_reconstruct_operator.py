"""Reconstruct Capture: ``pdir.reconstruct_capture`` (blender_addon/reconstruct_operator.py) and its bpy-free job
(blender_addon/core/reconstruct_job.py).

The bpy-free tests run a stand-in script through the real job (progress lines, staging folder,
cancel, one-line errors) and need neither bpy nor torch; the ``bpy`` tests run the real
``headless/infer.py`` on ``examples/capture`` through the operator (synchronous ``execute``, as
in background mode) and check the imported relief asset.
"""

import sys
import textwrap
import time
import types
from pathlib import Path

import numpy as np
import pytest

from blender_addon.core import reconstruct_job
from pbrdf.data.predictions import MAP_NAMES

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "capture"

# --------------------------------------------------------------------------- bpy-free helpers


def test_command_line_runs_the_infer_module_without_blend():
    cmd = reconstruct_job.command_line("/py", "/data/mug", "/out")
    expected = ["/py", "-m", "headless.infer", "--input", "/data/mug", "--out", "/out", "--quiet", "--progress-lines"]
    assert cmd == expected
    cmd = reconstruct_job.command_line("/py", "/data/mug", "/out", card=True, checkpoint="/m/model.pt")
    assert cmd[-3:] == ["--card", "--checkpoint", "/m/model.pt"] and "--blend" not in cmd
    assert "--checkpoint" not in reconstruct_job.command_line("/py", "c", "o", checkpoint="  ")
    # The module exists and takes every flag the add-on passes.
    from headless import infer

    args = infer.build_parser().parse_args(cmd[3:])
    assert (args.input, args.out, args.card, args.blend) == (Path("/data/mug"), Path("/out"), True, False)
    # The refine checkbox: on (the default) leaves infer.py's auto refinement (None), off passes --no-refine.
    assert infer.build_parser().parse_args(cmd[3:]).refine is None and "-refine" not in " ".join(cmd)
    off = reconstruct_job.command_line("/py", "/data/mug", "/out", refine=False)
    assert off[-1] == "--no-refine" and infer.build_parser().parse_args(off[3:]).refine is False


def test_parse_progress_and_the_time_estimate():
    assert reconstruct_job.parse_progress("progress: 0.35 predicting the maps") == (0.35, "predicting the maps")
    assert reconstruct_job.parse_progress("  progress:1 ") == (1.0, "")
    assert reconstruct_job.parse_progress("progress: -2 x") == (0.0, "x")
    for line in ("wrote 6 maps", "progress: nan x", "progress: soon", "progressive: 0.5", "warning: progress: 1"):
        assert reconstruct_job.parse_progress(line) is None, line
    f = [reconstruct_job.estimate_fraction(t) for t in (0, 1, 5, 20, 60, 1e9)]
    assert f[0] == 0 and all(a < b for a, b in zip(f[:-1], f[1:], strict=True))
    assert f[-1] <= reconstruct_job.MAX_ESTIMATE < 1


def test_error_line_is_the_scripts_error_or_its_last_line():
    assert reconstruct_job.error_line(["warning: a", "error: cap: no object found", ""], 2) == "cap: no object found"
    assert reconstruct_job.error_line(["Traceback (...)", "  File x", "KeyError: 'k'"], 1) == "KeyError: 'k'"
    line = reconstruct_job.error_line(["ModuleNotFoundError: No module named 'torch'"], 1)
    assert line.startswith("ModuleNotFoundError: No module named 'torch' - set a Python") and "\n" not in line
    assert "exit status -15" in reconstruct_job.error_line([], -15)


def test_capture_folder_checks_and_default_output(tmp_path):
    for path, match in [("", "choose a capture folder"), (tmp_path / "nope", "no such capture folder"),
                        (tmp_path, "not a capture folder")]:  # fmt: skip
        with pytest.raises(ValueError, match=match):
            reconstruct_job.check_capture_folder(path)
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match="not a folder"):
        reconstruct_job.check_capture_folder(tmp_path / "file")
    (tmp_path / "seq" / "0001").mkdir(parents=True)
    (tmp_path / "seq" / "0001" / "capture.json").write_text("{}")
    with pytest.raises(ValueError, match="seq: a sequence of capture folders; choose one of them"):
        reconstruct_job.check_capture_folder(tmp_path / "seq")
    assert reconstruct_job.check_capture_folder(EXAMPLE) == EXAMPLE.resolve()
    assert reconstruct_job.check_capture_folder(EXAMPLE / "capture.json") == EXAMPLE.resolve()
    assert reconstruct_job.default_output_dir(EXAMPLE) == ROOT / "examples" / "capture_reconstruction"
    assert reconstruct_job.repository_root(ROOT / "blender_addon") == ROOT
    assert reconstruct_job.repository_root(tmp_path / "addon") is None  # an installed zip: no repository


def test_find_outputs_names_the_missing_maps(tmp_path):
    for kind in ("normal", "albedo", "roughness", "metallic", "mask"):
        (tmp_path / f"cap_{kind}.exr").write_bytes(b"")
    card = reconstruct_job.find_outputs(tmp_path, "cap", card=True)
    assert list(card) == ["normal", "albedo", "roughness", "metallic", "mask"]
    with pytest.raises(FileNotFoundError, match=r"^the reconstruction wrote no cap_depth.exr in "):
        reconstruct_job.find_outputs(tmp_path, "cap")


# A stand-in for headless/infer.py: what it does comes from the capture folder's mode.txt.
STAND_IN = textwrap.dedent(
    """
    import argparse, pathlib, sys, time
    p = argparse.ArgumentParser()
    for flag in ("--input", "--out", "--checkpoint"):
        p.add_argument(flag)
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--progress-lines", action="store_true")
    p.add_argument("--card", action="store_true")
    a = p.parse_args()
    cap, out = pathlib.Path(a.input), pathlib.Path(a.out)
    mode = (cap / "mode.txt").read_text().strip()
    if not mode.startswith("silent"):
        print("progress: 0.40 predicting the maps", flush=True)
    if mode == "warn":
        print("warning: " + str(cap) + ": no distance_m; 0.75 m assumed", file=sys.stderr)
        print("warning: " + str(cap) + ": no distance_m; 0.75 m assumed", file=sys.stderr)
    if mode == "fail":
        print("warning: something", file=sys.stderr)
        print("error: " + str(cap) + ": nothing usable", file=sys.stderr)
        sys.exit(2)
    kinds = ["normal", "albedo", "roughness", "metallic", "mask"] + ([] if a.card else ["depth"])
    if mode == "partial":
        kinds = kinds[:2]
    for kind in kinds:
        (out / f"{cap.name}_{kind}.exr").write_text(kind)
        (out / f"{cap.name}_{kind}.png").write_text(kind)
        if mode.endswith("slow"):
            time.sleep(60)
    print("wrote", len(kinds), "maps")
    """
)


def _stand_in(tmp_path, mode: str, name: str = "cap") -> tuple[Path, Path]:
    """``(capture folder, folder holding the stand-in module)``."""
    repo = tmp_path / "repo"
    repo.mkdir(exist_ok=True)
    (repo / "stand_in.py").write_text(STAND_IN)
    cap = tmp_path / name
    cap.mkdir()
    (cap / "capture.json").write_text("{}")
    (cap / "mode.txt").write_text(mode)
    return cap, repo


def _job(tmp_path, mode: str, out: Path, **kw) -> reconstruct_job.ReconstructJob:
    cap, repo = _stand_in(tmp_path, mode)
    return reconstruct_job.ReconstructJob(sys.executable, cap, out, repo_root=repo, module="stand_in", **kw)


def test_job_moves_the_maps_into_place_and_reports_progress(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "other_file.txt").write_text("kept")
    (out / "cap_depth.exr").write_text("old relief")
    job = _job(tmp_path, "ok", out)
    job.start()
    assert job.command()[1:3] == ["-m", "stand_in"] and "--blend" not in job.command()
    assert job.wait(poll_seconds=0.01) == "done", job.error
    assert job.stdout == ["progress: 0.40 predicting the maps", "wrote 6 maps"]
    assert (job.fraction, job.stage) == (1.0, "done")
    took = job.elapsed
    time.sleep(0.02)
    assert job.elapsed == took > 0  # the run's duration, not the time since
    assert job.outputs == reconstruct_job.expected_outputs(out, "cap") and job.outputs["depth"].read_text() == "depth"
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["other_file.txt"] + [f"cap_{k}.{e}" for k in MAP_NAMES for e in ("exr", "png")]
    )  # the staging folder is gone
    (tmp_path / "again").mkdir()
    card = _job(tmp_path / "again", "ok", out, card=True)
    card.start()
    assert card.wait() == "done" and not (out / "cap_depth.exr").exists()  # no stale relief beside a card


def test_job_failure_is_the_scripts_error_line_and_leaves_nothing(tmp_path):
    out = tmp_path / "new" / "out"
    job = _job(tmp_path, "fail", out)
    job.start()
    assert job.wait() == "failed"
    assert job.error == f"{tmp_path / 'cap'}: nothing usable"
    assert not out.exists()  # the job made it, and removes it again
    (tmp_path / "again").mkdir()
    job = _job(tmp_path / "again", "partial", tmp_path / "o2")
    job.start()
    assert job.wait() == "failed" and job.error.startswith("the reconstruction wrote no cap_roughness.exr, ")
    assert not (tmp_path / "o2").exists()


def test_job_cancel_stops_the_process_and_removes_its_output(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("kept")
    job = _job(tmp_path, "slow", out)
    job.start()
    staged = [p for p in out.iterdir() if p.name.startswith(reconstruct_job.STAGING_PREFIX)]
    assert len(staged) == 1 and job.command()[job.command().index("--out") + 1] == str(staged[0])
    while not (any(staged[0].iterdir()) and job.stage == "predicting the maps"):
        assert job.poll() == "running" and job.elapsed < 30
        time.sleep(0.05)  # until the stand-in has said where it is, written its first map and sleeps
    assert job.fraction == 0.4
    proc = job._proc
    job.cancel()
    assert job.state == "cancelled" and proc.poll() is not None
    assert [p.name for p in out.iterdir()] == ["mine.txt"]
    with pytest.raises(ValueError, match="not a folder"):
        reconstruct_job.ReconstructJob(sys.executable, job.capture, out / "mine.txt")


def test_job_without_progress_lines_estimates_from_the_time(tmp_path):
    job = _job(tmp_path, "silent-slow", tmp_path / "out")
    job.start()
    time.sleep(0.3)
    assert job.poll() == "running"
    assert 0 < job.fraction < reconstruct_job.MAX_ESTIMATE and job.stage.startswith("running the network (")
    job.cancel()
    assert job.state == "cancelled" and not (tmp_path / "out").exists()
    with pytest.raises(ValueError, match="must not lie inside the capture folder"):
        reconstruct_job.ReconstructJob(sys.executable, job.capture, job.capture / "maps")


# --------------------------------------------------------------------------- the operator (bpy wheel)


@pytest.fixture
def reconstruct(bpy, monkeypatch):
    """The add-on's ``reconstruct_operator`` module with Blender's own Python (the project venv) running the network."""
    from blender_addon import reconstruct_operator, render_operator

    monkeypatch.delenv(render_operator.PYTHON_ENV, raising=False)
    # The venv has torch: no preference needed.
    assert reconstruct_operator.reconstruction_python() == Path(sys.executable)
    return reconstruct_operator


def _stub(reconstruct, **props):
    """An object with the operator's properties and a ``report`` that records, for calling ``execute`` directly."""
    reports = []
    values = {
        "capture_dir": "",
        "output_dir": "",
        "mesh": "RELIEF",
        "checkpoint": "",
        "distance": 0.0,
        "refine": True,
    } | props
    op = types.SimpleNamespace(**values, report=lambda kind, text: reports.append((set(kind), text)))
    return op, reports


@pytest.mark.bpy
def test_operator_reconstructs_the_example_capture_as_a_relief(bpy, reconstruct, tmp_path):
    out = tmp_path / "maps"
    start = time.perf_counter()
    assert bpy.ops.pdir.reconstruct_capture(capture_dir=str(EXAMPLE), output_dir=str(out)) == {"FINISHED"}
    seconds = time.perf_counter() - start
    print(f"reconstruct_capture(examples/capture): {seconds:.1f} s")
    assert not (ROOT / "examples" / "capture_reconstruction").exists()
    names = {p.name for p in out.iterdir()}  # every map and preview (and capture_camera.json), no staging folder
    assert {f"capture_{k}.{e}" for k in MAP_NAMES for e in ("exr", "png")} <= names
    assert all(n.startswith("capture_") for n in names)
    obj = bpy.data.objects["capture"]
    assert obj.type == "MESH" and obj.parent == bpy.context.scene.camera
    assert obj["pdir_capture"] == str(EXAMPLE.resolve()) and obj["pdir_missing"] == ""
    co = np.empty(len(obj.data.vertices) * 3)
    obj.data.vertices.foreach_get("co", co)
    depth = -co.reshape(-1, 3)[:, 2]
    assert len(depth) > 4 and len(obj.data.polygons) > 2
    assert depth.max() - depth.min() > 0.01  # a relief, not a card (the example is a 15 cm-ish object)
    assert np.median(depth) == pytest.approx(0.8332, rel=0.02)  # anchored at capture.json's distance_m
    nodes = obj.active_material.node_tree.nodes
    bsdf = next(n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")

    def source(socket):
        (link,) = bsdf.inputs[socket].links
        node = link.from_node
        return node.label if node.bl_idname == "ShaderNodeTexImage" else node.inputs["Color"].links[0].from_node.label

    got = {s: source(s) for s in ("Base Color", "Roughness", "Metallic", "Alpha")}
    assert got == {"Base Color": "albedo", "Roughness": "roughness", "Metallic": "metallic", "Alpha": "mask"}
    # the relief carries the normals itself (custom normals); its Normal Map node stays, unlinked (pbr_import)
    assert obj.data.has_custom_normals and not bsdf.inputs["Normal"].links
    assert next(n for n in nodes if n.bl_idname == "ShaderNodeNormalMap").space == "OBJECT"
    assert reconstruct.running_job() is None


@pytest.mark.bpy
def test_bad_folder_is_one_report_line_and_cancelled(bpy, reconstruct, tmp_path):
    out = tmp_path / "out"
    op, reports = _stub(reconstruct, capture_dir=str(tmp_path), output_dir=str(out))
    assert reconstruct.PDIR_OT_reconstruct_capture.execute(op, bpy.context) == {"CANCELLED"}
    assert reports == [({"ERROR"}, f"{tmp_path}: not a capture folder (no capture.json; see examples/capture)")]
    assert not out.exists()
    with pytest.raises(RuntimeError, match="no such capture folder") as err:
        bpy.ops.pdir.reconstruct_capture(capture_dir=str(tmp_path / "nope"), output_dir=str(out))
    assert len(str(err.value).strip().splitlines()) == 1
    # Without an event loop (the wheel, blender -b) invoke runs execute instead of waiting for timer events.
    assert not reconstruct._modal_possible(bpy.context)
    with pytest.raises(RuntimeError, match="choose a capture folder"):
        bpy.ops.pdir.reconstruct_capture("INVOKE_DEFAULT", output_dir=str(out))
    assert not out.exists() and not any(o.type == "MESH" for o in bpy.data.objects)


@pytest.mark.bpy
def test_script_error_is_one_report_line_and_nothing_is_left(bpy, reconstruct, tmp_path):
    from pbrdf.data import capture
    from pbrdf.sensor import camera

    dark = capture.save_capture(tmp_path / "dark", np.full((4, 32, 32), 16, np.uint16), camera.CameraModel())
    out = tmp_path / "out"
    out.mkdir()
    op, reports = _stub(reconstruct, capture_dir=str(dark), output_dir=str(out), mesh="CARD")
    assert reconstruct.PDIR_OT_reconstruct_capture.execute(op, bpy.context) == {"CANCELLED"}
    ((kind, text),) = reports
    assert kind == {"ERROR"} and "\n" not in text
    assert text.startswith(f"Reconstruction of dark failed: {dark}: nothing usable: every raw value is at or below")
    assert list(out.iterdir()) == [] and not any(o.type == "MESH" for o in bpy.data.objects)


class _WindowManager:
    """Records what the modal operator does with the window manager (the wheel has no event loop)."""

    def __init__(self):
        self.calls, self.windows = [], []

    def __getattr__(self, name):
        if name.startswith(("progress_", "event_timer_", "modal_handler_")):
            return lambda *a, **k: self.calls.append((name, *a)) or f"{name}-handle"
        raise AttributeError(name)


def _modal_op(reconstruct, monkeypatch, tmp_path, mode):
    """A stub operator, a fake window context and a stand-in job for ``invoke`` / ``modal``."""
    op, reports = _stub(reconstruct)
    op._timer = None
    cls = reconstruct.PDIR_OT_reconstruct_capture
    for name in ("execute", "_status", "_end"):
        setattr(op, name, types.MethodType(getattr(cls, name), op))
    wm = _WindowManager()
    status = []
    workspace = types.SimpleNamespace(status_text_set=status.append)
    context = types.SimpleNamespace(window=object(), window_manager=wm, workspace=workspace, scene=None)
    job = _job(tmp_path, mode, tmp_path / "out")
    monkeypatch.setattr(reconstruct, "_new_job", lambda _op, _context: job)
    monkeypatch.setattr(reconstruct, "_modal_possible", lambda _context: True)
    return op, reports, context, wm, status, job


def _event(kind):
    return types.SimpleNamespace(type=kind)


def _run_to_the_end(reconstruct, op, context, job) -> set[str]:
    """``invoke``, then timer events until the modal operator ends; its last return value."""
    cls = reconstruct.PDIR_OT_reconstruct_capture
    assert cls.invoke(op, context, _event("LEFTMOUSE")) == {"RUNNING_MODAL"}
    result = {"RUNNING_MODAL"}
    while result == {"RUNNING_MODAL"}:
        assert job.elapsed < 30
        time.sleep(0.05)
        result = cls.modal(op, context, _event("TIMER"))
    return result


@pytest.mark.bpy
def test_modal_run_shows_progress_and_the_cancel_button_stops_it(bpy, reconstruct, monkeypatch, tmp_path):
    op, reports, context, wm, status, job = _modal_op(reconstruct, monkeypatch, tmp_path, "slow")
    cls = reconstruct.PDIR_OT_reconstruct_capture
    assert cls.invoke(op, context, _event("LEFTMOUSE")) == {"RUNNING_MODAL"}
    assert reconstruct.running_job() is job and not cls.poll(bpy.context)
    assert [c[0] for c in wm.calls] == ["event_timer_add", "modal_handler_add", "progress_begin"]
    while job.stage != "predicting the maps" or not any(job.out.glob(".reconstruct-partial-*/cap_normal.exr")):
        assert cls.modal(op, context, _event("TIMER")) == {"RUNNING_MODAL"} and job.elapsed < 30
        time.sleep(0.05)
    assert cls.modal(op, context, _event("MOUSEMOVE")) == {"PASS_THROUGH"}  # the UI stays usable
    assert ("progress_update", 40) in wm.calls and "Reconstructing cap: 40 % - predicting the maps" in status[-1]
    assert bpy.ops.pdir.reconstruct_cancel() == {"FINISHED"}  # the panel's Cancel button
    assert cls.modal(op, context, _event("MOUSEMOVE")) == {"CANCELLED"}
    assert reports == [({"WARNING"}, "Reconstruction of cap cancelled; nothing written")]
    assert job.state == "cancelled" and not job.out.exists()
    assert [c[0] for c in wm.calls[-2:]] == ["event_timer_remove", "progress_end"] and status[-1] is None
    assert reconstruct.running_job() is None and cls.poll(bpy.context)
    with pytest.raises(RuntimeError):  # nothing to cancel now
        bpy.ops.pdir.reconstruct_cancel()


@pytest.mark.bpy
def test_modal_run_to_the_end_imports_or_reports_one_line(bpy, reconstruct, monkeypatch, tmp_path):
    op, reports, context, wm, status, job = _modal_op(reconstruct, monkeypatch, tmp_path, "ok")
    result = _run_to_the_end(reconstruct, op, context, job)
    # The stand-in's "maps" are not images: the import's error is the one report line; the maps stay.
    assert result == {"CANCELLED"} and job.state == "done" and len(reports) == 1
    ((kind, text),) = reports
    assert kind == {"ERROR"} and text.startswith("Reconstructed cap, but the import failed: ") and "\n" not in text
    assert (job.out / "cap_normal.exr").is_file() and reconstruct.running_job() is None and status[-1] is None


@pytest.mark.bpy
def test_the_scripts_warnings_become_warning_reports(bpy, reconstruct, monkeypatch, tmp_path):
    op, reports, context, wm, status, job = _modal_op(reconstruct, monkeypatch, tmp_path, "warn")
    _run_to_the_end(reconstruct, op, context, job)
    # one WARNING per distinct warning line (a terminal user sees them on stderr), then the import's one ERROR
    assert job.state == "done" and [k for k, _ in reports] == [{"WARNING"}, {"ERROR"}]
    assert reports[0][1] == f"{job.capture}: no distance_m; 0.75 m assumed"


class _Layout:
    """Records a panel's ``draw`` (the wheel draws no UI); icons are checked against Blender's list."""

    ICONS = None

    def __init__(self, log):
        self.log, self.enabled = log, True

    def _icon(self, icon):
        assert icon in _Layout.ICONS, icon

    def prop(self, data, name, **kw):
        self.log.append(("prop", name))

    def label(self, text="", icon="NONE"):
        self._icon(icon)
        self.log.append(("label", text))

    def row(self, **kw):
        return self

    def operator(self, idname, icon="NONE", **kw):
        self._icon(icon)
        op = types.SimpleNamespace()
        self.log.append(("operator", idname, op))
        return op


@pytest.mark.bpy
def test_panel_shows_the_settings_or_the_running_job(bpy, reconstruct, monkeypatch, tmp_path):
    _Layout.ICONS = set(bpy.types.UILayout.bl_rna.functions["label"].parameters["icon"].enum_items.keys())
    s = bpy.context.scene.pdir_reconstruct
    s.capture_dir, s.mesh = str(EXAMPLE), "CARD"
    log = []
    panel = types.SimpleNamespace(layout=_Layout(log))
    reconstruct.PDIR_PT_reconstruct.draw(panel, bpy.context)
    assert [e[1] for e in log if e[0] == "prop"] == [
        "capture_dir",
        "output_dir",
        "mesh",
        "checkpoint",
        "distance",
        "refine",
    ]
    ((_, idname, op),) = [e for e in log if e[0] == "operator"]
    assert idname == "pdir.reconstruct_capture"
    assert (op.capture_dir, op.mesh, op.output_dir, op.checkpoint, op.refine) == (str(EXAMPLE), "CARD", "", "", True)
    assert s.bl_rna.properties["refine"].default is True  # the checkbox starts checked
    assert not [e for e in log if e[0] == "label"]  # Blender's Python here has torch: no how-to line
    monkeypatch.setattr(reconstruct, "_job", types.SimpleNamespace(name="mug", fraction=0.4, stage="predicting"))
    log.clear()
    reconstruct.PDIR_PT_reconstruct.draw(panel, bpy.context)
    assert log[:2] == [("label", "mug: 40 %"), ("label", "predicting")] and log[2][1] == "pdir.reconstruct_cancel"
