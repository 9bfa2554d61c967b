"""``capture.json`` is opened and parsed in one module only: :mod:`pbrdf.data.capture`.

Every other module gets its keys (camera model, rig, radiometry, intrinsics, ``distance_m``)
from ``load_capture`` / ``read_capture_meta``. A grep over the source of the four packages with
the AST: a call that reads a file (``open``, ``read_text``, ``read_bytes``, ``json.load(s)``,
``read_json_object``, or a helper of the same module that calls a JSON reader) whose argument or
receiver is ``capture.json`` (the name ``CAPTURE_JSON``, the literal, or a variable assigned from
either in the same function).
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pbrdf", "network", "headless", "blender_addon")
HOME = "pbrdf/data/capture.py"
_TOKENS = ("CAPTURE_JSON", "capture.json")
_READERS = {"open", "read_text", "read_bytes", "load", "loads", "loads_strict", "read_json_object"}
_JSON_READERS = {"load", "loads", "loads_strict", "read_json_object"}


def _name(func: ast.expr) -> str | None:
    return func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else None


def _calls(node: ast.AST) -> list[ast.Call]:
    return [n for n in ast.walk(node) if isinstance(n, ast.Call)]


def capture_json_readers(text: str) -> list[int]:
    """Line numbers of the calls in ``text`` (a module's source) that read ``capture.json``."""
    tree = ast.parse(text)
    # module functions that parse JSON: a call to them reads their argument as JSON
    helpers = {
        f.name
        for f in ast.walk(tree)
        if isinstance(f, ast.FunctionDef) and any(_name(c.func) in _JSON_READERS for c in _calls(f))
    }
    scopes = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)] + [tree]
    hits = []
    for scope in scopes:
        derived = set()
        for node in ast.walk(scope):
            if isinstance(node, ast.Assign) and any(t in ast.unparse(node.value) for t in _TOKENS):
                derived |= {t.id for t in node.targets if isinstance(t, ast.Name)}

        def names_capture_json(expr: ast.expr) -> bool:
            source = ast.unparse(expr)
            used = {n.id for n in ast.walk(expr) if isinstance(n, ast.Name)}
            return any(t in source for t in _TOKENS) or bool(used & derived)  # noqa: B023

        for call in _calls(scope):
            name = _name(call.func)
            if name not in _READERS and name not in helpers:
                continue
            operands = [*call.args, *(k.value for k in call.keywords)]
            if isinstance(call.func, ast.Attribute) and name in ("read_text", "read_bytes"):
                operands.append(call.func.value)
            if any(names_capture_json(e) for e in operands):
                hits.append(call.lineno)
    return sorted(set(hits))


def test_capture_json_is_parsed_in_one_module():
    readers = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if "_vendor" in path.parts:
                continue
            lines = capture_json_readers(path.read_text(encoding="utf-8"))
            if lines:
                readers[path.relative_to(ROOT).as_posix()] = lines
    assert HOME in readers, "the finder no longer sees pbrdf.data.capture's own reading: fix the test"
    others = {k: v for k, v in readers.items() if k != HOME}
    assert not others, f"capture.json read outside {HOME} (use load_capture / read_capture_meta): {others}"


def test_finder_sees_the_ways_of_reading_it():
    seen = """
def a(folder):
    where = folder / CAPTURE_JSON
    return _obj(where)

def _obj(p):
    return json.loads(p.read_text())

def b(folder):
    return json.loads((folder / "capture.json").read_text())

def c(folder):
    with open(os.path.join(folder, "capture.json")) as f:
        return f.read()
"""
    assert capture_json_readers(seen) == [4, 10, 13]
    unseen = """
def d(folder):
    (folder / CAPTURE_JSON).write_text("{}")
    return (folder / CAPTURE_JSON).is_file(), json.loads((folder / "sidecar.json").read_text())
"""
    assert capture_json_readers(unseen) == []
