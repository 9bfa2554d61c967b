"""The import graph of the four packages: one direction, no cycles, bpy only in the add-on; module sizes.

Layers: ``pbrdf`` at the bottom; ``blender_addon.core`` (the scene side) and ``network`` (learning)
beside each other on it, neither importing the other; the bpy half of ``blender_addon`` on
``core``; ``headless`` on top, the only place that joins the scene side and the network.
Every ``import`` statement counts, including those deferred into functions or behind
``TYPE_CHECKING``: a deferred import is still a dependency. No module grows past
:data:`MAX_LINES` lines unless its docstring says why (``Kept in one module:`` and the reason).
"""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pbrdf", "blender_addon", "network", "headless")
BPY_MODULES = {"bpy", "bmesh", "mathutils", "bpy_extras", "bl_math", "gpu", "idprop"}
#: Longest module (lines) without a stated reason; split a longer one along its seams.
MAX_LINES = 630
#: How a longer module states why it stays whole: this phrase, then the reason (a few words at least).
KEPT_WHOLE = re.compile(r"Kept in one module:\s*(\S+\s+){2,}\S")


def layer(module: str) -> str:
    """The layer a project module belongs to."""
    if module.startswith("blender_addon.core") or module == "blender_addon.core":
        return "core"
    if module == "blender_addon" or module.startswith("blender_addon."):
        return "addon"
    return module.split(".")[0]


# layer -> layers it may import (itself included)
ALLOWED = {
    "pbrdf": {"pbrdf"},
    "core": {"pbrdf", "core"},
    "network": {"pbrdf", "network"},
    "addon": {"pbrdf", "core", "addon"},
    "headless": {"pbrdf", "core", "network", "addon", "headless"},
}


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def all_modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if "_vendor" in path.parts:
                continue
            out[module_name(path)] = path
    return out


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Project modules and third-party top-level names ``name`` imports (relative ones resolved)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_pkg = path.name == "__init__.py"
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.add(target)
            for alias in node.names:  # `from pkg import module`
                sub = f"{target}.{alias.name}"
                if sub in modules:
                    found.add(sub)
    resolved = set()
    for target in found:
        # the longest project module that is a prefix of the target
        parts = target.split(".")
        for k in range(len(parts), 0, -1):
            cand = ".".join(parts[:k])
            if cand in modules:
                resolved.add(cand)
                break
        else:
            resolved.add(parts[0])
    resolved.discard(name)
    return resolved


@pytest.fixture(scope="module")
def graph():
    modules = all_modules()
    return {name: imports_of(name, path, modules) for name, path in modules.items()}, modules


def test_every_package_is_found(graph):
    g, modules = graph
    for pkg in PACKAGES:
        assert pkg in modules
    assert "pbrdf.sensor.rig" in modules  # the rig lives in the bottom layer


def test_imports_point_down(graph):
    g, modules = graph
    bad = []
    for name, deps in g.items():
        for dep in deps:
            if dep in modules and layer(dep) not in ALLOWED[layer(name)]:
                bad.append(f"{name} ({layer(name)}) imports {dep} ({layer(dep)})")
    assert not bad, "upward or sideways imports:\n" + "\n".join(sorted(bad))


def test_bpy_only_in_the_addon(graph):
    g, _ = graph
    bad = [f"{n} imports {sorted(d & BPY_MODULES)}" for n, d in g.items() if d & BPY_MODULES and layer(n) != "addon"]
    assert not bad, "\n".join(bad)


def test_pbrdf_needs_no_renderer_or_torch(graph):
    g, _ = graph
    bad = []
    for name, deps in g.items():
        if layer(name) != "pbrdf":
            continue
        if deps & {"mitsuba", "drjit"}:
            bad.append(f"{name} imports mitsuba/drjit")
        if "torch" in deps and name != "pbrdf.expansion.generator":
            bad.append(f"{name} imports torch")
    assert not bad, "\n".join(bad)


def find_cycle(g: dict[str, set[str]]) -> list[str] | None:
    """One import cycle among project modules (a list of names, first == last), or None."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for dep in sorted(g.get(node, ())):
            if dep not in g:
                continue
            # a package's __init__ importing its own sub-modules is not a cycle of concepts
            if dep.startswith(node + "."):
                continue
            if state.get(dep) == 1:
                return stack[stack.index(dep) :] + [dep]
            if dep not in state:
                found = visit(dep)
                if found:
                    return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(g):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def test_no_import_cycles(graph):
    g, _ = graph
    cycle = find_cycle(g)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_cycle_finder_finds_a_planted_cycle():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert find_cycle(g) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def oversized_modules(paths: list[Path], max_lines: int = MAX_LINES, root: Path = ROOT) -> list[str]:
    """Files longer than ``max_lines`` whose module docstring does not say why they are kept in one module."""
    bad = []
    for path in paths:
        text = path.read_text()
        lines = len(text.splitlines())
        if lines <= max_lines:
            continue
        doc = ast.get_docstring(ast.parse(text, filename=str(path))) or ""
        if not KEPT_WHOLE.search(doc):
            bad.append(f"{path.relative_to(root)}: {lines} lines")
    return sorted(bad)


def test_modules_stay_small(graph):
    _, modules = graph
    bad = oversized_modules(list(modules.values()))
    assert not bad, (
        f"modules over {MAX_LINES} lines (split them along their seams, or say why in the docstring: "
        f"'Kept in one module: <reason>'):\n" + "\n".join(bad)
    )


def test_size_check_accepts_a_stated_reason_only(tmp_path):
    body = "".join(f"x{i} = {i}\n" for i in range(20))
    files = {
        "plain.py": body,
        "kept.py": '"""Big.\n\nKept in one module: the five classes are one document."""\n' + body,
        "no_reason.py": '"""Big.\n\nKept in one module:\n"""\n' + body,
        "short.py": "x = 1\n",
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    bad = oversized_modules([tmp_path / name for name in files], max_lines=10, root=tmp_path)
    assert [b.split(":")[0] for b in bad] == ["no_reason.py", "plain.py"]
