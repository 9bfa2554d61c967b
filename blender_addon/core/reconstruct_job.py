"""The "Reconstruct Capture" job without bpy: ``headless/infer.py`` in a subprocess, its progress and outputs.

The add-on's ``pdir.reconstruct_capture`` (:mod:`blender_addon.reconstruct_operator`) turns a capture
folder into predicted maps by running ``python -m headless.infer --input CAPTURE --out DIR``
(never ``--blend``: the add-on imports the maps into the open Blender session itself). torch
never runs inside Blender: the network always runs in its own process, like the polarized render
of :mod:`blender_addon.render_operator`, and it is found the same way:

- the Python: the add-on preference "Python with Mitsuba" or ``$PDIR_PYTHON`` (the project's
  ``.venv/bin/python``), else Blender's own Python when it has :data:`PACKAGES`;
- the script: run from the repository when the add-on sits in a checkout (working directory and
  ``PYTHONPATH`` = the repository root, :func:`repository_root`); an add-on installed from the
  zip has no repository, so that Python needs the project installed (``pip install -e .``), which
  makes ``python -m headless.infer`` and the shipped model (``models/small``) importable.

:class:`ReconstructJob` runs one reconstruction: it writes into a hidden staging folder inside the
output folder and moves ``<name>_<map>.exr/.png`` into place only after the process succeeded,
so a failed or cancelled run leaves nothing behind (a folder it created is removed again).
Progress: the script runs with ``--progress-lines`` and prints ``progress: FRACTION STAGE`` at
each stage (:func:`parse_progress`); until the first such line (Python and torch starting) the
fraction grows with the elapsed time toward :data:`EXPECTED_SECONDS` (never past
:data:`MAX_ESTIMATE` before the end).
"""

from __future__ import annotations

import math
import os
import queue
import shutil
import subprocess
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path

from pbrdf.data.capture import CAPTURE_JSON
from pbrdf.data.predictions import MAP_NAMES

__all__ = [
    "EXPECTED_SECONDS",
    "PACKAGES",
    "SCRIPT_MODULE",
    "ReconstructJob",
    "check_capture_folder",
    "command_line",
    "default_output_dir",
    "error_line",
    "estimate_fraction",
    "expected_outputs",
    "find_outputs",
    "parse_progress",
    "warning_lines",
    "repository_root",
]

#: The module run with ``python -m`` (``headless/infer.py``).
SCRIPT_MODULE = "headless.infer"
#: Python packages the reconstruction needs (Blender's own Python is used only when it has them).
PACKAGES = ("torch", "scipy", "OpenEXR", "PIL")
#: Typical seconds of one reconstruction (torch start, model, decode, prediction, depth) on a laptop CPU.
EXPECTED_SECONDS = 20.0
#: The time-based estimate stays below this fraction until the process has finished.
MAX_ESTIMATE = 0.95
#: Prefix of the staging folder inside the output folder.
STAGING_PREFIX = ".reconstruct-partial-"


def repository_root(addon_dir: str | os.PathLike) -> Path | None:
    """The repository around an add-on folder (the one holding ``headless/infer.py``), or None (zip install).

    Args:
        addon_dir: the add-on package folder (``blender_addon/`` in a checkout).
    """
    root = Path(addon_dir).resolve().parent
    return root if (root / "headless" / "infer.py").is_file() else None


def check_capture_folder(path: str | os.PathLike) -> Path:
    """The capture folder to reconstruct, or ValueError with one line saying what is wrong.

    A path to ``capture.json`` itself stands for its folder. Only the folder's shape is checked
    here; the script validates the content (and says so on one line when it fails).

    Example:
        >>> check_capture_folder("")
        Traceback (most recent call last):
        ...
        ValueError: choose a capture folder (raw HDR brackets plus capture.json)
    """
    if not str(path).strip():
        raise ValueError("choose a capture folder (raw HDR brackets plus capture.json)")
    folder = Path(path).expanduser()
    if folder.name == CAPTURE_JSON and folder.is_file():
        folder = folder.parent
    if not folder.exists():
        raise ValueError(f"{folder}: no such capture folder")
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder; choose a capture folder (raw HDR brackets plus {CAPTURE_JSON})")
    if not (folder / CAPTURE_JSON).is_file():
        if any((sub / CAPTURE_JSON).is_file() for sub in folder.iterdir() if sub.is_dir()):
            raise ValueError(
                f"{folder}: a sequence of capture folders; choose one of them (headless/infer.py reconstructs all)"
            )
        raise ValueError(f"{folder}: not a capture folder (no {CAPTURE_JSON}; see examples/capture)")
    return folder.resolve()


