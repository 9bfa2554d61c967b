"""The reconstruct job passes the panel's object distance to headless/infer.py (--distance)."""

from blender_addon.core.reconstruct_job import command_line


def test_distance_goes_to_the_command_line_only_when_set():
    assert command_line("py", "cap", "o", distance=0.85)[-2:] == ["--distance", "0.85"]
    assert "--distance" not in command_line("py", "cap", "o", distance=None)
    assert "--distance" not in command_line("py", "cap", "o", distance=0.0)  # the panel's 0: capture.json's
