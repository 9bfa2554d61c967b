"""The reconstruct job passes the panel's object distance (--distance) and refine checkbox to headless/infer.py."""

from blender_addon.core.reconstruct_job import ReconstructJob, command_line


def test_distance_goes_to_the_command_line_only_when_set():
    assert command_line("py", "cap", "o", distance=0.85)[-2:] == ["--distance", "0.85"]
    assert "--distance" not in command_line("py", "cap", "o", distance=None)
    assert "--distance" not in command_line("py", "cap", "o", distance=0.0)  # the panel's 0: capture.json's


def test_refine_checkbox_off_is_no_refine_and_on_is_infers_default(tmp_path):
    """On (the default): no flag, so infer.py refines where the distance is known; off: --no-refine."""
    (tmp_path / "cap").mkdir()
    (tmp_path / "cap" / "capture.json").write_text("{}")
    on = ReconstructJob("py", tmp_path / "cap", tmp_path / "o").command()
    off = ReconstructJob("py", tmp_path / "cap", tmp_path / "o", refine=False, distance=0.8).command()
    assert "--refine" not in on and "--no-refine" not in on
    assert off[-3:] == ["--distance", "0.8", "--no-refine"] and "--refine" not in off
