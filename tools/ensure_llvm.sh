#!/usr/bin/env bash
# Make sure Dr.Jit's LLVM backend works for polarized rendering. drjit 1.5 needs LLVM >= 15,
# and LLVM 15 itself aborts on some of Mitsuba's kernels ("Cannot select: fminimum"), so the
# check renders a tiny polarized scene in a subprocess. If that fails, Debian's libllvm19 is
# installed (Dr.Jit picks the highest libLLVM it finds).
set -euo pipefail
PY=${1:-.venv/bin/python}
check() {
  "$PY" - <<'PYEOF' >/dev/null 2>&1
import drjit as dr, mitsuba as mi
assert dr.has_backend(dr.JitBackend.LLVM)
mi.set_variant("llvm_ad_mono_polarized")
scene = mi.load_dict({
    "type": "scene",
    "integrator": {"type": "stokes", "nested": {"type": "volpath", "max_depth": 3}},
    "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8},
               "sampler": {"type": "independent", "sample_count": 2}},
    "light": {"type": "rectangle", "emitter": {"type": "area", "radiance": 1.0},
              "to_world": mi.ScalarTransform4f().translate([0, 0, 3])},
    "sheet": {"type": "rectangle", "bsdf": {"type": "polarizer", "theta": 90.0},
              "to_world": mi.ScalarTransform4f().translate([0, 0, 2.9])},
    "ball": {"type": "sphere", "bsdf": {"type": "pplastic"}},
})
mi.render(scene)
PYEOF
}
if check; then
  exit 0
fi
echo "ensure_llvm: Dr.Jit's LLVM backend cannot render polarized scenes; installing libllvm19 (Debian)" >&2
bash "$(dirname "$0")/apt_install.sh" libllvm19
if ! check; then
  echo "ensure_llvm: LLVM rendering still fails after installing libllvm19;" \
       "set DRJIT_LIBLLVM_PATH to /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1" >&2
  exit 1
fi
