"""headless/bench.py network --frame: a capture's stage profile and its strides against stride 1, in the JSON."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# The profile times the relief and the map writes as one stage: infer.py overlaps them (headless._overlap).
RELIEF = "relief depth integration, the maps written (EXR + PNG) meanwhile"


def _bench(tmp_path: Path, *extra: str) -> dict:
    out = tmp_path / "bench.json"
    cmd = [sys.executable, "headless/bench.py", "network", "--configs", "toy", "--no-train", "--skip-dense",
           "--no-reference", "--warmup", "0", "--out", str(out), "--quiet", *extra]  # fmt: skip
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return json.loads(out.read_text())


def test_frame_rows_profile_every_stage_and_compare_strides(tmp_path):
    frame = _bench(tmp_path, "--strides", "1", "2", "--frame", str(ROOT / "examples" / "capture"))["full_frame"]
    profile = frame["profile"]
    assert profile["stride"] == 1  # the example's 128 px object is below auto_stride's threshold
    assert profile["stages"]["per-pixel decoder"] > 0 and profile["stages"][RELIEF] > 0
    assert "| read the raw brackets |" in profile["table"]
    rows = frame["strides"]["rows"]
    assert list(rows) == ["stride_1", "stride_2"] and "stride 2" in rows["stride_2"]["what"]
    assert rows["stride_1"]["error_vs_stride_1"]["normal_deg_max"] == 0.0
    err = rows["stride_2"]["error_vs_stride_1"]
    assert 0.0 < err["normal_deg_p99"] <= err["normal_deg_max"] and err["albedo_rmse"] < 0.05
    # the refine variant: infer.py --no-refine's maps against its default refinement, side by side
    refine = frame["refine"]
    no, yes = refine["rows"]["no_refine"], refine["rows"]["refine"]
    assert "--no-refine" in no["what"] and "refine_input" in yes["what"] and refine["distance_m"] == 0.8331969976425171
    assert no["repeats"] == yes["repeats"] == len(refine["refine_seconds_all"]) == 3
    # each refined round is the predict plus the refinement: longer than the refinement alone
    assert all(w >= r > 0 for w, r in zip(yes["seconds_all"], refine["refine_seconds_all"], strict=True))
    assert refine["changed_maps"] == (["albedo"] if refine["refined"] else []), refine["message"]


def test_quick_leaves_the_frame_rows_out(tmp_path):
    assert "full_frame" not in _bench(tmp_path, "--quick", "--frame", str(ROOT / "examples" / "capture"))
