"""Time network/refine.py on a 192 px crop: a scene zoomed so its mask box is 192 px (5 runs).

PYTHONPATH=. python tools/refine_time.py [ROOT [INDEX]] [--roughness] [--runs N]

The default scene is test-procedural scene 0; ``--roughness`` times the whole refinement (albedo and
roughness, :func:`network.refine.refine` with ``roughness=True``). Wall and CPU seconds: on a shared,
loaded machine the wall time of a ``nice`` process says more about the neighbours than the refinement.
One torch thread per process when ``OMP_NUM_THREADS=1`` is set (the shared machine), else two.
"""

import argparse
import os
import time

import numpy as np
import torch
from scipy import ndimage

from network.checkpoint import load_checkpoint
from network.infer import DEFAULT_CHECKPOINT, load_input, predict
from network.refine import refine
from pbrdf.data import sample as psample
from pbrdf.sensor.rig import Rig

p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
p.add_argument("root", nargs="?", default="out/splits/test-procedural")
p.add_argument("index", nargs="?", type=int, default=0)
p.add_argument("--roughness", action="store_true")
p.add_argument("--runs", type=int, default=5)
args = p.parse_args()
torch.set_num_threads(1 if os.environ.get("OMP_NUM_THREADS") == "1" else 2)
model, ck = load_checkpoint(DEFAULT_CHECKPOINT)
_, meta = psample.read_sample(args.root, args.index, keys=("mask",))
paths = psample.sample_paths(args.root, args.index)
inp = load_input(paths.raw if paths.raw.is_dir() else paths.sidecar)
ys, xs = np.nonzero(inp.mask)
side = max(np.ptp(ys), np.ptp(xs)) + 1
f = 192 / side
maps = ndimage.zoom(inp.maps, (f, f, 1), order=1).astype(np.float32)
mask = ndimage.zoom(inp.mask.astype(float), f, order=0) > 0.5
k = inp.intrinsics.copy()
k[:2] *= f
print("mask bbox", np.ptp(np.nonzero(mask)[0]) + 1, "pixels", mask.sum())
pred = predict(model, maps, mask, inputs=ck["inputs"], input_scale=ck["input_scale"], radiance=inp.radiance)
ts, cpu = [], []
for _ in range(args.runs):
    t, c = time.perf_counter(), time.process_time()
    r = refine(pred, maps, k, Rig.from_dict(meta["rig"]), inp.radiance, 0.7, roughness=args.roughness)
    ts.append(time.perf_counter() - t)
    cpu.append(time.process_time() - c)
print("refine wall s", [round(x, 2) for x in ts], "median", round(float(np.median(ts)), 2))
print("refine CPU s (all threads)", [round(x, 2) for x in cpu], "median", round(float(np.median(cpu)), 2), r.message)
