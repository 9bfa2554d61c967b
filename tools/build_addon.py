"""Build the Blender extension zip (``make addon``).

Usage::

    python tools/build_addon.py --out DIR

Writes ``DIR/<id>-<version>.zip`` (id and version from ``blender_addon/blender_manifest.toml``,
e.g. ``polarimetric_inverse_rendering-0.1.0.zip``) and prints its path. The zip holds one
top-level folder named ``<id>/`` with the contents of ``blender_addon/`` (``blender_manifest.toml``,
``__init__.py``, the add-on modules, ``core/``) plus the project's bottom layer ``pbrdf/`` as
``<id>/_vendor/pbrdf/``, which the add-on puts on ``sys.path`` when Blender has no ``pbrdf`` of its
own. Caches (``__pycache__``, ``*.pyc``), hidden files and zips are left out. The build is
reproducible: sorted entries with a fixed timestamp, so the same sources give the same bytes.

Install it in Blender 4.2+ with Edit > Preferences > Get Extensions > Install from Disk (or drag
and drop the zip): extensions may keep the manifest in one top-level folder. The one folder also
makes the same zip a legacy add-on (Preferences > Add-ons > Install legacy Add-on, which refuses
an ``__init__.py`` at the zip's root and would scatter root files into ``scripts/addons/``).

Bad input (missing or invalid manifest, ``bl_info`` version different from the manifest's)
prints ``error: <message>`` on stderr and exits with status 2.
"""

from __future__ import annotations

import argparse
import ast
import io
import re
import sys
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # run as a script: make the repository root importable
    sys.path.insert(0, str(ROOT))

from pbrdf.io.atomic import atomic_write_bytes  # noqa: E402

ADDON_DIR = ROOT / "blender_addon"
VENDORED = {"pbrdf": ROOT / "pbrdf"}  # package name -> source folder, stored under _vendor/
MANIFEST = "blender_manifest.toml"
_REQUIRED = (
    "schema_version",
    "id",
    "version",
    "name",
    "tagline",
    "maintainer",
    "type",
    "blender_version_min",
    "license",
)
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # the earliest zip timestamp: reproducible archives


def read_manifest(addon_dir: Path = ADDON_DIR) -> dict:
    """The extension manifest, checked for the fields Blender requires and against ``bl_info``.

    Raises:
        FileNotFoundError: no manifest.
        ValueError: invalid TOML, a missing field, a bad id or version, or a ``bl_info`` version
            that differs from the manifest's.
    """
    path = addon_dir / MANIFEST
    if not path.is_file():
        raise FileNotFoundError(f"{path}: extension manifest not found")
    try:
        manifest = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{path}: invalid TOML: {e}") from None
    missing = [k for k in _REQUIRED if k not in manifest]
    if missing:
        raise ValueError(f"{path}: missing fields {missing}")
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", manifest["id"]):
        raise ValueError(f"{path}: id must be a Python identifier, got {manifest['id']!r}")
    if not re.fullmatch(r"\d+\.\d+\.\d+", manifest["version"]):
        raise ValueError(f"{path}: version must be MAJOR.MINOR.PATCH, got {manifest['version']!r}")
    bl_version = _bl_info_version(addon_dir / "__init__.py")
    if bl_version != manifest["version"]:
        raise ValueError(
            f"bl_info version {bl_version} in __init__.py differs from the manifest's {manifest['version']}"
        )
    return manifest


def _bl_info_version(init: Path) -> str:
    """``bl_info["version"]`` of an add-on ``__init__.py`` as ``"MAJOR.MINOR.PATCH"`` (read, not imported)."""
    for node in ast.parse(init.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "bl_info" for t in node.targets):
            return ".".join(str(v) for v in ast.literal_eval(node.value)["version"])
    raise ValueError(f"{init}: no bl_info")


def _files(folder: Path) -> list[Path]:
    """Files to ship under ``folder``, sorted: no caches, hidden files or archives."""
    out = []
    for p in folder.rglob("*"):
        rel = p.relative_to(folder).parts
        if not p.is_file() or "__pycache__" in rel or any(part.startswith(".") for part in rel):
            continue
        if p.suffix in (".pyc", ".pyo", ".zip"):
            continue
        out.append(p)
    return sorted(out, key=lambda p: p.relative_to(folder).as_posix())


def build_zip(out_dir: str | Path, addon_dir: Path = ADDON_DIR) -> Path:
    """Write the extension zip into ``out_dir`` (created if needed) and return its path.

    Every entry lies in the top-level folder ``<id>/`` (see the module docstring).
    """
    manifest = read_manifest(addon_dir)
    top = manifest["id"]
    entries = [(f"{top}/{p.relative_to(addon_dir).as_posix()}", p) for p in _files(addon_dir)]
    for name, src in VENDORED.items():
        if not (src / "__init__.py").is_file():
            raise FileNotFoundError(f"{src}: vendored package {name!r} not found")
        entries += [(f"{top}/_vendor/{name}/{p.relative_to(src).as_posix()}", p) for p in _files(src)]
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for arcname, path in sorted(entries):
            info = zipfile.ZipInfo(arcname, date_time=_ZIP_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, path.read_bytes())
    out = Path(out_dir) / f"{manifest['id']}-{manifest['version']}.zip"
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, buf.getvalue())
    return out


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="output folder of the zip")
    args = parser.parse_args(argv)
    try:
        path = build_zip(args.out)
    except (OSError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
