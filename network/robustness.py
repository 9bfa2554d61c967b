"""How the model's scores degrade as each rig imperfection grows, the decoder told the nominal or the true rig.

Each imperfection (:data:`TERMS`) grows in a few levels from the nominal rig (level 0) to a
realistic worst case (``docs/robustness.md`` says where each worst case comes from). For every
level every scene of a fixed subset of a test split is captured again through the perturbed rig
and given to the model as :func:`network.evaluation.predict_scene` gives a user's capture (decode,
automatic foreground mask, inference), twice:

* ``nominal`` decoder: the capture's ``capture.json`` carries the nominal camera model (the rig
  was not calibrated);
* ``true`` decoder: it carries the perturbed camera model, with dark frames (display off) for
  ambient light, so the decoder inverts what it can (:mod:`pbrdf.sensor.imperfections`). The
  display's degree of polarization and polarization angle act on the light in the scene: no
  decoder inverts them, and they have no ``true`` column.

The scene's light: camera-side terms re-simulate the Stokes images the split's sample was made of;
display-side terms need the scene under another display polarization. The emitted Stokes vector
enters the scene linearly, so three renders per scene (the *basis*: display polarized vertically
``v`` (the nominal display), horizontally ``h`` and at 45 degrees ``d``; ``headless/robustness.py``
renders them) give every display exactly::

    S(p, theta) = A + p (cos 2 theta B + sin 2 theta C),  A = (S_h + S_v) / 2,  B = (S_h - S_v) / 2,
    C = S_d - A

for a degree of polarization ``p`` and polarization angle ``theta`` (the rig's ``pi/2`` nominal).
The capture noise is the split's own draw (``numpy.random.default_rng([sample_seed, 1])``, as
``blender_addon/core/generate.py``), so the nominal cell reproduces the split's raw brackets bit
for bit and equals a plain evaluation of the same scenes; levels differ only by the imperfection.

Scores: normal MAE, albedo PSNR, roughness and metallic RMSE (:func:`network.evaluation.score` on
the ground truth's object coverage) with 95 % bootstrap intervals over scenes
(:func:`network.statistics.summarize`), and each level's paired per-scene difference to the nominal
cell. Each cell (term, level, decoder) is one JSON file, written atomically, so an interrupted
sweep resumes where it stopped.
"""

from __future__ import annotations

import functools
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
from pbrdf.data.dark_frames import dark_frames
from pbrdf.io.atomic import atomic_write_text
from pbrdf.io.strict_json import dumps_strict, loads_strict
from pbrdf.sensor.camera import CameraModel, simulate_capture

from .data import checkpoint_input_scale
from .evaluation import predict_scene, score_scene
from .inputs import checkpoint_inputs
from .statistics import summarize

__all__ = [
    "Term",
    "TERMS",
    "DECODERS",
    "SWEEP_METRICS",
    "crosstalk_matrix",
    "vignetting_focal_for",
    "true_camera",
    "display_stokes",
    "cell_key",
    "cell_plan",
    "capture_scene",
    "score_capture",
    "run_cell",
    "run_cells",
    "sweep",
    "load_cells",
]

#: The decoder's belief about the rig: the nominal one, or the true (perturbed) one.
DECODERS = ("nominal", "true")
#: Scores per cell (keys of :func:`network.evaluation.score`) -> (header, digits, higher is better).
SWEEP_METRICS = {
    "normal_mae": ("normal MAE (deg)", 2, False),
    "albedo_psnr": ("albedo PSNR (dB)", 2, True),
    "roughness_rmse": ("roughness RMSE", 3, False),
    "metallic_rmse": ("metallic RMSE", 3, False),
}


@dataclass(frozen=True)
class Term:
    """One imperfection of the sweep.

    Attributes:
        name: key (cell file names, ``--terms``).
        label: what a level means, for tables and plots.
        levels: the levels, ``levels[0]`` the nominal rig, growing to the worst case.
        invertible: whether a decoder given the true rig can undo it (else no ``true`` cells).
    """

    name: str
    label: str
    levels: tuple[float, ...]
    invertible: bool = True


