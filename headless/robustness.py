"""Robustness sweep: the model's scores as each rig imperfection grows, the decoder told the nominal or the true rig.

    python headless/robustness.py --input out/splits/test-procedural [--limit 24] [--out DIR] [--resume]
                                  [--terms crosstalk ambient ...] [--checkpoint M] [--train-stats F] [--quiet]

For the first --limit scenes of a test split (with raw brackets), every imperfection of
network/robustness.py (cross-talk, ambient light, vignetting, QWP retardance and fast axis,
analyzer extinction, display degree of polarization and polarization angle) grows in five levels
from the nominal rig to a realistic worst case. Each level re-captures every scene through the
perturbed rig (the split's own noise draw) and scores the model (default: the shipped one) through
the capture path (decode, automatic mask, inference) twice: with capture.json giving the nominal
camera model, and giving the true one (with dark frames for ambient light). The display terms act
on the scene's light and have no true-rig column.

The scene's light comes from three renders per scene (display polarized at 90, 0 and 45 degrees,
the split's resolution, spp, seeds and Mitsuba variant), cached in OUT/basis/; the render at 90
degrees must reproduce the split's raw brackets bit for bit (a warning says when it does not: the
nominal cell then differs from a plain headless/evaluate.py run).

With --cases, instead of the one-term sweep: each named rig (network/robustness_calibrated.py:
every term at its worst level at once, rig_jitter draws at scale 2) re-captures every scene and
the model is scored with the decoder given the nominal rig, the rig estimated by the
self-calibration from synthetic targets of that rig (decoded as infer.py --rig rig.json), and the
true rig; paired against the unperturbed rig. Writes OUT/calibrated/{cells,rigs}/ and
OUT/calibrated.md; --pool-with OTHER_OUT ... adds a table over the scenes of every folder's cells.

Writes OUT/cells/KEY.json (one per term, level and decoder, atomically: with --resume a killed
sweep goes on from the finished cells), OUT/robustness.md (table and tolerances), OUT/robustness.png
(figure) and OUT/robustness.json. One progress line per cell. OUT defaults to INPUT/robustness.
"""

from __future__ import annotations

import argparse
import io
import logging
import sys
import time
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import held_warnings  # noqa: E402

