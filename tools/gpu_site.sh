#!/usr/bin/env bash
# Build what a GPU lease carries besides the working tree (docs/gpu_lease.md), into .whl/ and .gpu/
# (both ignored by git):
#   .whl/site.tar.xz   the Python packages the machine's image lacks (mitsuba, drjit, trimesh, xatlas,
#                      OpenEXR) for CPython 3.12, unpacked from their wheels and pruned: the Mitsuba
#                      variants and plugins this project never uses are dropped (it renders with
#                      *_mono_polarized, relights with *_rgb); tools/gpu_machine.sh setup unpacks it;
#   .whl/pyamg-*.whl   kept as a wheel (the evaluation's depth metric; setup unpacks every .whl);
#   .gpu/meshes.tar.xz the real-mesh corpus (corpora/meshes, tools/ensure_meshcorpus.sh) for train-next.
#
#   bash tools/gpu_site.sh            # pip download (once; wheels cached in .whl/wheels), prune, pack
#
# Versions are the ones this machine's .venv holds (pip download fetches the cp312 builds). Idempotent:
# an existing output is kept; delete it to rebuild.
set -euo pipefail
PY=${PY:-.venv/bin/python}
MESHES=${MESHES:-corpora/meshes}
mkdir -p .whl/wheels .gpu
version() { $PY -c "import importlib.metadata as m; print(m.version('$1'))"; }
if [ ! -f .whl/site.tar.xz ]; then
    specs=()
    for p in mitsuba drjit trimesh xatlas OpenEXR pyamg; do specs+=("$p==$(version $p)"); done
    $PY -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_24_x86_64 \
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl/wheels "${specs[@]}"
    site=$(mktemp -d)
    trap 'rm -rf "$site"' EXIT
    for w in .whl/wheels/*.whl; do
        case $w in *pyamg*) cp "$w" .whl/ ;; *) $PY -m zipfile -e "$w" "$site" ;; esac
    done
    # Variants other than *_mono_polarized (renders), *_rgb (relight) and scalar_spectral_polarized (tests).
    for v in cuda_ad_mono cuda_ad_spectral cuda_ad_spectral_polarized llvm_ad_mono llvm_ad_spectral \
        llvm_ad_spectral_polarized scalar_spectral scalar_mono scalar_mono_polarized; do
        rm -f "$site"/mitsuba/"$v".cpython-*.so
    done
    # Plugins no module of pbrdf/, blender_addon/, network/ or headless/ names.
    for p in sunsky timed_sunsky sdfgrid bsplinecurve linearcurve ellipsoids ellipsoidsmesh ptracer volpathmis hair; do
        rm -f "$site/mitsuba/plugins/$p.so"
    done
    find "$site" \( -name '*.pyi' -o -name tests -o -name '__pycache__' \) -prune -exec rm -rf {} +
    tar -cJf .whl/site.tar.xz -C "$site" .
fi
if [ ! -f .gpu/meshes.tar.xz ]; then
    [ -f "$MESHES/.complete" ] || bash tools/ensure_meshcorpus.sh "$MESHES"
    tar -cJf .gpu/meshes.tar.xz -C "$(dirname "$MESHES")" "$(basename "$MESHES")"
fi
du -b .whl/site.tar.xz .whl/*.whl .gpu/meshes.tar.xz
