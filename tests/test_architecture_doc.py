"""docs/ARCHITECTURE.md names every module of the four packages, so its module tables stay complete.

The tables live under ``### `<package>/` ...`` headings; a row's first cell names modules in backticks relative
to that package (``polar/stokes.py``); a bare name after a name with a folder in the same cell shares its folder
(``bench/decode.py``, ``render.py``). Package ``__init__.py`` files need no row.
"""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("pbrdf", "network", "blender_addon", "headless")
DOC = ROOT / "docs" / "ARCHITECTURE.md"


def documented_modules(text: str) -> set[str]:
    """Repository-relative paths of the modules named in the doc's module tables."""
    named, package = set(), None
    for line in text.splitlines():
        heading = re.match(r"###\s+`([\w/]+)/`", line)
        if heading:
            package = heading.group(1)
            continue
        if line.startswith("#"):
            package = None
        if package is None or not line.startswith("|"):
            continue
        folder = ""
        for name in re.findall(r"`([\w/.]+\.py)`", line.split("|")[1]):
            if "/" in name:
                folder = name.rsplit("/", 1)[0] + "/"
                named.add(f"{package}/{name}")
            else:
                named.add(f"{package}/{folder}{name}")
    return named


def package_modules() -> set[str]:
    """Repository-relative paths of every module of the four packages but their ``__init__.py``."""
    return {
        p.relative_to(ROOT).as_posix()
        for pkg in PACKAGES
        for p in (ROOT / pkg).rglob("*.py")
        if p.name != "__init__.py" and "__pycache__" not in p.parts
    }


def test_every_module_is_in_the_architecture_doc():
    missing = sorted(package_modules() - documented_modules(DOC.read_text()))
    assert not missing, f"docs/ARCHITECTURE.md has no row for {missing}"


def test_the_doc_names_no_module_that_does_not_exist():
    stale = sorted(documented_modules(DOC.read_text()) - package_modules() - {f"{p}/__init__.py" for p in PACKAGES})
    assert not stale, f"docs/ARCHITECTURE.md names modules that do not exist: {stale}"


def test_the_parser_reads_folders_and_shared_folders():
    doc = "\n".join(["### `net/` — x", "| module | what |", "|---|---|", "| `bench/a.py`, `b.py` | y |",
                     "| `c.py` | z |",
                     "## Other", "| `d.py` | w |"])  # fmt: skip
    assert documented_modules(doc) == {"net/bench/a.py", "net/bench/b.py", "net/c.py"}
