"""Choose the photometric-stereo baseline's grey prior on tuning renders that no evaluation reads.

    python headless/render.py --out /tmp/tune-multi --count 24 --seed 777 --objects 1-3 --shapes train \
        --pbrdfs out/splits/pbrdfs-train --table-fraction 0.5 --keep-raw --resolution 128 --spp 16
    python headless/render.py --out /tmp/tune-single --count 24 --seed 778 --keep-raw --resolution 128 --spp 16
    python tools/tune_baseline_prior.py 24 /tmp/tune-multi /tmp/tune-single

Prints, per dataset, the baseline's mean normal error (deg, per scene, on the object pixels of
the automatic mask, through the real-capture path) for each prior weight.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from network import baseline  # noqa: E402
from network.infer import load_input  # noqa: E402
from network.metrics import normal_mae_deg  # noqa: E402
from pbrdf.data import sample as psample  # noqa: E402

PRIORS = (0.02, 0.2, 1.0, 3.0, 10.0)


def mean_error(root: str, count: int, prior: float) -> float:
    """Mean per-scene normal error of the baseline with ``grey_prior=prior`` on a dataset with raw brackets."""
    original = baseline.albedo_chromaticity
    baseline.albedo_chromaticity = functools.partial(original, grey_prior=prior)
    try:
        errs = []
        for idx in range(count):
            s, meta = psample.read_sample(root, idx, keys=("normal", "object"))
            inp = load_input(psample.sample_paths(root, idx).raw)
            maps, auto = inp.maps, inp.mask
            sel = (s["object"] >= 0) & auto
            if not sel.any():
                continue
            errs.append(normal_mae_deg(baseline.predict_sample(maps, auto, meta)["normal"], s["normal"], sel))
        return float(np.mean(errs))
    finally:
        baseline.albedo_chromaticity = original


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit("usage: tune_baseline_prior.py COUNT DATASET [DATASET ...]")
    for root in sys.argv[2:]:
        print(root, {p: round(mean_error(root, int(sys.argv[1]), p), 1) for p in PRIORS}, flush=True)
