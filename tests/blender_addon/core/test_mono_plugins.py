"""blender_addon/core/mono_plugins.py: registration once per variant, refused outside mono-polarized JIT variants."""

import pytest

pytestmark = pytest.mark.mitsuba
mi = pytest.importorskip("mitsuba")

from blender_addon.core import mono_plugins, polarized_display, table_bsdf  # noqa: E402


def test_registers_once_and_refuses_other_variants():
    before = mi.variant()
    try:
        mi.set_variant("llvm_ad_mono_polarized")
        built = []

        def make():
            built.append(1)
            return polarized_display._emitter_class()

        mono_plugins.register_once("pdir_test_emitter", "emitter", make)
        mono_plugins.register_once("pdir_test_emitter", "emitter", make)
        assert built == [1]
        table_bsdf.register()  # the project's plugins go through the same door
        polarized_display.register()
        mi.set_variant("scalar_rgb")
        with pytest.raises(RuntimeError, match="not 'scalar_rgb'"):
            mono_plugins.register_once("pdir_test_emitter", "emitter", make)
        with pytest.raises(RuntimeError, match=table_bsdf.PLUGIN):
            table_bsdf.register()
    finally:
        if before:
            mi.set_variant(before)
