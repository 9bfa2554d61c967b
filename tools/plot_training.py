"""Plot a training run's curves (loss per term, learning rate, validation normal MAE) and copy them for the docs.

    python tools/plot_training.py RUN_DIR --out docs/measurements/curves/NAME

Reads RUN_DIR/log.csv and RUN_DIR/val.csv (network.train) and writes OUT/curves.png, OUT/log.csv
(step, loss, the loss terms, lr, seconds) and OUT/val.csv: the curves a run's data leaves behind,
small enough to commit.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

KEEP = ("step", "loss", "normal", "albedo", "roughness", "metallic", "chromaticity", "real", "real_weight", "lr",
        "seconds")  # fmt: skip


def _rows(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return [r for r in csv.DictReader(f) if not r.get("skipped")]


def _smooth(values: list[float], k: int) -> list[float]:
    out, acc = [], []
    for v in values:
        acc.append(v)
        acc = acc[-k:]
        out.append(sum(acc) / len(acc))
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 without completed steps)."""
    parser = argparse.ArgumentParser(prog="plot_training.py", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("run", type=Path, help="training output folder (log.csv, val.csv)")
    parser.add_argument("--out", type=Path, required=True, help="folder for curves.png, log.csv, val.csv")
    args = parser.parse_args(argv)
    log, val = _rows(args.run / "log.csv"), _rows(args.run / "val.csv")
    if not log:
        print(f"error: {args.run / 'log.csv'}: no completed steps", file=sys.stderr)
        return 2
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    args.out.mkdir(parents=True, exist_ok=True)
    steps = [int(r["step"]) for r in log]
    k = max(1, len(log) // 50)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for key in ("loss", "normal", "albedo", "roughness", "metallic"):
        vals = [float(r[key]) for r in log if r.get(key)]
        if len(vals) == len(steps):
            axes[0].plot(steps, _smooth(vals, k), label=key)
    real = [(int(r["step"]), float(r["real"])) for r in log if r.get("real")]  # the steps with a real pass
    if real:
        axes[0].plot(*zip(*real, strict=True), "k--", label="real (re-render, unweighted)")
    axes[0].set(yscale="log", xlabel="step", title=f"training loss (running mean of {k})")
    axes[0].legend()
    axes[1].plot(steps, [float(r["lr"]) for r in log])
    if real:
        twin = axes[1].twinx()
        twin.plot(steps, [float(r.get("real_weight") or 0.0) for r in log], "k--")
        twin.set(ylabel="real-loss weight (dashed)")
    axes[1].set(xlabel="step", title="learning rate")
    if val:
        axes[2].plot([int(r["step"]) for r in val], [float(r["normal_mae_deg"]) for r in val], "o-")
    axes[2].set(xlabel="step", ylabel="deg", title="validation normal MAE")
    fig.suptitle(str(args.run))
    fig.tight_layout()
    fig.savefig(args.out / "curves.png", dpi=80)
    with open(args.out / "log.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(KEEP)
        w.writerows([[r.get(c, "") for c in KEEP] for r in log])
    with open(args.out / "val.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(("step", "normal_mae_deg", "samples"))
        w.writerows([[r["step"], r["normal_mae_deg"], r["samples"]] for r in val])
    print(f"wrote {args.out / 'curves.png'}, log.csv, val.csv ({len(log)} steps, {len(val)} validations)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
