"""The command-line conventions of every headless script (cross-cutting).

Every ``headless/*.py`` script: ``--help`` exits 0 and prints the module's one-line summary, from
any working directory (the bootstrap puts the repository root on ``sys.path``) and as
``python -m headless.x``; each has ``build_parser()`` and ``main(argv=None) -> int``; the flags
follow one convention (``--input``, ``--out``, ``--seed``, ``--quiet``) and the old spellings are gone.
"""

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = sorted(p.stem for p in (ROOT / "headless").glob("*.py") if not p.name.startswith("_"))
#: Scripts that draw random numbers take --seed.
SEEDED = {"ablation", "bench", "demo", "expand_pbrdf", "optics_check", "render", "train"}
#: Scripts that read one input file or folder take --input (compare reads two: --before, --after).
WITH_INPUT = {
    "ablation",
    "bench",
    "calibrate",
    "dark_frames",
    "decode",
    "evaluate",
    "expand_pbrdf",
    "export_gltf",
    "infer",
    "mesh_corpus",
    "pack",
    "relight",
    "robustness",
    "train",
}
#: Every script (one per line: helpers add theirs without touching the others').
ALL_SCRIPTS = {
    "ablation",
    "bench",
    "calibrate",
    "compare",
    "dark_frames",
    "decode",
    "demo",
    "evaluate",
    "expand_pbrdf",
    "export_gltf",
    "infer",
    "mesh_corpus",
    "optics_check",
    "pack",
    "relight",
    "render",
    "robustness",
    "train",
}


def _summary(script: str) -> str:
    """The first line of the script's module docstring."""
    doc = ast.get_docstring(ast.parse((ROOT / "headless" / f"{script}.py").read_text()))
    return doc.splitlines()[0]


def test_every_script_is_found():
    assert ALL_SCRIPTS == set(SCRIPTS)
    assert not (ROOT / "headless" / "pipeline.py").exists() and not (ROOT / "headless" / "report.py").exists()


@pytest.mark.parametrize("script", SCRIPTS)
def test_help(script, tmp_path):
    """--help works from another working directory and describes the script."""
    proc = subprocess.run([sys.executable, str(ROOT / "headless" / f"{script}.py"), "--help"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "usage" in proc.stdout.lower()
    assert " ".join(_summary(script).split()) in " ".join(proc.stdout.split())
    assert "--quiet" in proc.stdout or script == "bench"  # bench: on each sub-command (below)


def test_help_as_module():
    proc = subprocess.run([sys.executable, "-m", "headless.bench", "decode", "--help"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0 and "polanalyser" in proc.stdout and "--quiet" in proc.stdout


@pytest.mark.parametrize("script", SCRIPTS)
def test_thin_main_and_conventions(script):
    """Importing a script has no side effects; it has build_parser() and main(); the flags follow the convention."""
    mod = importlib.import_module(f"headless.{script}")
    assert callable(mod.main) and mod.main.__defaults__ == (None,)
    parser = mod.build_parser()
    if script == "bench":  # flags live on the sub-commands
        sub = next(a for a in parser._actions if a.dest == "what")
        options = set().union(*({s for a in p._actions for s in a.option_strings} for p in sub.choices.values()))
    else:
        options = {s for a in parser._actions for s in a.option_strings}
    assert {"--help", "--quiet"} <= options
    assert ("--seed" in options) == (script in SEEDED), script
    assert ("--input" in options) == (script in WITH_INPUT), script
    assert not {"--data", "--maps", "--measured", "--capture"} & options


def test_bootstrap_is_identical_everywhere():
    """One bootstrap mechanism: the same two lines in every script."""
    lines = (
        "if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first\n"
        "    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))\n"
    )
    for script in SCRIPTS:
        text = (ROOT / "headless" / f"{script}.py").read_text()
        assert text.count(lines) == 1, script
        assert text.count("sys.path") == 1, script


#: Scripts documented to run inside the Blender binary (`blender -b -P headless/x.py -- ...`).
IN_BLENDER = {"relight", "render"}


def test_blender_scripts_refuse_old_blender_and_exit_with_their_status():
    """The scripts that run under `blender -b -P` check the version first and end with run_main."""
    for script in SCRIPTS:
        text = (ROOT / "headless" / f"{script}.py").read_text()
        uses = "refuse_old_blender(" in text and text.rstrip().splitlines()[-1].lstrip().startswith("run_main(main)")
        assert uses == (script in IN_BLENDER), script


def _fake_blender(monkeypatch, version):
    """Pretend to run inside a Blender binary of ``version`` (bpy.app.version is read-only)."""
    from blender_addon import compat
    from headless import _cli

    monkeypatch.setattr(_cli, "in_blender_binary", lambda: True)
    monkeypatch.setattr(compat, "running_blender", lambda: version)


def test_refuse_old_blender_exits_with_one_line(monkeypatch, capsys):
    from headless._cli import refuse_old_blender

    refuse_old_blender("render.py")  # outside the Blender binary: nothing happens
    _fake_blender(monkeypatch, (4, 2, 0))
    refuse_old_blender("render.py")
    assert capsys.readouterr().err == ""
    _fake_blender(monkeypatch, (3, 4, 1))
    with pytest.raises(SystemExit) as exc:
        refuse_old_blender("render.py")
    assert exc.value.code == 2
    assert capsys.readouterr().err.splitlines() == ["error: render.py needs Blender 4.2 or later, this is 3.4.1"]


def test_run_main_turns_any_failure_into_one_line_inside_blender(monkeypatch, capsys):
    """`blender -b -P` exits 0 after an uncaught exception: run_main exits 1 with one `error:` line instead."""
    from headless._cli import run_main

    def fails():
        raise RuntimeError("Cycles\n  went away")

    with pytest.raises(RuntimeError):  # outside Blender: the traceback as usual
        run_main(fails)
    _fake_blender(monkeypatch, (5, 0, 1))
    for main, code, err in ((fails, 1, ["error: Cycles went away"]), (lambda: 3, 3, []), (lambda: 0, 0, [])):
        with pytest.raises(SystemExit) as exc:
            run_main(main)
        assert exc.value.code == code and capsys.readouterr().err.splitlines() == err
