#!/usr/bin/env bash
# Build what a GPU lease carries besides the working tree (docs/gpu_lease.md), into .whl/ and .gpu/
# (both ignored by git):
#   .whl/site.tar.xz   the Python packages the machine's image lacks (mitsuba, drjit, trimesh, xatlas,
#                      OpenEXR) for CPython 3.12, unpacked from their wheels and pruned: the Mitsuba
#                      variants (scalar_* and spectral ones too: tests only), the spectral table and the
#                      plugins this project never uses are dropped (it renders with *_mono_polarized,
#                      relights with *_rgb); tools/gpu_machine.sh setup unpacks it;
#   .whl/pyamg-*.whl   kept as a wheel (the evaluation's depth metric; setup unpacks every .whl);
#   .gpu/meshes.tar.xz the real-mesh corpus (corpora/meshes, tools/ensure_meshcorpus.sh) for train-next.
#
#   bash tools/gpu_site.sh            # pip download (once), prune, pack (a few minutes of xz)
#
# Versions are the ones this machine's .venv holds (pip download fetches the cp312 builds into WHEELS,
# default out/gpu-wheels: outside what a lease carries). Idempotent: an existing output is kept; delete
# it to rebuild.
set -euo pipefail
PY=${PY:-.venv/bin/python}
MESHES=${MESHES:-corpora/meshes}
WHEELS=${WHEELS:-out/gpu-wheels}
mkdir -p "$WHEELS" .whl .gpu
version() { $PY -c "import importlib.metadata as m; print(m.version('$1'))"; }
if [ ! -f .whl/site.tar.xz ]; then
    specs=()
    for p in mitsuba drjit trimesh xatlas OpenEXR pyamg; do specs+=("$p==$(version $p)"); done
    $PY -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_24_x86_64 \
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d "$WHEELS" "${specs[@]}"
    site=$(mktemp -d)
    trap 'rm -rf "$site"' EXIT
    for w in "$WHEELS"/*.whl; do
        case $w in *pyamg*) cp "$w" .whl/ ;; *) $PY -m zipfile -e "$w" "$site" ;; esac
    done
    # The variants other than *_mono_polarized (renders) and *_rgb (relight) of the CUDA and LLVM backends,
    # and the spectral upsampling table (7 MB compressed; only spectral variants read it). Checked on a
    # copy of the CPU machine's Mitsuba 3.9.1 pruned alike: train-next renders with llvm (2026-11-27).
    for v in cuda_ad_mono cuda_ad_spectral cuda_ad_spectral_polarized llvm_ad_mono llvm_ad_spectral \
        llvm_ad_spectral_polarized scalar_rgb scalar_spectral scalar_spectral_polarized scalar_mono \
        scalar_mono_polarized; do
        rm -f "$site"/mitsuba/"$v".cpython-*.so
    done
    rm -rf "$site/mitsuba/data/srgb.coeff" "$site/mitsuba/data/sunsky"
    # Plugins no module of pbrdf/, blender_addon/, network/, headless/ or tools/ names. Rendering 24 train-next
    # and 8 val-next scenes loaded 19 plugins (aov bitmap blendbsdf box depth diffuse direct hdrfilm merge
    # multijitter normalmap path perspective pplastic rectangle roughconductor stokes twosided uniform).
    for p in sunsky timed_sunsky sdfgrid bsplinecurve linearcurve ellipsoids ellipsoidsmesh ptracer volpathmis hair \
        principled principledthin projector batch gridvolume thinlens specfilm blender blendphase irradiancemeter \
        radiancemeter tabphase heterogeneous moment sggx rayleigh hg cylinder orthographic directionalarea \
        catmullrom lanczos mitchell; do
        rm -f "$site/mitsuba/plugins/$p.so"
    done
    find "$site" \( -name '*.pyi' -o -name tests -o -name '__pycache__' \) -prune -exec rm -rf {} +
    XZ_OPT=${XZ_OPT:--9 -T0} tar -cJf .whl/site.tar.xz -C "$site" .
fi
if [ ! -f .gpu/meshes.tar.xz ]; then
    [ -f "$MESHES/.complete" ] || bash tools/ensure_meshcorpus.sh "$MESHES"
    tar -cJf .gpu/meshes.tar.xz -C "$(dirname "$MESHES")" "$(basename "$MESHES")"
fi
du -b .whl/site.tar.xz .whl/*.whl .gpu/meshes.tar.xz
