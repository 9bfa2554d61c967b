"""Collection rules for the doctests of the four packages (``--doctest-modules``).

Without the bpy wheel (``pytest -m "not bpy"`` in an environment without the ``bpy`` extra) the
add-on modules that import bpy at module level cannot be imported, so their doctests are not
collected; everything else is. Fixtures live in ``tests/conftest.py``.
"""

import ast
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parent
BPY_MODULES = {"bpy", "bmesh", "mathutils", "bpy_extras", "gpu", "idprop"}


def imports_bpy_at_import_time(path: Path) -> bool:
    """Whether the module's top-level statements (not function bodies) import a bpy module."""
    tree = ast.parse(path.read_text(), filename=str(path))
    pending = list(tree.body)
    while pending:
        node = pending.pop()
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] in BPY_MODULES for a in node.names):
            return True
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in BPY_MODULES:
            return True
        if isinstance(node, ast.If | ast.Try):
            pending.extend(node.body + node.orelse + getattr(node, "finalbody", []))
            for handler in getattr(node, "handlers", []):
                pending.extend(handler.body)
    return False


collect_ignore_glob = ["out/*", "dist/*", ".venv*/*", "examples/*", "models/*"]
collect_ignore = ["tools"]
if importlib.util.find_spec("bpy") is None:
    collect_ignore += [
        str(p.relative_to(ROOT))
        for p in sorted((ROOT / "blender_addon").rglob("*.py"))
        if imports_bpy_at_import_time(p)
    ]