#: The imperfections and their levels (worst cases justified in ``docs/robustness.md``).
TERMS: tuple[Term, ...] = (
    Term("crosstalk", "cross-talk, off-diagonal (adjacent colours; R-B half)", (0.0, 0.02, 0.05, 0.10, 0.15)),
    Term("ambient", "ambient light, fraction of the display radiance", (0.0, 0.01, 0.025, 0.05, 0.10)),
    Term("vignetting", "vignetting, light lost at the frame corner (cos^4)", (0.0, 0.05, 0.10, 0.20, 0.30)),
    Term("qwp_retardance", "QWP retardance error (deg, every channel)", (0.0, 2.5, 5.0, 7.5, 10.0)),
    Term("qwp_angle", "QWP fast-axis error (deg)", (0.0, 1.0, 2.0, 3.5, 5.0)),
    Term("extinction", "analyzer extinction ratio (nominal 100)", (100.0, 60.0, 40.0, 30.0, 20.0)),
    Term("display_dop", "display degree of polarization", (1.0, 0.99, 0.97, 0.95, 0.90), invertible=False),
    Term("display_angle", "display polarization-angle error (deg)", (0.0, 1.0, 2.0, 3.5, 5.0), invertible=False),
)
_BY_NAME = {t.name: t for t in TERMS}


def _term(name: str) -> Term:
    if name not in _BY_NAME:
        raise ValueError(f"term must be one of {sorted(_BY_NAME)}; got {name!r}")
    return _BY_NAME[name]


def crosstalk_matrix(off: float) -> tuple[tuple[float, ...], ...]:
    """The cross-talk of one level: ``off`` between adjacent colours (R-G, G-B), ``off / 2`` between R and B.

    The colour filters of a Bayer sensor overlap most between neighbouring bands.

    >>> crosstalk_matrix(0.1)[0]
    (1.0, 0.1, 0.05)
    """
    return tuple(tuple(1.0 if r == c else off / abs(r - c) for r in range(3)) for c in range(3))


def vignetting_focal_for(loss: float, raw_shape: tuple[int, int]) -> float:
    """Focal length in raw pixels whose cos^4 falloff leaves ``1 - loss`` at the frame's corner pixel.

    Args:
        loss: fraction of the light lost at the corner pixel, in ``[0, 1)`` (0: no falloff, ``inf``).
        raw_shape: ``(H, W)`` of the raw frame (the optical axis at its centre).

    >>> from pbrdf.sensor.imperfections import vignetting_map
    >>> f = vignetting_focal_for(0.2, (64, 64))
    >>> round(float(vignetting_map((64, 64), f, (0.0, 0.0, 0.0))[0, 0]), 6)
    0.8
    """
    if not 0.0 <= loss < 1.0:
        raise ValueError(f"loss must be in [0, 1); got {loss}")
    if loss == 0.0:
        return math.inf
    h, w = raw_shape
    d = math.hypot(h / 2 - 0.5, w / 2 - 0.5)  # the corner pixel centre
    c = math.sqrt(1.0 - loss)  # cos^2 of the corner's field angle
    return d * math.sqrt(c / (1.0 - c))


def true_camera(
    term: str, level: float, nominal: CameraModel, *, display_radiance: float, raw_shape: tuple[int, int]
) -> CameraModel:
    """The camera model of the perturbed rig: ``nominal`` with ``term`` at ``level`` (display terms: unchanged).

    Args:
        term: a :data:`TERMS` name.
        level: its level (in the term's units: degrees for angles, a fraction or a ratio otherwise).
        nominal: the sample's camera model.
        display_radiance: the display's radiance (``rig.display.radiance``); ambient light is a fraction of it.
        raw_shape: ``(H, W)`` of the raw frames (vignetting).
    """
    t = _term(term)
    if level == t.levels[0] or not t.invertible:
        return nominal
    if term == "crosstalk":
        return nominal.replace(crosstalk=crosstalk_matrix(level))
    if term == "ambient":
        return nominal.replace(ambient=(level * display_radiance,) * 3)
    if term == "vignetting":
        return nominal.replace(vignetting_focal_px=vignetting_focal_for(level, raw_shape))
    if term == "qwp_retardance":
        return nominal.replace(qwp_retardance=tuple(d + math.radians(level) for d in nominal.qwp_retardance))
    if term == "qwp_angle":
        return nominal.replace(qwp_angle=nominal.qwp_angle + math.radians(level))
    return nominal.replace(extinction_ratio=(level,) * 3)  # extinction


