"""Time network/refine.py on a 192 px crop: test-procedural scene 0 zoomed so its mask box is 192 px (5 runs).

PYTHONPATH=. python tools/refine_time.py
"""

import sys
import time

import numpy as np
import torch
from scipy import ndimage

from network.checkpoint import load_checkpoint
from network.infer import DEFAULT_CHECKPOINT, load_input, predict
from network.refine import refine
from pbrdf.data import sample as psample
from pbrdf.sensor.rig import Rig

torch.set_num_threads(2)
model, ck = load_checkpoint(DEFAULT_CHECKPOINT)
root = sys.argv[1] if len(sys.argv) > 1 else "out/splits/test-procedural"
_, meta = psample.read_sample(root, 0, keys=("mask",))
inp = load_input(psample.sample_paths(root, 0).raw)
ys, xs = np.nonzero(inp.mask)
side = max(ys.ptp(), xs.ptp()) + 1
f = 192 / side
maps = ndimage.zoom(inp.maps, (f, f, 1), order=1).astype(np.float32)
mask = ndimage.zoom(inp.mask.astype(float), f, order=0) > 0.5
k = inp.intrinsics.copy()
k[:2] *= f
print("mask bbox", np.ptp(np.nonzero(mask)[0]) + 1, "pixels", mask.sum())
pred = predict(model, maps, mask, inputs=ck["inputs"], input_scale=ck["input_scale"], radiance=inp.radiance)
ts = []
for _ in range(5):
    t = time.perf_counter()
    r = refine(pred, maps, k, Rig.from_dict(meta["rig"]), inp.radiance, 0.7)
    ts.append(time.perf_counter() - t)
print("refine s", [round(x, 2) for x in ts], "median", np.median(ts), r.message)
