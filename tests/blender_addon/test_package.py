"""Packaging of the add-on: registration, preferences, the extension zip and its installation.

The installation test runs Blender (the bpy 5.0 wheel) in a subprocess with a temporary user
directory and a site-packages view WITHOUT the project's editable install and without the
optional packages Blender's Python lacks (mitsuba, drjit, trimesh, xatlas, OpenEXR, scipy,
Pillow, torch): the zip must install through Blender's own extension operator, find ``pbrdf`` in
its ``_vendor`` folder, register, build a rig, and say how to get Mitsuba; the same zip must
install as a legacy add-on (one folder in ``scripts/addons``). The import without bpy and the
build errors need no bpy and run without it. On a Blender older than 4.2 (faked with the wheel,
and a real ``blender`` binary where one is installed, e.g. Debian's 3.4) ``register()`` refuses
with one line and registers nothing.
"""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import textwrap
import tomllib
import zipfile
from pathlib import Path

import pytest

import blender_addon

try:  # the bpy-free tests (import without bpy, build errors) run without the wheel too
    import bpy
except ImportError:
    bpy = None

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tools"))
import build_addon  # noqa: E402

#: Skips a test (also marked ``bpy``) where the bpy wheel is missing.
needs_bpy = pytest.mark.skipif(bpy is None, reason="needs the bpy wheel (the `bpy` extra)")

EXT_ID = "polarimetric_inverse_rendering"
# Packages that Blender's bundled Python does not have.
MISSING_IN_BLENDER = ("mitsuba", "drjit", "trimesh", "xatlas", "OpenEXR", "scipy", "PIL", "torch")


@pytest.fixture(scope="module")
def zip_path(tmp_path_factory):
    return build_addon.build_zip(tmp_path_factory.mktemp("dist"))


def _registered():
    return {
        "panel": hasattr(bpy.types, "PDIR_PT_main"),
        "settings": hasattr(bpy.types.Scene, "pdir_rig") and hasattr(bpy.types.Scene, "pdir_builder"),
        "operator": hasattr(bpy.types, "PDIR_OT_add_rig"),
    }


def test_package_imports_without_bpy():
    code = "import sys; sys.modules['bpy'] = None; import blender_addon, pbrdf.sensor.rig; print('ok')"
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr


@pytest.mark.bpy
@needs_bpy
def test_register_unregister_twice():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for _ in range(2):
        blender_addon.register()
        assert all(_registered().values()), _registered()
        assert bpy.ops.pdir.add_rig() == {"FINISHED"}
        blender_addon.unregister()
        assert not any(_registered().values()), _registered()
    blender_addon.unregister()  # a second unregister is a no-op


@pytest.mark.bpy
@needs_bpy
def test_register_refuses_blender_older_than_4_2(monkeypatch):
    """bpy.app.version is read-only: the version the add-on reads (compat.running_blender) is faked."""
    from blender_addon import compat

    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender_addon.unregister()
    monkeypatch.setattr(compat, "running_blender", lambda: (3, 4, 1))
    with pytest.raises(RuntimeError) as exc:
        blender_addon.register()
    assert str(exc.value) == "Polarimetric Inverse Rendering needs Blender 4.2 or later, this is 3.4.1"
    assert not any(_registered().values()) and not blender_addon._registered  # nothing half-registered
    monkeypatch.setattr(compat, "running_blender", lambda: (4, 2, 0))
    blender_addon.register()
    assert all(_registered().values())
    blender_addon.unregister()


@pytest.mark.skipif(shutil.which("blender") is None, reason="no `blender` binary on PATH")
def test_legacy_zip_in_the_blender_binary(zip_path, tmp_path):
    """The zip installed with Install legacy Add-on in a real Blender: refused in one line before 4.2, else enabled."""
    script = tmp_path / "legacy.py"
    script.write_text(_LEGACY_BINARY_SCRIPT)
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env["BLENDER_USER_SCRIPTS"] = str(tmp_path / "scripts")
    cmd = [shutil.which("blender"), "-b", "--factory-startup", "--python-exit-code", "1", "-P", str(script), "--",
           str(zip_path), str(tmp_path / "result.json")]  # fmt: skip
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    res = json.loads((tmp_path / "result.json").read_text())
    assert res["install"] == ["FINISHED"]
    assert sorted(p.name for p in (tmp_path / "scripts" / "addons").iterdir() if p.name != "__pycache__") == [EXT_ID]
    version = tuple(res["version"])
    if version < (4, 2, 0):
        assert res["error"] == (
            f"Polarimetric Inverse Rendering needs Blender 4.2 or later, this is {'.'.join(map(str, version))}"
        )
        assert not res["registered"]
    else:
        assert res["error"] is None and res["registered"]


