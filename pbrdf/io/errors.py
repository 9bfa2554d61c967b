"""Errors as one line: the formatter every user-facing message goes through, and the shared error types.

A person reads one ``error:`` line per failure (the CLIs, the add-on's report); a traceback or a
multi-line message from a library is collapsed here, in one place.

Example:
    >>> one_line(ValueError("bad\\n  value")), one_line(KeyError())
    ('bad value', 'KeyError')
    >>> issubclass(NothingToReconstruct, ValueError)
    True
"""

from __future__ import annotations

__all__ = ["NothingToReconstruct", "one_line"]


class NothingToReconstruct(ValueError):
    """The input holds nothing to reconstruct: an empty mask, or one that vanishes at the network's grid.

    A ``ValueError`` so that every CLI reports it as bad input; callers that score many scenes
    catch this type alone (a scene without an object is scored as the constant predictor), and let
    every other failure, such as a network that returns NaN, stop them.
    """


def one_line(exc: BaseException | Warning | str, limit: int = 500) -> str:
    """An exception, warning or text as one line: whitespace collapsed, else the type's name.

    Args:
        exc: the exception, warning or message.
        limit: the longest line returned; a longer one ends in ``...``.

    Returns:
        The message on one line, at most ``limit`` characters.

    Example:
        >>> one_line("a" * 10, limit=8)
        'aaaaa...'
    """
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[: limit - 3] + "..."
