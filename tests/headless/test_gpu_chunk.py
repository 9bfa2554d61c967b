"""The GPU chunk script rehearsed on the CPU (tools/gpu_chunk.sh with DEVICE=cpu VARIANT=llvm), end to end.

Two invocations as two leases: the first renders 2 + 1 scenes (64 px, 4 spp: the documented smaller
override of the split's 192 px / 16 spp), packs them, starts `small` from the shipped model and trains 2
steps; the second carries the first's chunk state in, re-renders nothing and goes on to step 4.
"""

import gzip
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pbrdf.data.splits import MESH_CORPUS_DIR

ROOT = Path(__file__).resolve().parents[2]
EXPORTED = ("state.pt", "best.pt", "state.json", "log.csv.gz", "val.csv", "curves.png")

pytestmark = [pytest.mark.slow, pytest.mark.mitsuba]


def _chunk(tmp: Path, n: int, state: Path, stop: int) -> subprocess.CompletedProcess:
    env = {
        **os.environ, "PY": sys.executable, "DEVICE": "cpu", "VARIANT": "llvm", "SHARDS": "1", "COUNT": "2",
        "VAL_COUNT": "1", "PBRDF_COUNT": "2", "RESOLUTION": "64", "SPP": "4", "STEPS": "50", "STOP": str(stop),
        "BATCH": "2", "WORKERS": "0", "CKPT_EVERY": "2", "REWARM": "2", "LEASE_S": "3000", "DATA": str(tmp / "data"),
        "OUT": str(tmp / f"out{n}"), "STATE": str(state), "RUN": str(tmp / f"run{n}"), "OMP_NUM_THREADS": "2",
    }  # fmt: skip
    return subprocess.run(["bash", "tools/gpu_chunk.sh"], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)  # fmt: skip


def test_chunk_script_rehearsal_resumes_without_rerendering(tmp_path):
    if not (MESH_CORPUS_DIR / ".complete").is_file():
        pytest.skip(f"the mesh corpus {MESH_CORPUS_DIR} is missing (`make setup` unpacks it)")
    first = _chunk(tmp_path, 1, tmp_path / "no-state-yet", stop=2)
    assert first.returncode == 0, first.stderr[-3000:]
    out1 = tmp_path / "out1"
    for name in (*EXPORTED, "timings.txt"):
        assert (out1 / name).is_file(), name
    info = json.loads((out1 / "state.json").read_text())
    assert info["step"] == 2 and len(info["chunks"]) == 1 and info["chunks"][0]["device"] == "cpu"
    samples = sorted((tmp_path / "data" / "train-next" / "samples").glob("*.exr"))
    assert len(samples) == 2
    mtimes = [p.stat().st_mtime_ns for p in samples]

    second = _chunk(tmp_path, 2, out1, stop=4)  # a new lease: a fresh run folder, the first chunk's state
    assert second.returncode == 0, second.stderr[-3000:]
    info2 = json.loads((tmp_path / "out2" / "state.json").read_text())
    assert info2["step"] == 4 and [(c["start"], c["end"]) for c in info2["chunks"]] == [(0, 2), (2, 4)]
    assert [p.stat().st_mtime_ns for p in samples] == mtimes  # nothing re-rendered
    timings = (tmp_path / "out2" / "timings.txt").read_text()
    assert "rendered train-next: 2 samples (0 new)" in timings and "training from step 2 (re-warm from 2)" in timings
    log1, log2 = (gzip.decompress((tmp_path / f"out{n}" / "log.csv.gz").read_bytes()).decode().splitlines()
                  for n in (1, 2))  # fmt: skip
    assert [int(r.split(",")[0]) for r in log2[1:]] == [0, 1, 2, 3]  # one curve over both chunks
    assert log2[:3] == log1[:3]  # the first chunk's rows, carried on