#: Basis renders: key -> display polarization angle in degrees (network/robustness.py's v, h, d).
BASIS_ANGLES_DEG = {"v": 90.0, "h": 0.0, "d": 45.0}


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    from network.robustness import TERMS  # noqa: PLC0415
    from network.robustness_calibrated import case_names  # noqa: PLC0415

    parser = argparse.ArgumentParser(
        prog="robustness.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--input", type=Path, required=True, metavar="SPLIT", help="a rendered test split folder")
    parser.add_argument("--limit", type=int, default=24, help="score the first N scenes (default 24)")
    parser.add_argument("--out", type=Path, help="output folder (default INPUT/robustness)")
    parser.add_argument("--terms", nargs="+", choices=[t.name for t in TERMS], metavar="TERM",
                        help="imperfections to sweep (default all): " + ", ".join(t.name for t in TERMS))  # fmt: skip
    parser.add_argument("--cases", nargs="+", choices=case_names(), metavar="CASE",
                        help="score perturbed rigs with the nominal, calibrated and true decoders instead of the "
                        "sweep: " + ", ".join(case_names()))  # fmt: skip
    parser.add_argument("--pool-with", nargs="+", type=Path, default=[], metavar="OUT",
                        help="with --cases: other splits' output folders to pool into one more table")  # fmt: skip
    parser.add_argument("--resume", action="store_true", help="keep the finished cells in OUT/cells")
    parser.add_argument("--checkpoint", type=Path, help="model.pt/checkpoint.pt (default: the shipped model)")
    parser.add_argument("--train-stats", type=Path, help="training means (default: beside the checkpoint)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error, printed as one ``error:`` line)."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    return held_warnings(lambda: _run(args))


def render_basis(root: Path, index: int) -> dict:
    """The three Stokes images ``(H, W, 3, 4)`` float32 of sample ``index`` (:data:`BASIS_ANGLES_DEG`).

    Rendered as the split rendered it (its manifest's resolution and spp, the sidecar's spec,
    seeds and Mitsuba variant), only the display's polarization angle changed.

    Raises:
        ValueError: the sample's display is not the nominal one (polarized at 90 degrees, fully).
    """
    import dataclasses  # noqa: PLC0415
    import math  # noqa: PLC0415

    from blender_addon.core import render  # noqa: PLC0415
    from blender_addon.core.spec import SceneSpec  # noqa: PLC0415
    from pbrdf.data import dataset as pdataset  # noqa: PLC0415
    from pbrdf.data import sample as psample  # noqa: PLC0415

    manifest = pdataset.read_manifest(root)
    meta = psample.check_complete(root, index, verify_hash=False)
    spec = SceneSpec.from_dict(meta["spec"])
    display = spec.rig.display
    if abs(display.polarization_angle - math.pi / 2) > 1e-12 or display.degree_of_polarization != 1.0:
        raise ValueError(f"{root} sample {index}: the sweep starts from the nominal display (polarized at 90 deg)")
    settings = render.RenderSettings(resolution=manifest["resolution"], spp=manifest["spp"], variant=meta["variant"])
    out = {}
    for key, deg in BASIS_ANGLES_DEG.items():
        rig = dataclasses.replace(spec.rig, display=dataclasses.replace(display, polarization_angle=math.radians(deg)))
        out[key] = render.render_stokes(dataclasses.replace(spec, rig=rig), settings).stokes.astype("float32")
    return out


class BasisCache:
    """Scene index -> its basis, rendered once into ``folder/NNNNNN.npz`` (atomically) and read back after."""

    def __init__(self, root: Path, folder: Path) -> None:
        self.root, self.folder = root, folder
        self.not_reproduced: list[int] = []

    def path(self, index: int) -> Path:
        """The cache file of scene ``index``."""
        return self.folder / f"{index:06d}.npz"

    def ensure(self, index: int) -> None:
        """Render the basis of ``index`` unless cached; note when it does not reproduce the split's capture."""
        import numpy as np  # noqa: PLC0415

        from pbrdf.data import capture as pcapture  # noqa: PLC0415
        from pbrdf.data import sample as psample  # noqa: PLC0415
        from pbrdf.io.atomic import atomic_write_bytes  # noqa: PLC0415
        from pbrdf.sensor.camera import simulate_capture  # noqa: PLC0415

        if not self.path(index).is_file():
            basis = render_basis(self.root, index)
            buf = io.BytesIO()
            np.savez(buf, **basis)
            self.folder.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(self.path(index), buf.getvalue())
        basis = self(index)
        cap = pcapture.load_capture(psample.sample_paths(self.root, index).raw)
        seed = int(psample.check_complete(self.root, index, verify_hash=False)["sample_seed"])
        up = np.repeat(np.repeat(basis["v"], 2, axis=0), 2, axis=1)
        if not np.array_equal(simulate_capture(up, cap.model, rng=np.random.default_rng([seed, 1])), cap.raws):
            self.not_reproduced.append(index)

    def __call__(self, index: int) -> dict:
        """The cached basis of scene ``index`` (:meth:`ensure` first)."""
        import numpy as np  # noqa: PLC0415

        with np.load(self.path(index)) as z:
            return {k: z[k] for k in BASIS_ANGLES_DEG}


def _run(args: argparse.Namespace) -> int:
    import warnings  # noqa: PLC0415

    import torch  # noqa: PLC0415

    from network import robustness, robustness_report  # noqa: PLC0415
    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.constant import STATS_FILE, load_statistics  # noqa: PLC0415
    from network.infer import DEFAULT_CHECKPOINT  # noqa: PLC0415
    from pbrdf.data import dataset as pdataset  # noqa: PLC0415
    from pbrdf.data.splits import require_role  # noqa: PLC0415
    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415
    from pbrdf.io.strict_json import dumps_strict  # noqa: PLC0415

    torch.set_num_threads(1)  # one core: the machine is usually shared, and evaluate.py's workers use one too
    t0 = time.perf_counter()
    if args.limit < 1:
        raise ValueError(f"--limit must be >= 1, got {args.limit}")
    root = args.input
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: split folder not found")
    require_role(root, ("test",), "the robustness sweep")
    indices = sorted(pdataset.completed_indices(root, verify_hash=False))[: args.limit]
    if not indices:
        raise ValueError(f"{root}: no completed samples")
    out = args.out or root / "robustness"
    ckpt_path = args.checkpoint or Path(DEFAULT_CHECKPOINT)
    model, ckpt = load_checkpoint(ckpt_path)
    beside = ckpt_path.parent / STATS_FILE
    stats = load_statistics(
        args.train_stats or (beside if beside.is_file() else DEFAULT_CHECKPOINT.parent / STATS_FILE)
    )
    log = None if args.quiet else (lambda line: print(line, flush=True))
    cache = BasisCache(root, out / "basis")
    for n, i in enumerate(indices, 1):
        cache.ensure(i)
        if log:
            log(f"basis {n}/{len(indices)}: scene {i}")
    if cache.not_reproduced:
        warnings.warn(f"scenes {cache.not_reproduced}: the re-render does not reproduce the split's raw brackets "
                      "(another Mitsuba?); the nominal cell differs from a plain evaluation", stacklevel=1)  # fmt: skip
    if args.cases:
        return _calibrated(args, (model, ckpt, ckpt_path), root, indices, stats, cache, out, log, t0)
    cells = robustness.sweep(model, ckpt, root, indices, stats, cache, out / "cells", terms=args.terms,
                             resume=args.resume, log=log)  # fmt: skip
    head = f"Robustness of {ckpt_path} on {root} (scenes {indices[0]}-{indices[-1]}, {len(indices)} scenes)"
    tolerances = robustness_report.tolerance_table(cells)
    text = (f"{head}\n\n{robustness_report.sweep_table(cells)}\nLevel at which each score worsens by the limit "
            f"(paired per-scene mean; linear between levels):\n\n{tolerances}")  # fmt: skip
    files = [atomic_write_text(out / "robustness.md", text)]
    files.append(atomic_write_text(out / "robustness.json", dumps_strict({"scenes": indices, "cells": cells}) + "\n"))
    try:
        files.append(robustness_report.plot_sweep(cells, out / "robustness.png"))
    except ImportError:
        warnings.warn("matplotlib is not installed: no figure", stacklevel=1)
    print(text)
    print(f"{time.perf_counter() - t0:.0f} s; wrote " + ", ".join(str(f) for f in files))
    return 0


def _calibrated(args, loaded, root: Path, indices, stats, cache, out: Path, log, t0: float) -> int:
    """The --cases run: cells, tables (with the pooled one for --pool-with) and the written files."""
    from network import robustness_calibrated as rc  # noqa: PLC0415
    from network import robustness_report as rr  # noqa: PLC0415
    from network.robustness import load_cells  # noqa: PLC0415
    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415

    model, ckpt, ckpt_path = loaded
    cells = rc.calibration_sweep(model, ckpt, root, indices, stats, cache, out / "calibrated", cases=args.cases,
                                 resume=args.resume, log=log)  # fmt: skip
    head = f"{ckpt_path} on {root} (scenes {indices[0]}-{indices[-1]}, {len(indices)} scenes)"
    text = f"{head}\n\n{rr.calibration_table(cells)}\n{rr.calibration_verdicts(cells)}"
    if args.pool_with:
        pooled = {root.name: cells}
        for other in args.pool_with:
            pooled[other.name] = load_cells(other / "calibrated" / "cells")
        joined = rr.pool_cells(pooled)
        n = len(joined[rc.UNPERTURBED]["scenes"])
        text += (f"\nPooled over {', '.join(pooled)} ({n} scenes):\n\n{rr.calibration_table(joined)}\n"
                 f"{rr.calibration_verdicts(joined)}")  # fmt: skip
    path = atomic_write_text(out / "calibrated.md", text)
    print(text)
    print(f"{time.perf_counter() - t0:.0f} s; wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
