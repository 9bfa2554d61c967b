"""The command-line conventions every headless script shares.

Flags: ``--input`` (a file or folder the script reads), ``--out`` (what it writes), ``--seed``
(where it draws random numbers), ``--quiet`` (no progress bars; the lines a script prints at the
end, its summary or the paths it wrote, still print so that scripts chain) and ``--help`` (the
module docstring).

Every script is a thin ``main(argv=None) -> int`` over a ``build_parser()`` and starts with the
same bootstrap, so that it runs as ``python headless/x.py``, as ``python -m headless.x`` and
(``render.py``, ``relight.py``) as ``blender -b -P headless/render.py -- ...``::

    if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
        sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

The scripts that run inside the Blender binary also call :func:`refuse_old_blender` right after
that bootstrap (one ``error:`` line and status 2 on a Blender older than the add-on's minimum,
before anything else is imported) and end with :func:`run_main` instead of ``raise
SystemExit(main())``: ``blender -b -P`` prints an uncaught exception's traceback and exits with
status 0 (unless ``--python-exit-code N`` comes before ``-P``), so there an uncaught exception
becomes one ``error:`` line and status 1, and the script's own status reaches the shell through
``sys.exit`` (which does exit Blender with that code).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import warnings
from collections.abc import Callable, Iterable
from typing import NoReturn

from pbrdf.io.errors import one_line

__all__ = [
    "flag_wording",
    "in_blender_binary",
    "model_override",
    "held_warnings",
    "refuse_old_blender",
    "require",
    "run_main",
    "script_args",
]


def model_override(text: str) -> tuple[str, object]:
    """One ``--overrides`` item: ``key=value`` with a JSON value (or a plain string).

    Example:
        >>> model_override("image_size=128"), model_override("cross_observation=token")
        (('image_size', 128), ('cross_observation', 'token'))
    """
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected key=value, got {text!r}")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value  # a plain string, e.g. cross_observation=token


def require(parser: argparse.ArgumentParser, args: argparse.Namespace, *flags: str) -> None:
    """Fail like argparse's ``required=True`` when a flag was not given (for flags required only in some modes).

    Args:
        parser: the script's parser (its ``error`` exits with status 2).
        args: the parsed arguments.
        *flags: option strings, e.g. ``"--input"``.
    """
    missing = [f for f in flags if getattr(args, f.lstrip("-").replace("-", "_"), None) is None]
    if missing:
        parser.error(f"the following arguments are required: {', '.join(missing)}")


def flag_wording(message: str, names: Iterable[str]) -> str:
    """A library error in a script's words: ``name=value`` of a parameter becomes its flag ``--name value``.

    Libraries name their parameters (``max_skipped=3``); a script maps the ones that are its flags
    (underscores become dashes; ``=True`` becomes the bare switch). Other text stays as it is.

    Args:
        message: the library's error message.
        names: the parameter names that are flags of the script.

    Returns:
        The message with each ``name=value`` of ``names`` written as the flag.

    Example:
        >>> flag_wording("pass resume=True; inputs='polar', not 'full'; table_fraction=0.3 > 0", ["resume", "inputs",
        ...              "table_fraction"])
        "pass --resume; --inputs polar, not 'full'; --table-fraction 0.3 > 0"
    """

    def flag(m: re.Match) -> str:
        name, value = "--" + m[1].replace("_", "-"), m[2].strip("'")
        return name if value == "True" else f"{name} {value}"

    pattern = "|".join(re.escape(n) for n in names)
    return re.sub(rf"(?<![\w-])({pattern})=('[^']*'|\{{[^}}]*\}}|[^\s,;)]+)", flag, message)


def script_args(argv: list[str]) -> list[str]:
    """The script's own arguments: those after ``--`` (``blender -b -P script -- ...``), else ``argv[1:]``.

    Args:
        argv: the full command line, e.g. ``sys.argv``.

    Returns:
        The arguments for the script's parser.

    Example:
        >>> script_args(["blender", "-b", "-P", "headless/relight.py", "--", "--input", "pred"])
        ['--input', 'pred']
        >>> script_args(["headless/relight.py", "--input", "pred"])
        ['--input', 'pred']
    """
    return argv[argv.index("--") + 1 :] if "--" in argv else argv[1:]


def held_warnings(work: Callable[[], int], *, status: int = 2) -> int:
    """Run ``work`` with warnings held back: one ``error:`` line on bad input, else each warning once.

    The convention of every script that reads a user's files: a ``ValueError`` or ``OSError`` (bad
    input, a missing file) prints exactly one ``error:`` line and nothing else, and returns
    ``status``; on success each distinct warning prints as one ``warning:`` line after the work.

    Args:
        work: the script's work; returns its exit status.
        status: the status returned on bad input.

    Returns:
        ``work()``'s status, or ``status``.

    Example:
        >>> import contextlib, io, warnings
        >>> err = io.StringIO()
        >>> def bad() -> int:
        ...     warnings.warn("held")
        ...     raise ValueError("capture.json:\\n missing key")
        >>> with contextlib.redirect_stderr(err):
        ...     held_warnings(bad)
        2
        >>> err.getvalue()
        'error: capture.json: missing key\\n'
    """
    with warnings.catch_warnings(record=True) as caught:
        try:
            code = work()
        except (ValueError, OSError) as exc:
            print(f"error: {one_line(exc)}", file=sys.stderr)
            return status
    for message in dict.fromkeys(one_line(w.message) for w in caught):
        print(f"warning: {message}", file=sys.stderr)
    return code


def in_blender_binary() -> bool:
    """True inside the Blender binary (``blender -b -P``); False with the bpy wheel or without bpy."""
    bpy = sys.modules.get("bpy")
    return bpy is not None and bool(getattr(getattr(bpy, "app", None), "binary_path", ""))


def refuse_old_blender(prog: str) -> None:
    """Inside a Blender older than the add-on's minimum: print one ``error:`` line and exit with status 2.

    A no-op outside the Blender binary (the bpy wheel's route checks the version where it imports
    bpy). Call it right after the script's bootstrap, before the project's other imports, so that
    an old Blender says why it is refused instead of failing somewhere inside them.

    Args:
        prog: the script's name in the message, e.g. ``"render.py"``.
    """
    if not in_blender_binary():
        return
    from blender_addon.compat import blender_refusal, running_blender  # noqa: PLC0415

    problem = blender_refusal(running_blender())
    if problem:
        print(f"error: {prog} {problem}", file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        sys.exit(2)


def run_main(main: Callable[[], int]) -> NoReturn:
    """Run a script's ``main()`` and exit with its status, also inside the Blender binary.

    Outside Blender this is ``raise SystemExit(main())``. Inside ``blender -b -P`` an uncaught
    exception becomes one line ``error: <message>`` on stderr and status 1 (Blender itself would
    print the traceback and exit with status 0); ``sys.exit`` then ends Blender with the status.
    ``SystemExit`` (argparse's usage errors, ``--help``) passes through unchanged.
    """
    if not in_blender_binary():
        raise SystemExit(main())
    try:
        code = main()
    except SystemExit:
        raise
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        code = 130
    except Exception as exc:  # noqa: BLE001 - the one place that turns any failure into one line
        print(f"error: {one_line(exc)}", file=sys.stderr)
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    sys.exit(code)