def default_output_dir(capture: str | os.PathLike) -> Path:
    """``<capture>_reconstruction`` beside the capture folder; a temporary folder if that is not writable.

    Beside the capture, because the maps are results worth keeping (relight, bake and re-import
    read the EXR files) and belong with their capture; not inside it, so the capture folder stays
    exactly what the camera wrote. A read-only location falls back to
    ``<tmp>/pdir-reconstruction/<capture name>``.

    Example:
        >>> default_output_dir("/data/scans/mug").name
        'mug_reconstruction'
    """
    capture = Path(capture)
    parent = capture.parent
    if parent.is_dir() and not os.access(parent, os.W_OK):
        return Path(tempfile.gettempdir()) / "pdir-reconstruction" / capture.name
    return parent / f"{capture.name}_reconstruction"


def command_line(
    python: str | os.PathLike,
    capture: str | os.PathLike,
    out: str | os.PathLike,
    *,
    card: bool = False,
    checkpoint: str | os.PathLike | None = None,
    module: str = SCRIPT_MODULE,
    distance: float | None = None,
    refine: bool = True,
) -> list[str]:
    """The command that reconstructs ``capture`` into ``out`` (never ``--blend``); ``distance`` (m) -> ``--distance``.

    ``refine`` (the panel's checkbox) leaves infer.py's default, which refines where a distance is known (the
    panel's or capture.json's ``distance_m``); False passes ``--no-refine``.

    Example:
        >>> " ".join(command_line("py", "cap", "o", card=True, checkpoint="m.pt"))
        'py -m headless.infer --input cap --out o --quiet --progress-lines --card --checkpoint m.pt'
        >>> command_line("py", "cap", "o", refine=False)[-1]
        '--no-refine'
    """
    cmd = [str(python), "-m", module, "--input", str(capture), "--out", str(out), "--quiet", "--progress-lines"]
    if card:
        cmd.append("--card")
    if checkpoint is not None and str(checkpoint).strip():
        cmd += ["--checkpoint", str(checkpoint)]
    if distance:
        cmd += ["--distance", f"{distance:g}"]
    if not refine:  # on: infer.py's default refinement against the capture (network/refine.py)
        cmd.append("--no-refine")
    return cmd


def parse_progress(line: str) -> tuple[float, str] | None:
    """``(fraction, stage)`` of a ``progress: FRACTION STAGE`` line (fraction clipped to [0, 1]); else None.

    Example:
        >>> parse_progress("progress: 0.35 predicting the maps"), parse_progress("progress: 1.7")
        ((0.35, 'predicting the maps'), (1.0, ''))
        >>> parse_progress("wrote 6 maps"), parse_progress("progress: soon")
        (None, None)
    """
    head, sep, rest = line.strip().partition(":")
    if not sep or head.strip() != "progress":
        return None
    value, _, stage = rest.strip().partition(" ")
    try:
        fraction = float(value)
    except ValueError:
        return None
    if not math.isfinite(fraction):
        return None
    return min(max(fraction, 0.0), 1.0), stage.strip()


def estimate_fraction(elapsed: float, expected: float = EXPECTED_SECONDS) -> float:
    """A progress fraction from the elapsed seconds: ``MAX_ESTIMATE * (1 - exp(-2 t / expected))``.

    About 0.82 at the expected time, then slowly toward :data:`MAX_ESTIMATE`, never past it.

    Example:
        >>> estimate_fraction(0.0), round(estimate_fraction(20.0), 2), estimate_fraction(1e6) <= MAX_ESTIMATE
        (0.0, 0.82, True)
    """
    return MAX_ESTIMATE * (1.0 - math.exp(-2.0 * max(elapsed, 0.0) / expected))


def warning_lines(stderr: Sequence[str]) -> list[str]:
    """The script's ``warning: ...`` lines, prefix removed, each once in order: what a finished job reports.

    The capture's own warnings (no distance, no dark frames, a mask that fills the frame) reach a
    terminal user on stderr; in Blender they become the operator's WARNING reports.

    Example:
        >>> warning_lines(["progress: 0.5 x", "warning: cap: no distance_m", "warning: cap: no distance_m", "w"])
        ['cap: no distance_m']
    """
    lines = (ln.strip() for ln in stderr)
    return list(dict.fromkeys(ln.removeprefix("warning:").strip() for ln in lines if ln.startswith("warning:")))


