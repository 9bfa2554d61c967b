"""tools/roughness_corr.py on a real rendered split: every object classified and measured as the sidecar says."""

import importlib.util
from pathlib import Path

import pytest

pytestmark = [pytest.mark.mitsuba, pytest.mark.usefixtures("torch_one_thread")]
ROOT = Path(__file__).resolve().parents[2]


def _tool(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def split(tmp_path_factory):
    """Six 64 px scenes of 1-2 analytic objects (metals among them), raw brackets kept."""
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate

    root = tmp_path_factory.mktemp("rough")
    generate(GenerateConfig(out=root, count=6, resolution=64, spp=4, seed=11, keep_raw=True, objects=(1, 2)),
             progress=False)  # fmt: skip
    return root


def test_roughness_rows_match_the_sidecar_materials(split, capsys):
    from pbrdf.data import sample as psample
    from tools._capture_scenes import capture_scenes, load

    tool = _tool("roughness_corr")
    scenes = list(capture_scenes(*load(None), split, 6))
    assert all(sc.preds["baseline"] == {} for sc in scenes)  # the model alone: photometric stereo not run
    rows = tool.object_rows(scenes)
    assert rows, "no object with 100 masked pixels"
    kinds = set()
    for row in rows:
        _, meta = psample.read_sample(split, row["scene"])
        material = meta["materials"][meta["objects"][row["object"]]["material"]]
        kinds.add(row["kind"])
        # The truth side is the sidecar's material, independent of the EXR maps the tool reads.
        assert row["kind"] == ("metal" if material["metallic"] >= 0.5 else "dielectric"), (row, material)
        assert row["truth"] == pytest.approx(material["roughness"], abs=1e-3)
        assert 0.0 <= row["pred"] <= 1.0
    assert kinds == {"metal", "dielectric"}, f"the fixture should hold both kinds, got {kinds}"
    assert tool.main(["--input", str(split), "--limit", "6"]) == 0
    out = capsys.readouterr().out
    assert f"{split.name:16s} dielectric" in out and "all              metal" in out
