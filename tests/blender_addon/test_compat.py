"""blender_addon/compat.py: one minimum Blender version, its copies, and the one-line refusal (no bpy)."""

import ast
import tomllib
from pathlib import Path

import pytest

from blender_addon.compat import MIN_BLENDER, blender_refusal, version_text

ADDON = Path(__file__).resolve().parents[2] / "blender_addon"


def test_minimum_version_agrees_with_bl_info_and_manifest():
    """Blender reads bl_info and the manifest without importing the add-on: both repeat MIN_BLENDER."""
    tree = ast.parse((ADDON / "__init__.py").read_text())
    bl_info = next(
        ast.literal_eval(node.value)
        for node in tree.body
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "bl_info" for t in node.targets)
    )
    manifest = tomllib.loads((ADDON / "blender_manifest.toml").read_text())
    assert bl_info["blender"] == MIN_BLENDER
    assert tuple(int(v) for v in manifest["blender_version_min"].split(".")) == MIN_BLENDER


@pytest.mark.parametrize(
    ("version", "refused"),
    [((3, 4, 1), True), ((4, 1, 9), True), ((2, 93, 0), True), ((4, 2, 0), False), ((4, 5, 3), False),
     ((5, 0, 1), False)],
)  # fmt: skip
def test_refusal_names_the_minimum_and_the_running_version(version, refused):
    message = blender_refusal(version)
    if not refused:
        assert message is None
        return
    assert message == f"needs Blender 4.2 or later, this is {version_text(version)}"
    assert "\n" not in message