def error_line(stderr: Sequence[str], returncode: int | None) -> str:
    """The one line saying why the script failed: its last ``error: ...`` line, else its last stderr line.

    A missing module (the Python lacks torch, or the project is not installed there) gets a how-to.

    Example:
        >>> error_line(["warning: x", "error: cap: nothing usable"], 2)
        'cap: nothing usable'
        >>> error_line([], -9)
        'the reconstruction stopped with exit status -9 and no message'
    """
    lines = [ln.strip() for ln in stderr if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    if errors:
        return errors[-1].removeprefix("error:").strip()
    if not lines:
        return f"the reconstruction stopped with exit status {returncode} and no message"
    last = lines[-1]
    if last.startswith("ModuleNotFoundError:") or "No module named" in last:
        return (
            f"{last} - set a Python that has the project installed (its .venv/bin/python, or "
            f"'pip install -e .' of the repository) in the add-on preferences or $PDIR_PYTHON"
        )
    return last


def expected_outputs(folder: str | os.PathLike, name: str, *, card: bool = False) -> dict[str, Path]:
    """``{kind: folder/<name>_<kind>.exr}`` for the maps the script writes (no ``depth`` for a card)."""
    return {k: Path(folder) / f"{name}_{k}.exr" for k in MAP_NAMES if not (card and k == "depth")}


def find_outputs(folder: str | os.PathLike, name: str, *, card: bool = False) -> dict[str, Path]:
    """The map files of a finished reconstruction; FileNotFoundError naming the missing ones on one line."""
    files = expected_outputs(folder, name, card=card)
    missing = [p.name for p in files.values() if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"the reconstruction wrote no {', '.join(missing)} in {folder}")
    return files


def _reader(stream, sink: queue.Queue, tag: str) -> None:
    for line in iter(stream.readline, ""):
        sink.put((tag, line.rstrip("\r\n")))
    stream.close()


class ReconstructJob:
    """One reconstruction in a subprocess: start, poll (progress), cancel, and the outputs when done.

    Args:
        python: the Python that runs the script.
        capture: the capture folder (checked with :func:`check_capture_folder`).
        out: the output folder (created when missing; the maps land there as ``<name>_<map>.*``).
        card: a flat card (``--card``: no depth map) instead of a relief mesh.
        checkpoint: a ``model.pt``; None or empty: the shipped model.
        distance: the object distance in m (``--distance``); None or 0: capture.json's, else the default.
        repo_root: the repository to run from (:func:`repository_root`); None: the installed project.
        module: the module run with ``-m`` (tests substitute a stand-in).
        refine: infer.py's default test-time refinement (where a distance is known); False: ``--no-refine``.

    Attributes:
        state: ``"new"``, ``"running"``, ``"done"``, ``"failed"`` or ``"cancelled"``.
        fraction, stage: the progress and a few words on what runs.
        error: the one-line reason after ``"failed"``.
        outputs: ``{kind: path}`` after ``"done"``.
    """

    def __init__(
        self,
        python: str | os.PathLike,
        capture: str | os.PathLike,
        out: str | os.PathLike,
        *,
        card: bool = False,
        checkpoint: str | os.PathLike | None = None,
        repo_root: str | os.PathLike | None = None,
        module: str = SCRIPT_MODULE,
        distance: float | None = None,
        refine: bool = True,
    ) -> None:
        self.distance = distance or None
        self.capture = check_capture_folder(capture)
        self.out = Path(out).expanduser().resolve()
        if self.out == self.capture or self.capture in self.out.parents:
            raise ValueError(f"{self.out}: the output folder must not lie inside the capture folder")
        if self.out.exists() and not self.out.is_dir():
            raise ValueError(f"{self.out}: exists and is not a folder; choose another output folder")
        self.name = self.capture.name
        self.python, self.card, self.module, self.refine = Path(python), card, module, refine
        self.checkpoint = checkpoint if checkpoint is not None and str(checkpoint).strip() else None
        self.repo_root = Path(repo_root) if repo_root is not None else None
        self.state, self.fraction, self.stage, self.error = "new", 0.0, "", ""
        self.outputs: dict[str, Path] = {}
        self.stdout: list[str] = []
        self.stderr: list[str] = []
        self._proc: subprocess.Popen | None = None
        self._lines: queue.Queue = queue.Queue()
        self._threads: list[threading.Thread] = []
        self._staging: Path | None = None
        self._created_out = False
        self._reported = False
        self._start = self._stop = 0.0

    @property
    def elapsed(self) -> float:
        """Seconds from :meth:`start` to now, or to the end of the process once it has ended."""
        return ((self._stop or time.monotonic()) - self._start) if self._start else 0.0

    def command(self) -> list[str]:
        """The command line (after :meth:`start`, with the staging folder as ``--out``)."""
        return command_line(self.python, self.capture, self._staging or self.out, card=self.card,
                            checkpoint=self.checkpoint, module=self.module, distance=self.distance,
                            refine=self.refine)  # fmt: skip

    def start(self) -> None:
        """Create the staging folder and start the process (OSError: it cannot start; nothing left behind)."""
        if self.state != "new":
            raise RuntimeError(f"the job is {self.state}, not new")
        self._created_out = not self.out.exists()
        self.out.mkdir(parents=True, exist_ok=True)
        self._staging = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=self.out))
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        if self.repo_root is not None:
            env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(self.repo_root), env.get("PYTHONPATH", "")]))
        try:
            self._proc = subprocess.Popen(
                self.command(), cwd=self.repo_root, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, text=True, encoding="utf-8", errors="replace", bufsize=1,
            )  # fmt: skip
        except OSError as e:
            self._clean_up()
            self.state, self.error = "failed", f"cannot start {self.python}: {e.strerror or e}"
            raise OSError(self.error) from None
        self._threads = [
            threading.Thread(target=_reader, args=(stream, self._lines, tag), daemon=True)
            for stream, tag in ((self._proc.stdout, "out"), (self._proc.stderr, "err"))
        ]
        for t in self._threads:
            t.start()
        self._start = time.monotonic()
        self.state, self.stage = "running", "starting Python and the network"

    def _drain(self) -> None:
        while True:
            try:
                tag, line = self._lines.get_nowait()
            except queue.Empty:
                return
            (self.stdout if tag == "out" else self.stderr).append(line)
            parsed = parse_progress(line) if tag == "out" else None
            if parsed is not None:
                self.fraction, self.stage = parsed[0], parsed[1] or self.stage
                self._reported = True

    def poll(self) -> str:
        """Update :attr:`fraction`, :attr:`stage` (and on exit the outputs or the error); returns :attr:`state`."""
        if self.state != "running":
            return self.state
        self._drain()
        code = self._proc.poll()
        if code is None:
            if not self._reported:
                self.fraction = estimate_fraction(self.elapsed)
                self.stage = f"running the network ({self.elapsed:.0f} s)"
            return self.state
        self._stop = time.monotonic()
        for t in self._threads:
            t.join(timeout=5)
        self._drain()
        if code != 0:
            self.state, self.error = "failed", error_line(self.stderr, code)
            self._clean_up()
            return self.state
        try:
            self.outputs = self._move_outputs()
        except OSError as e:
            self.state, self.error = "failed", str(e).splitlines()[0] if str(e) else type(e).__name__
            self._clean_up()
            return self.state
        self.state, self.fraction, self.stage = "done", 1.0, "done"
        return self.state

    def _move_outputs(self) -> dict[str, Path]:
        find_outputs(self._staging, self.name, card=self.card)  # every map, before anything moves
        for p in sorted(self._staging.iterdir()):
            if p.is_file() and p.name.startswith(f"{self.name}_"):
                os.replace(p, self.out / p.name)
        shutil.rmtree(self._staging, ignore_errors=True)
        self._staging = None
        if self.card:  # a relief of an earlier run must not pass for this card's depth
            stale = self.out / f"{self.name}_depth.exr"
            stale.unlink(missing_ok=True)
            stale.with_suffix(".png").unlink(missing_ok=True)
        return find_outputs(self.out, self.name, card=self.card)

    def wait(self, poll_seconds: float = 0.1, timeout: float | None = None) -> str:
        """Poll until the process ends (or cancel after ``timeout`` seconds); returns :attr:`state`."""
        while self.poll() == "running":
            if timeout is not None and self.elapsed > timeout:
                self.cancel()
                self.state, self.error = "failed", f"the reconstruction took longer than {timeout:g} s"
                break
            time.sleep(poll_seconds)
        return self.state

    def cancel(self) -> None:
        """Stop the process and remove what it wrote (its staging folder; the output folder if this job made it)."""
        if self.state != "running":
            return
        proc = self._proc
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)
        self._stop = time.monotonic()
        for t in self._threads:
            t.join(timeout=5)
        self._drain()
        self._clean_up()
        self.state, self.stage = "cancelled", "cancelled"

    def _clean_up(self) -> None:
        if self._staging is not None:
            shutil.rmtree(self._staging, ignore_errors=True)
            self._staging = None
        if self._created_out and self.out.is_dir() and not any(self.out.iterdir()):
            self.out.rmdir()