def display_stokes(basis: Mapping[str, np.ndarray], dop: float = 1.0, angle_error_deg: float = 0.0) -> np.ndarray:
    """Stokes images ``(H, W, 3, 4)`` under a display of degree of polarization ``dop`` and angle ``pi/2 + error``.

    Args:
        basis: ``v``, ``h``, ``d``: the scene's Stokes images under the display polarized at 90, 0
            and 45 degrees (module docs).
        dop: degree of polarization in ``[0, 1]``.
        angle_error_deg: polarization-angle error in degrees.

    Returns:
        ``basis["v"]`` itself for the nominal display (bit-identical capture), else float64.

    >>> v, h = np.zeros((1, 1, 3, 4)), np.ones((1, 1, 3, 4))
    >>> display_stokes({"v": v, "h": h, "d": h}, dop=0.0)[0, 0, 0].tolist()  # unpolarized: the mean of v and h
    [0.5, 0.5, 0.5, 0.5]
    """
    if not 0.0 <= dop <= 1.0:
        raise ValueError(f"dop must be in [0, 1]; got {dop}")
    if dop == 1.0 and angle_error_deg == 0.0:
        return basis["v"]
    v, h, d = (np.asarray(basis[k], dtype=np.float64) for k in ("v", "h", "d"))
    a = (h + v) / 2
    theta = math.pi / 2 + math.radians(angle_error_deg)
    return a + dop * (math.cos(2 * theta) * (h - a) + math.sin(2 * theta) * (d - a))


def _display_levels(term: str, level: float) -> tuple[float, float]:
    """``(dop, angle_error_deg)`` of a cell."""
    if term == "display_dop":
        return level, 0.0
    if term == "display_angle":
        return 1.0, level
    return 1.0, 0.0


def cell_key(term: str, index: int, decoder: str) -> str:
    """File stem of a cell: ``nominal`` for every level 0, else ``TERM-LEVELINDEX-DECODER``.

    >>> cell_key("crosstalk", 0, "true"), cell_key("crosstalk", 2, "true")
    ('nominal', 'crosstalk-2-true')
    """
    if decoder not in DECODERS:
        raise ValueError(f"decoder must be one of {DECODERS}; got {decoder!r}")
    return "nominal" if index == 0 else f"{term}-{index}-{decoder}"


def cell_plan(terms: Sequence[str] | None = None) -> list[tuple[str, int, str]]:
    """The cells of a sweep, ``(term, level index, decoder)``: the nominal cell first, then per term and level.

    >>> [c for c in cell_plan(["display_dop"])][:3]
    [('nominal', 0, 'nominal'), ('display_dop', 1, 'nominal'), ('display_dop', 2, 'nominal')]
    >>> len(cell_plan())
    57
    """
    plan = [("nominal", 0, "nominal")]
    for name in terms if terms is not None else [t.name for t in TERMS]:
        t = _term(name)
        for i in range(1, len(t.levels)):
            plan += [(name, i, dec) for dec in (DECODERS if t.invertible else DECODERS[:1])]
    return plan


