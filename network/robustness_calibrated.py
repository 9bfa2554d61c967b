"""The model's scores on a perturbed rig decoded with the nominal, the calibrated and the true rig.

Issue 28 asks that decoding with the self-calibration's estimate brings the model back within its
interval of the nominal case. A *case* (:data:`CASES`) is one imperfect rig with many terms at
once: every imperfection of :data:`network.robustness.TERMS` at its realistic worst level, or a
draw of :func:`pbrdf.sensor.rig_jitter.draw_rig` at scale 2. Every scene of a fixed subset is
captured again through that rig (the split's own noise draw; the display terms through
:func:`network.robustness.display_stokes`) and scored through the capture path
(:func:`network.evaluation.predict_scene`: decode, automatic mask, inference) three ways:

* ``nominal``: ``capture.json`` carries the nominal camera model, no dark frames (the rig was not
  calibrated; as the one-term sweep's nominal decoder);
* ``calibrated``: the calibration targets of docs/calibration.md are synthesized through the same
  rig with noise (:func:`pbrdf.sensor.calibration_targets.simulate_targets`, as
  ``tools/make_calibration_captures.py``), :func:`pbrdf.sensor.calibration.calibrate` estimates
  the rig, the estimate is written as ``rig.json`` (as ``headless/calibrate.py``) and the scene's
  capture (``capture.json`` as the lab wrote it, the nominal model, plus dark frames) is decoded
  with that file as ``headless/infer.py --rig rig.json`` does
  (:func:`pbrdf.data.capture_rig.with_rig`);
* ``true``: ``capture.json`` carries the true camera model, plus dark frames (an exact calibration).

The ``unperturbed`` cell is the nominal rig itself (:func:`network.robustness.run_cell`'s nominal
cell: the split's raw brackets bit for bit). Each cell is one JSON file, written atomically, so an
interrupted run resumes; the estimated and true rigs are written beside the cells.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pbrdf.data import capture as pcapture
from pbrdf.data import sample as psample
from pbrdf.data.capture_rig import read_rig
from pbrdf.data.dark_frames import dark_frames
from pbrdf.io.strict_json import dumps_strict
from pbrdf.sensor.calibration import calibrate, rig_errors
from pbrdf.sensor.calibration_targets import simulate_targets
from pbrdf.sensor.camera import simulate_capture
from pbrdf.sensor.projection import pinhole_intrinsics
from pbrdf.sensor.rig import Rig
from pbrdf.sensor.rig_jitter import draw_rig

from .robustness import TERMS, _summary, display_stokes, run_cell, run_cells, score_capture, true_camera

__all__ = [
    "CAL_DECODERS",
    "UNPERTURBED",
    "TARGET_FOCAL_FRACTION",
    "RigCase",
    "CASES",
    "case_names",
    "perturbed_rig",
    "calibrate_rig",
    "case_capture",
    "run_case_cell",
    "calibration_sweep",
]

#: The decoder's knowledge of the perturbed rig (module docs).
CAL_DECODERS = ("nominal", "calibrated", "true")
#: Key of the cell on the nominal rig itself.
UNPERTURBED = "unperturbed"
#: Focal length of the calibration targets' raw grid as a fraction of its width (the real camera's
#: field of view, as ``tools/make_calibration_captures.py``).
TARGET_FOCAL_FRACTION = 0.94


@dataclass(frozen=True)
class RigCase:
    """One perturbed rig.

    Attributes:
        name: key (cell file names, ``--cases``).
        label: for tables.
        levels: ``(term, level)`` of :data:`network.robustness.TERMS` applied at once (or empty).
        jitter_seed: seed of :func:`pbrdf.sensor.rig_jitter.draw_rig` (or None).
        jitter_scale: its scale.
        seed: the calibration targets' noise seed.
    """

    name: str
    label: str
    levels: tuple[tuple[str, float], ...] = ()
    jitter_seed: int | None = None
    jitter_scale: float = 2.0
    seed: int = 0


#: Every term at its worst level (:data:`network.robustness.TERMS`).
_WORST = tuple((t.name, t.levels[-1]) for t in TERMS)


def _with_ambient(level: float) -> tuple[tuple[str, float], ...]:
    """:data:`_WORST` with the ambient light at ``level``."""
    return tuple((n, level if n == "ambient" else v) for n, v in _WORST)


#: The cases: every term at its worst level at once; the same in a dim room (ambient light 1 % of the
#: display, the sweep's smallest level: dark frames do not remove the room light's noise) and in a
#: dark one (the room light's cost told from the rest); the camera terms alone (the display terms no
#: decoder inverts left out); and three rig-jitter draws at scale 2.
CASES: tuple[RigCase, ...] = (
    RigCase("worst", "every term at its worst level", _WORST, seed=1),
    RigCase("worst-dim", "every term at its worst level, ambient 1 %", _with_ambient(0.01), seed=5),
    RigCase("worst-dark", "every term at its worst level, no ambient light", _with_ambient(0.0), seed=6),
    RigCase(
        "worst-camera",
        "every camera term at its worst level, no ambient light, the nominal display",
        tuple((n, v) for n, v in _with_ambient(0.0) if not n.startswith("display")),
        seed=7,
    ),
    RigCase("jitter2-a", "rig_jitter draw, scale 2 (seed 101)", jitter_seed=101, seed=2),
    RigCase("jitter2-b", "rig_jitter draw, scale 2 (seed 102)", jitter_seed=102, seed=3),
    RigCase("jitter2-c", "rig_jitter draw, scale 2 (seed 103)", jitter_seed=103, seed=4),
)
_BY_NAME = {c.name: c for c in CASES}


def case_names() -> list[str]:
    """The names of :data:`CASES`.

    >>> case_names()[0]
    'worst'
    """
    return list(_BY_NAME)


def _case(name: str | RigCase) -> RigCase:
    if isinstance(name, RigCase):
        return name
    if name not in _BY_NAME:
        raise ValueError(f"case must be one of {case_names()}; got {name!r}")
    return _BY_NAME[name]


def perturbed_rig(case: str | RigCase, rig: Rig, raw_shape: tuple[int, int]) -> Rig:
    """The true rig of ``case``: ``rig`` (the nominal one) with the case's imperfections.

    Args:
        case: a :data:`CASES` name or a :class:`RigCase`.
        rig: the nominal rig (its camera model and display are the starting point).
        raw_shape: ``(H, W)`` of the raw frames (the vignetting level is the loss at their corner).

    Returns:
        The perturbed rig: camera model and display (degree and angle of polarization).

    >>> worst = perturbed_rig("worst", Rig(), (256, 256))
    >>> worst.camera.model.extinction_ratio, worst.display.degree_of_polarization
    ((20.0, 20.0, 20.0), 0.9)
    """
    c = _case(case)
    if c.jitter_seed is not None:
        return draw_rig(rig, c.jitter_seed, c.jitter_scale)[0]
    model, display = rig.camera.model, rig.display
    radiance = float(display.radiance)
    for term, level in c.levels:
        if term == "display_dop":
            display = dataclasses.replace(display, degree_of_polarization=level)
        elif term == "display_angle":
            display = dataclasses.replace(display, polarization_angle=display.polarization_angle + math.radians(level))
        else:
            model = true_camera(term, level, model, display_radiance=radiance, raw_shape=raw_shape)
    return dataclasses.replace(rig, display=display, camera=dataclasses.replace(rig.camera, model=model))


def calibrate_rig(true_rig: Rig, raw_shape: tuple[int, int], seed: int) -> tuple[Rig, dict[str, float]]:
    """Calibrate ``true_rig`` from synthetic targets, as a lab would with ``headless/calibrate.py``.

    The targets (dark, white R G B, polarizer at six angles) are formed through ``true_rig`` with
    Poisson-Gaussian noise (``default_rng([seed, 3])``) on a raw grid of ``raw_shape`` (the
    vignetting is a map of the frame) with focal length :data:`TARGET_FOCAL_FRACTION` of its width.

    Returns:
        ``(estimated rig, its errors)``: :func:`pbrdf.sensor.calibration.rig_errors` against ``true_rig``.
    """
    h, w = raw_shape
    k = pinhole_intrinsics(TARGET_FOCAL_FRACTION * w, w, h)
    targets = simulate_targets(true_rig, (h, w), rng=np.random.default_rng([seed, 3]), intrinsics=k)
    est = calibrate(targets).rig
    return est, rig_errors(est, true_rig, (h, w))


def case_capture(
    folder: str | Path,
    basis: Mapping[str, np.ndarray],
    capture: pcapture.Capture,
    sample_seed: int,
    true_rig: Rig,
    decoder: str,
) -> Path:
    """Write one scene's capture folder through ``true_rig`` with ``decoder``'s ``capture.json``.

    Args:
        folder: the capture folder to write (must not exist or be empty).
        basis: the scene's Stokes basis (:func:`network.robustness.display_stokes`), ``(H, W, 3, 4)``.
        capture: the sample's own capture (nominal camera model; its metadata is kept).
        sample_seed: the sample's seed (noise ``default_rng([sample_seed, 1])``, dark frames ``[.., 2]``).
        true_rig: the perturbed rig (:func:`perturbed_rig`).
        decoder: one of :data:`CAL_DECODERS`: ``nominal`` and ``calibrated`` write the nominal
            camera model (the calibrated one is decoded with ``rig.json`` after), ``true`` the
            true one; ``calibrated`` and ``true`` add dark frames.

    Returns:
        The folder.
    """
    if decoder not in CAL_DECODERS:
        raise ValueError(f"decoder must be one of {CAL_DECODERS}; got {decoder!r}")
    display = true_rig.display
    up = display_stokes(basis, display.degree_of_polarization, math.degrees(display.polarization_angle - math.pi / 2))
    up = np.repeat(np.repeat(up, 2, axis=0), 2, axis=1)  # one rendered pixel per 2x2 raw block, as the split
    model = dataclasses.replace(true_rig.camera.model, exposures=capture.model.exposures, sensor=capture.model.sensor)
    raws = simulate_capture(up, model, rng=np.random.default_rng([sample_seed, 1]))
    dark = None
    if decoder != "nominal":  # the display off: the room light and the sensor's offset
        dark = dark_frames(model, up.shape[:2], sample_seed, stream=2, dtype=up.dtype)
    believed = model if decoder == "true" else capture.model
    extra = dict(capture.metadata)
    if decoder == "true":
        extra["rig"] = dataclasses.replace(true_rig, camera=dataclasses.replace(true_rig.camera, model=model)).to_dict()
    return pcapture.save_capture(folder, raws, believed, extra=extra, dark=dark)


def _nominal_rig(capture: pcapture.Capture) -> Rig:
    """The sample's rig with its capture's camera model."""
    rig = capture.meta.rig
    return dataclasses.replace(rig, camera=dataclasses.replace(rig.camera, model=capture.model))


class _Rigs:
    """Per (case, raw shape, nominal rig): the true rig and its calibration, computed once, written to ``folder``."""

    def __init__(self, folder: Path) -> None:
        self.folder, self.done = folder, {}

    def __call__(self, case: RigCase, capture: pcapture.Capture, estimate: bool) -> tuple[Rig, dict | None]:
        """``(true rig, calibration errors)``; with ``estimate`` the estimate is in ``folder/CASE-calibrated.json``."""
        nominal, shape = _nominal_rig(capture), tuple(capture.raws.shape[1:])
        key = (case.name, shape, dumps_strict(nominal.to_dict()), estimate)
        if key not in self.done:
            true, errors = perturbed_rig(case, nominal, shape), None
            self.folder.mkdir(parents=True, exist_ok=True)
            true.save(self.folder / f"{case.name}-true.json")
            if estimate:
                est, errors = calibrate_rig(true, shape, case.seed)
                est.save(self.folder / f"{case.name}-calibrated.json")
            self.done[key] = (true, errors)
        return self.done[key]


def run_case_cell(
    model,
    checkpoint: Mapping[str, Any],
    root: str | Path,
    indices: Sequence[int],
    stats: Mapping[str, Any],
    basis_fn: Callable[[int], Mapping[str, np.ndarray]],
    case: str | RigCase,
    decoder: str,
    *,
    rigs_dir: str | Path | None = None,
) -> dict[str, Any]:
    """Score the model on ``indices`` of ``root`` captured through ``case``'s rig, decoded by ``decoder``.

    Args:
        model: the loaded model.
        checkpoint: its checkpoint dict (input variant and scale).
        root: a rendered split with raw brackets.
        indices: the scenes scored.
        stats: training statistics.
        basis_fn: scene index -> its Stokes basis.
        case: a :data:`CASES` name or a :class:`RigCase`.
        decoder: one of :data:`CAL_DECODERS`.
        rigs_dir: where to write the true and estimated rig files (and read ``rig.json`` back from), or None.

    Returns:
        JSON-ready cell: ``case``, ``decoder``, ``scenes``, ``rows``, ``summary`` (as
        :func:`network.robustness.run_cell`), ``calibration_errors`` (``calibrated`` only), ``seconds``.
    """
    c = _case(case)
    if decoder not in CAL_DECODERS:
        raise ValueError(f"decoder must be one of {CAL_DECODERS}; got {decoder!r}")
    t0 = time.perf_counter()
    root = Path(root)
    rows, errors = [], None
    with tempfile.TemporaryDirectory(prefix="robustness-cal-") as tmp:
        rigs = _Rigs(Path(rigs_dir) if rigs_dir is not None else Path(tmp) / "rigs")
        for i in indices:
            meta = psample.check_complete(root, i, verify_hash=False)
            cap = pcapture.load_capture(psample.sample_paths(root, i).raw)
            true, errors_i = rigs(c, cap, decoder == "calibrated")
            folder = case_capture(Path(tmp) / f"{i:06d}", basis_fn(i), cap, int(meta["sample_seed"]), true, decoder)
            rig = None
            if decoder == "calibrated":  # the user's path: the rig.json calibrate.py wrote, read back
                rig, errors = read_rig(rigs.folder / f"{c.name}-calibrated.json"), errors_i
            rows.append(score_capture(model, checkpoint, root, i, stats, folder, rig=rig))
            shutil.rmtree(folder)
    cell = {"case": c.name, "decoder": decoder, "scenes": [r["index"] for r in rows], "rows": rows,
            "summary": _summary(rows), "seconds": time.perf_counter() - t0}  # fmt: skip
    if errors is not None:
        cell["calibration_errors"] = errors
    return cell


def calibration_plan(cases: Sequence[str] | None = None) -> list[tuple[str, str]]:
    """The cells ``(case, decoder)``: the unperturbed one first, then per case calibrated, true, nominal.

    >>> calibration_plan(["worst"])
    [('unperturbed', 'nominal'), ('worst', 'calibrated'), ('worst', 'true'), ('worst', 'nominal')]
    """
    names = case_names() if cases is None else [_case(n).name for n in cases]
    return [(UNPERTURBED, "nominal")] + [(n, d) for n in names for d in ("calibrated", "true", "nominal")]


def calibration_sweep(
    model,
    checkpoint: Mapping[str, Any],
    root: str | Path,
    indices: Sequence[int],
    stats: Mapping[str, Any],
    basis_fn: Callable[[int], Mapping[str, np.ndarray]],
    out: str | Path,
    *,
    cases: Sequence[str] | None = None,
    resume: bool = False,
    log: Callable[[str], None] | None = None,
) -> dict[str, dict[str, Any]]:
    """Run every cell of :func:`calibration_plan` into ``out/cells`` (rigs into ``out/rigs``); returns them by key.

    Keys: ``unperturbed`` and ``CASE-DECODER``. With ``resume`` the cells already in ``out/cells``
    for the same scenes are kept (ValueError for other scenes).
    """
    out = Path(out)

    def compute(case: str, decoder: str) -> Callable[[], dict[str, Any]]:
        if case == UNPERTURBED:
            return lambda: run_cell(model, checkpoint, root, indices, stats, basis_fn, "nominal", 0, "nominal")
        return lambda: run_case_cell(model, checkpoint, root, indices, stats, basis_fn, case, decoder,
                                     rigs_dir=out / "rigs")  # fmt: skip

    plan = [(UNPERTURBED if case == UNPERTURBED else f"{case}-{decoder}", compute(case, decoder))
            for case, decoder in calibration_plan(cases)]  # fmt: skip
    return run_cells(plan, out / "cells", indices, resume=resume, log=log)
