"""Python Mitsuba plugins of the mono-polarized JIT variants: which variants they run in, registered once per variant.

:mod:`.table_bsdf` (a BSDF) and :mod:`.polarized_display` (an emitter) are written against the
``*_mono_polarized`` JIT variants: one scalar wavelength per pass and Dr.Jit arrays. Their class
derives from the current variant's ``mi.BSDF`` or ``mi.Emitter``, so it is built and registered
per variant, the first time a scene needs it.

>>> is_mono_jit("llvm_ad_mono_polarized"), is_mono_jit("scalar_mono_polarized"), is_mono_jit("llvm_ad_rgb")
(True, False, False)
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["is_mono_jit", "register_once"]

_REGISTERED: set[tuple[str, str]] = set()


def is_mono_jit(variant: str) -> bool:
    """Whether ``variant`` is a ``*_mono_polarized`` JIT (LLVM or CUDA) variant."""
    return variant.endswith("_mono_polarized") and not variant.startswith("scalar")


def register_once(name: str, kind: str, make_class: Callable[[], type]) -> None:
    """Register the plugin ``name`` for the current Mitsuba variant, once per variant.

    Args:
        name: the plugin name scene dicts use as ``type``.
        kind: ``"bsdf"`` or ``"emitter"``.
        make_class: builds the plugin class for the current variant.

    Raises:
        RuntimeError: the current variant is not a mono-polarized JIT variant.
    """
    import mitsuba as mi  # noqa: PLC0415

    variant = mi.variant()
    if (variant, name) in _REGISTERED:
        return
    if not is_mono_jit(variant):
        raise RuntimeError(f"{name} is for the *_mono_polarized JIT variants, not {variant!r}")
    cls = make_class()
    register = {"bsdf": mi.register_bsdf, "emitter": mi.register_emitter}[kind]
    register(name, lambda props: cls(props))
    _REGISTERED.add((variant, name))