_LEGACY_BINARY_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import bpy, addon_utils
    zip_path, out = sys.argv[sys.argv.index("--") + 1:]
    res = {"version": list(bpy.app.version), "error": None}
    res["install"] = sorted(bpy.ops.preferences.addon_install(filepath=zip_path))
    errors = []
    addon_utils.enable("polarimetric_inverse_rendering", default_set=True, handle_error=errors.append)
    res["error"] = str(errors[0]) if errors else None
    res["registered"] = hasattr(bpy.types, "PDIR_PT_main")
    json.dump(res, open(out, "w"))
    """
)


@pytest.mark.bpy
@needs_bpy
def test_legacy_addon_enable_and_preferences(tmp_path):
    """Enabled through addon_utils (the legacy add-on route, bl_info): preferences are reachable."""
    import addon_utils

    from blender_addon import prefs

    bpy.ops.wm.read_factory_settings(use_empty=True)
    mod = addon_utils.enable("blender_addon", default_set=True, handle_error=None)
    try:
        assert mod is blender_addon and mod.bl_info["blender"] >= (4, 2, 0)
        preferences = prefs.addon_preferences()
        assert preferences is not None and type(preferences).bl_idname == "blender_addon"
        ok, message = prefs.mitsuba_available()  # the project venv has mitsuba and drjit
        assert ok and "Blender's Python" in message
        preferences.python_path = str(tmp_path / "missing-python")
        assert prefs.external_python() is None
        preferences.python_path = sys.executable
        assert prefs.external_python() == Path(sys.executable)
    finally:
        addon_utils.disable("blender_addon", default_set=True)
    assert not any(_registered().values())


@pytest.mark.bpy
@needs_bpy
def test_zip_layout_and_manifest(zip_path, tmp_path):
    manifest_src = tomllib.loads((REPO / "blender_addon" / "blender_manifest.toml").read_text())
    assert zip_path.name == f"{EXT_ID}-{manifest_src['version']}.zip"
    with zipfile.ZipFile(zip_path) as zf:
        names = zf.namelist()
        manifest = tomllib.loads(zf.read(f"{EXT_ID}/blender_manifest.toml").decode())
        init = zf.read(f"{EXT_ID}/__init__.py").decode()
    # One top-level folder: an extension (manifest in a single folder) and a legacy add-on alike.
    assert all(n.startswith(f"{EXT_ID}/") for n in names)
    assert manifest == manifest_src
    assert manifest["id"] == EXT_ID and manifest["type"] == "add-on"
    assert tuple(int(v) for v in manifest["blender_version_min"].split(".")) == (4, 2, 0)
    for required in (
        "__init__.py",
        "rig_bpy.py",
        "scene_builder.py",
        "ui.py",
        "core/spec.py",
        "_vendor/pbrdf/sensor/rig.py",
        "_vendor/pbrdf/sensor/camera.py",
    ):
        assert f"{EXT_ID}/{required}" in names
    assert not any("__pycache__" in n or n.endswith(".pyc") for n in names)
    assert "bl_info" in init and blender_addon.bl_info["version"] == tuple(
        int(v) for v in manifest["version"].split(".")
    )
    # Reproducible: the same sources give the same bytes.
    again = build_addon.build_zip(tmp_path)
    assert again.read_bytes() == zip_path.read_bytes()
    # Blender's own manifest validator (the CLI behind `blender --command extension validate`).
    scripts = Path(bpy.utils.resource_path("LOCAL")) / "scripts"
    cli = scripts / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    tags = scripts / "modules" / "_bpy_internal" / "extensions" / "tags.py"
    res = subprocess.run(
        [sys.executable, str(cli), "validate", f"--valid-tags={tags}", str(zip_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stdout + res.stderr


def test_build_errors(tmp_path, capsys):
    addon = tmp_path / "addon"
    addon.mkdir()
    (addon / "__init__.py").write_text('bl_info = {"version": (0, 2, 0)}\n')
    with pytest.raises(FileNotFoundError, match="manifest not found"):
        build_addon.read_manifest(addon)
    text = (REPO / "blender_addon" / "blender_manifest.toml").read_text()
    (addon / "blender_manifest.toml").write_text(text)
    with pytest.raises(ValueError, match="bl_info version 0.2.0"):
        build_addon.read_manifest(addon)
    (addon / "blender_manifest.toml").write_text(text.replace('id = "', 'id = "1'))
    with pytest.raises(ValueError, match="identifier"):
        build_addon.read_manifest(addon)
    out_file = tmp_path / "file"
    out_file.write_text("")
    assert build_addon.main(["--out", str(out_file)]) == 2
    assert capsys.readouterr().err.startswith("error: ")


_INSTALL_SCRIPT = textwrap.dedent(
    """
    import importlib.util, json, sys
    import bpy, addon_utils
    zip_path, assets, out = sys.argv[1:4]
    res = {}
    res["pbrdf_before"] = importlib.util.find_spec("pbrdf") is not None
    res["install"] = sorted(bpy.ops.extensions.package_install_files(
        filepath=zip_path, repo="user_default", enable_on_install=True))
    name = "bl_ext.user_default.polarimetric_inverse_rendering"
    res["enabled"] = name in bpy.context.preferences.addons
    res["unavailable"] = dict(sys.modules[name].UNAVAILABLE)
    import pbrdf
    res["pbrdf_file"] = pbrdf.__file__
    res["add_rig"] = sorted(bpy.ops.pdir.add_rig())
    mod = sys.modules[name]
    res["mitsuba"] = list(mod.prefs.mitsuba_available())
    res["prefs"] = type(bpy.context.preferences.addons[name].preferences).bl_idname
    res["rig_to_json"] = sorted(bpy.ops.pdir.rig_to_json(filepath=out + "/rig.json"))
    try:
        res["build_scene"] = sorted(bpy.ops.pdir.build_scene(folder=assets, count=1, seed=0))
    except RuntimeError as e:
        res["build_scene"] = str(e)
    addon_utils.disable(name, default_set=True)
    res["disabled"] = not hasattr(bpy.types, "PDIR_PT_main")
    # The same zip as a legacy add-on (Install legacy Add-on): one folder in scripts/addons.
    res["legacy_install"] = sorted(bpy.ops.preferences.addon_install(filepath=zip_path))
    legacy = addon_utils.enable("polarimetric_inverse_rendering", default_set=True, handle_error=None)
    res["legacy"] = legacy is not None and hasattr(bpy.types, "PDIR_PT_main")
    res["legacy_add_rig"] = sorted(bpy.ops.pdir.add_rig())
    addon_utils.disable("polarimetric_inverse_rendering", default_set=True)
    json.dump(res, open(out + "/result.json", "w"))
    """
)


@pytest.mark.bpy
@needs_bpy
def test_zip_installs_as_extension_without_optional_packages(zip_path, tmp_path):
    # A site-packages view with bpy and numpy but without the editable install and optional packages.
    site = tmp_path / "site"
    site.mkdir()
    deny = tuple(n.lower() for n in MISSING_IN_BLENDER) + ("__editable__", "snapshot_pdir", "pillow")
    for entry in Path(sysconfig.get_paths()["purelib"]).iterdir():
        if entry.suffix == ".pth" or entry.name.lower().startswith(deny):
            continue
        (site / entry.name).symlink_to(entry)
    user = tmp_path / "user"
    assets = tmp_path / "assets"
    assets.mkdir()
    (assets / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    script = tmp_path / "install.py"
    script.write_text(_INSTALL_SCRIPT)
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env.update(PYTHONPATH=str(site), BLENDER_USER_RESOURCES=str(user))
    proc = subprocess.run(
        [sys.executable, "-S", str(script), str(zip_path), str(assets), str(tmp_path)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    res = json.loads((tmp_path / "result.json").read_text())
    assert res["pbrdf_before"] is False  # Blender-like: no project packages
    assert res["install"] == ["FINISHED"] and res["enabled"]
    assert Path(res["pbrdf_file"]).is_relative_to(user / "extensions" / "user_default" / EXT_ID / "_vendor")
    assert res["add_rig"] == ["FINISHED"] and res["rig_to_json"] == ["FINISHED"]
    assert (tmp_path / "rig.json").is_file()
    ok, message = res["mitsuba"]
    assert not ok and "pip install mitsuba" in message and "preferences" in message
    assert res["prefs"] == f"bl_ext.user_default.{EXT_ID}"
    # Without trimesh the scene builder either works (core imports trimesh lazily) or says what is missing.
    assert res["build_scene"] == ["FINISHED"] or "trimesh" in res["build_scene"]
    assert res["disabled"] and res["legacy_install"] == ["FINISHED"]
    installed = sorted(p.name for p in (user / "scripts" / "addons").iterdir() if p.name != "__pycache__")
    assert installed == [EXT_ID]  # one folder, nothing scattered into scripts/addons
    assert res["legacy"] and res["legacy_add_rig"] == ["FINISHED"]
    # Every module registers in a Blender without the optional packages.
    assert res["unavailable"] == {}, f"modules left out without optional packages: {res['unavailable']}"