def capture_scene(
    folder: str | Path,
    basis: Mapping[str, np.ndarray],
    capture: pcapture.Capture,
    sample_seed: int,
    term: str,
    level: float,
    decoder: str,
) -> Path:
    """Write the capture folder of one scene through the perturbed rig, with the decoder's camera model.

    Args:
        folder: the capture folder to write (must not exist or be empty).
        basis: the scene's Stokes basis (:func:`display_stokes`), on the rendered grid ``(H, W, 3, 4)``.
        capture: the sample's own capture (its camera model is the nominal one; its metadata is kept).
        sample_seed: the sample's seed (the capture noise: ``default_rng([sample_seed, 1])``; dark
            frames ``[sample_seed, 2]``).
        term: a :data:`TERMS` name or ``"nominal"``.
        level: the term's level.
        decoder: ``"nominal"`` or ``"true"`` (module docs).

    Returns:
        The folder: raws (and, for ambient light with the true decoder, dark frames) and ``capture.json``.
    """
    nominal = capture.model
    up = display_stokes(basis, *_display_levels(term, level))
    up = np.repeat(np.repeat(up, 2, axis=0), 2, axis=1)  # one rendered pixel per 2x2 raw block, as the split
    if term == "nominal":
        model = nominal
    else:
        radiance = float(capture.meta.rig.display.radiance)
        model = true_camera(term, level, nominal, display_radiance=radiance, raw_shape=up.shape[:2])
    raws = simulate_capture(up, model, rng=np.random.default_rng([sample_seed, 1]))
    dark = None
    if decoder == "true" and any(model.ambient):  # the display off: the room light and the sensor's offset
        dark = dark_frames(model, up.shape[:2], sample_seed, stream=2, dtype=up.dtype)
    believed = model if decoder == "true" else nominal
    extra = dict(capture.metadata)
    if isinstance(extra.get("rig"), dict):  # the rig file's camera model is the decoder's belief too
        extra["rig"] = {**extra["rig"], "camera": {**extra["rig"].get("camera", {}), "model": believed.to_dict()}}
    return pcapture.save_capture(folder, raws, believed, extra=extra, dark=dark)


def score_capture(model, checkpoint, root: Path, index: int, stats, folder: Path, rig=None) -> dict[str, Any]:
    """One scene's row (``index``, ``pixels``, ``mask_iou``, ``ours``): the model on the capture in ``folder``.

    ``rig`` (a calibrated :class:`pbrdf.sensor.rig.Rig`) decodes it as ``headless/infer.py --rig`` does.
    """
    scene = predict_scene(model, checkpoint_inputs(checkpoint), root, index, stats, baseline=False, capture=folder,
                          input_scale=checkpoint_input_scale(checkpoint), rig=rig)  # fmt: skip
    scene.intrinsics = None  # no depth integration: normals are scored directly
    row = score_scene(scene, lpips=False)
    return {"index": index, "pixels": row["pixels"], "mask_iou": row["mask_iou"], "ours": row["ours"]}


