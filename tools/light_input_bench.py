"""Time and accuracy of the light input (network/light_input.py) and its cost in `small` (docs/measurements/network.md).

PYTHONPATH=. python tools/light_input_bench.py
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from network.bench.timing import time_call  # noqa: E402
from network.config import get_config  # noqa: E402
from network.light_input import light_channels  # noqa: E402
from network.model import PolarInverseModel  # noqa: E402
from pbrdf.sensor import projection  # noqa: E402
from pbrdf.sensor.rig import Rig  # noqa: E402


def median_ms(f: Callable[[], object], n: int) -> float:
    """Median wall time of ``n`` calls in ms (:func:`network.bench.timing.time_call`, no warm-up)."""
    return time_call(f, "light input", repeat=n, warmup=0)[0].median * 1e3


def main() -> None:
    """Print the light channels' time and error per grid, their size per distance, and the model's cost."""
    torch.set_num_threads(1)
    rig = Rig()
    k = projection.crop_intrinsics(rig.camera.intrinsics(), (724, 924, 1324, 1524), (192, 192))
    exact = light_channels(rig, k, (192, 192), 0.7, grid=None)
    for grid in (None, 24, 12):
        ms = median_ms(lambda g=grid: light_channels(rig, k, (192, 192), 0.7, grid=g), 3 if grid is None else 9)
        err = np.abs(light_channels(rig, k, (192, 192), 0.7, grid=grid) - exact).max() / np.abs(exact).max()
        print(f"192 px, grid {grid}: {ms:.1f} ms, max |error| / max |light| {err:.1e}")
    for d in (0.35, 0.5, 0.75, 1.0, 1.6):
        a = light_channels(rig, k, (192, 192), d)
        print(f"d {d} m: |Phi_R| {np.linalg.norm(a[0:3, 96, 96]):.3f}, |Phi_B| {np.linalg.norm(a[6:9, 96, 96]):.3f}")
    maps, mask = torch.rand(1, 9, 192, 192), torch.zeros(1, 1, 192, 192)
    mask[..., 30:160, 40:150] = 1
    light = torch.from_numpy(exact)[None]
    torch.manual_seed(0)
    blind = PolarInverseModel(get_config("small", image_size=192, canonical_size=128)).eval()
    lit = PolarInverseModel(get_config("small", image_size=192, canonical_size=128, light_input=True)).eval()
    lit.load_state_dict(blind.state_dict(), strict=False)
    with torch.no_grad():
        tb = median_ms(lambda: blind(maps, mask), 3)
        tl = median_ms(lambda: lit(maps, mask, light=light), 3)
        same = all(torch.equal(blind(maps, mask)[n], lit(maps, mask, light=light)[n]) for n in ("normal", "albedo"))
    print(f"small at 192 px, dense forward: blind {tb:.0f} ms, light {tl:.0f} ms (x{tl / tb:.3f}); equal: {same}")


if __name__ == "__main__":
    main()