def _cell_rows(model, checkpoint, root: Path, indices, stats, basis_fn, term, level, decoder) -> list[dict]:
    """Per-scene rows of one cell: pixels, mask IoU and the model's scores."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="robustness-") as tmp:
        for i in indices:
            paths = psample.sample_paths(root, i)
            meta = psample.check_complete(root, i, verify_hash=False)
            cap = pcapture.load_capture(paths.raw)
            folder = capture_scene(Path(tmp) / f"{i:06d}", basis_fn(i), cap, int(meta["sample_seed"]), term, level,
                                   decoder)  # fmt: skip
            rows.append(score_capture(model, checkpoint, root, i, stats, folder))
            shutil.rmtree(folder)
    return rows


def run_cell(
    model,
    checkpoint: Mapping[str, Any],
    root: str | Path,
    indices: Sequence[int],
    stats: Mapping[str, Any],
    basis_fn: Callable[[int], Mapping[str, np.ndarray]],
    term: str,
    level_index: int,
    decoder: str,
) -> dict[str, Any]:
    """Score the model on ``indices`` of ``root`` captured through the rig of one cell.

    Args:
        model: the loaded model.
        checkpoint: its checkpoint dict (input variant and scale).
        root: a rendered split with raw brackets.
        indices: the scenes scored.
        stats: training statistics (the constant answer of :func:`network.evaluation.predict_scene`).
        basis_fn: scene index -> its Stokes basis (:func:`display_stokes`).
        term: a :data:`TERMS` name or ``"nominal"``.
        level_index: index into the term's levels (0: the nominal rig).
        decoder: one of :data:`DECODERS`.

    Returns:
        JSON-ready cell: ``term``, ``level_index``, ``level``, ``decoder``, ``scenes``, ``rows``
        (per scene), ``summary`` (metric -> :func:`network.statistics.summarize`), ``seconds``.
    """
    if decoder == "true" and term != "nominal" and not _term(term).invertible:
        raise ValueError(f"term {term!r} acts on the scene's light: no decoder inverts it (decoder must be 'nominal')")
    level = 0.0 if term == "nominal" else _term(term).levels[level_index]
    t0 = time.perf_counter()
    rows = _cell_rows(model, checkpoint, Path(root), list(indices), stats, basis_fn, term, level, decoder)
    return {
        "term": term,
        "level_index": level_index,
        "level": level,
        "decoder": decoder,
        "scenes": [r["index"] for r in rows],
        "rows": rows,
        "summary": _summary(rows),
        "seconds": time.perf_counter() - t0,
    }


def _summary(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    w = [r["pixels"] for r in rows]
    out = {k: summarize([r["ours"][k] for r in rows], w) for k in SWEEP_METRICS}
    out["mask_iou"] = summarize([r["mask_iou"] for r in rows])
    return out


def load_cells(folder: str | Path) -> dict[str, dict[str, Any]]:
    """The finished cells in ``folder`` (``*.json``), by :func:`cell_key`."""
    return {p.stem: loads_strict(p.read_text()) for p in sorted(Path(folder).glob("*.json"))}


def run_cells(
    plan: Sequence[tuple[str, Callable[[], dict[str, Any]]]],
    cells_dir: str | Path,
    indices: Sequence[int],
    *,
    resume: bool = False,
    log: Callable[[str], None] | None = None,
) -> dict[str, dict[str, Any]]:
    """Compute each ``(key, compute)`` of ``plan`` into ``cells_dir/KEY.json``, keeping finished ones on ``resume``.

    Raises:
        ValueError: ``resume`` with a cell of other scenes than ``indices`` in ``cells_dir``.
    """
    out = Path(cells_dir)
    out.mkdir(parents=True, exist_ok=True)
    done = load_cells(out) if resume else {}
    cells = {}
    for n, (key, compute) in enumerate(plan, 1):
        if key in done:
            if done[key]["scenes"] != list(indices):
                raise ValueError(f"{out / key}.json: scored scenes {done[key]['scenes']}, not {list(indices)}; "
                                 "use another output folder")  # fmt: skip
            cells[key] = done[key]
            if log:
                log(f"[{n}/{len(plan)}] {key}: done before, skipped")
            continue
        cells[key] = c = compute()
        atomic_write_text(out / f"{key}.json", dumps_strict(c) + "\n")
        if log:
            s, level = c["summary"], f" (level {c['level']:g})" if "level" in c else ""
            log(f"[{n}/{len(plan)}] {key}{level}: normal MAE {s['normal_mae']['mean']:.2f} deg, albedo PSNR "
                f"{s['albedo_psnr']['mean']:.2f} dB, roughness RMSE {s['roughness_rmse']['mean']:.3f}, "
                f"{c['seconds']:.0f} s")  # fmt: skip
    return cells


def sweep(
    model,
    checkpoint: Mapping[str, Any],
    root: str | Path,
    indices: Sequence[int],
    stats: Mapping[str, Any],
    basis_fn: Callable[[int], Mapping[str, np.ndarray]],
    cells_dir: str | Path,
    *,
    terms: Sequence[str] | None = None,
    resume: bool = False,
    log: Callable[[str], None] | None = None,
) -> dict[str, dict[str, Any]]:
    """Run every cell of :func:`cell_plan` into ``cells_dir`` (one JSON each); returns them by key.

    Args:
        model: the loaded model.
        checkpoint: its checkpoint dict.
        root: a rendered split with raw brackets.
        indices: the scenes scored.
        stats: training statistics.
        basis_fn: scene index -> its Stokes basis (:func:`display_stokes`).
        cells_dir: folder of the cell files (created).
        terms: the :data:`TERMS` names to sweep (default all).
        resume: keep the cells already in ``cells_dir`` for the same scenes (a killed sweep goes on);
            without it they are computed again.
        log: called with one progress line per cell.

    Raises:
        ValueError: ``resume`` with a cell of other scenes in ``cells_dir``.
    """
    plan = [(cell_key(t, i, d), functools.partial(run_cell, model, checkpoint, root, indices, stats, basis_fn, t, i, d))
            for t, i, d in cell_plan(terms)]  # fmt: skip
    return run_cells(plan, cells_dir, indices, resume=resume, log=log)
