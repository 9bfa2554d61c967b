#!/usr/bin/env bash
# The GPU measurements of docs/measurements/gpu.md, one stage per argument, on a bare CUDA machine.
#
#   bash tools/gpu_machine.sh setup bench dataset paper ablation
#
# setup:    unpack the Python packages the machine lacks (mitsuba, drjit, trimesh, xatlas,
#           OpenEXR for CPython 3.12) from .whl/site.tar.xz, and any .whl/*.whl (pyamg, which the
#           evaluation's depth metric needs), into /tmp/site; check the CUDA variant.
# bench:    headless/bench.py render --variant cuda and network --device cuda (paper, bf16).
# dataset:  the train-engine split rendered with the CUDA variant by SHARDS processes: samples/s.
# paper:    `paper` at 384 px with bf16 on scenes rendered here, scored on the test splits
#           (rendered here with the CUDA variant: the same scenes, another noise draw).
# ablation: the six runs of headless/ablation.py trained here (float16 weights to $OUT).
# Results go to $OUT (or out/gpu); GPU_DATA (default /tmp/gpu-data) keeps the renders.
set -euo pipefail
OUT=${OUT:-out/gpu}
DATA=${GPU_DATA:-/tmp/gpu-data}
SHARDS=${SHARDS:-8}
PY=${PY:-python3}
mkdir -p "$OUT" "$DATA"
export PYTHONUNBUFFERED=1 PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}

stamp() { echo "== $(date -u +%H:%M:%S) $*"; }

# Render split $1 into $DATA/$1 with SHARDS processes (extra arguments follow); prints the time.
render_split() {
    local split=$1
    shift
    local t0=$SECONDS
    for k in $(seq 0 $((SHARDS - 1))); do
        $PY headless/render.py --split "$split" --variant cuda --out "$DATA/$split" --shard "$k/$SHARDS" \
            --resume --quiet "$@" &
    done
    wait
    stamp "rendered $split: $(ls "$DATA/$split/samples" | grep -c '\.exr$') samples in $((SECONDS - t0)) s"
}

# The pBRDF libraries of train-data ("train") and test-sets ("test"), with the Makefile's seeds.
pbrdfs() {
    local which count seed
    for which in "$@"; do
        if [ "$which" = train ]; then count=200 seed=12000; else count=24 seed=22000; fi
        [ -f "$DATA/pbrdfs-$which/materials.json" ] ||
            $PY headless/expand_pbrdf.py --out "$DATA/pbrdfs-$which" --count $count --seed $seed --quiet
    done
}

# Shard $4 of $2 scenes at 384 px (train-engine's settings, run seed $3) into $DATA/$1.
render_384() {
    $PY headless/render.py --out "$DATA/$1" --count "$2" --seed "$3" --resolution 384 --spp 16 --shapes train \
        --objects 1-3 --pbrdfs "$DATA/pbrdfs-train" --table-fraction 0.5 --variant cuda --shard "$4/$SHARDS" \
        --resume --quiet
}

test_sets() {
    render_split test-procedural
    render_split test-meshes
    render_split test-pbrdf --pbrdfs "$DATA/pbrdfs-test"
    render_split test-scenes --pbrdfs "$DATA/pbrdfs-test"
}

for stage in "$@"; do
    stamp "stage $stage"
    case $stage in
    setup)
        if [ ! -d /tmp/site/mitsuba ]; then mkdir -p /tmp/site && tar -xJf .whl/site.tar.xz -C /tmp/site; fi
        for w in .whl/*.whl; do [ -e "$w" ] && $PY -m zipfile -e "$w" /tmp/site; done  # e.g. pyamg (depth metric)
        nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
        $PY -c "from blender_addon.core.passes import choose_variant; print('variant', choose_variant('cuda'))"
        ;;
    bench)
        $PY headless/bench.py render --variant cuda --quiet --out "$OUT/render_cuda.json" >/dev/null
        $PY headless/bench.py network --device cuda --bf16 --configs small --paper --strides 1 4 --no-reference \
            --quiet --out "$OUT/network_cuda.json" >/dev/null
        ;;
    dataset)
        pbrdfs train
        COUNT=${COUNT:-160}
        render_split train-engine --count "$COUNT" --pbrdfs "$DATA/pbrdfs-train" 2>&1 | tee "$OUT/dataset.txt"
        ;;
    paper)
        pbrdfs train test
        t0=$SECONDS
        for k in $(seq 0 $((SHARDS - 1))); do
            render_384 train-384 "${PAPER_SCENES:-512}" 30000 "$k" &
            render_384 val-384 32 31000 "$k" &
        done
        wait
        stamp "rendered train-384 and val-384 in $((SECONDS - t0)) s"
        test_sets >"$OUT/test_sets.txt" 2>&1 &
        # A lease is short: training stops after PAPER_SECONDS (best.pt is the best validated so far).
        timeout "${PAPER_SECONDS:-270}" $PY headless/train.py --input "$DATA/train-384" --val "$DATA/val-384" \
            --config paper --bf16 --device cuda --steps "${PAPER_STEPS:-600}" --batch-size 4 --lr 2e-4 \
            --lr-warmup 50 --min-lr-ratio 0.1 --seed 0 \
            --input-scale calibrated --checkpoint-every 100 --val-samples 16 --workers 6 --out "$DATA/paper" \
            --resume --quiet --no-tensorboard || echo "training ended by the time limit (status $?)"
        wait
        tail -3 "$OUT/test_sets.txt"
        $PY headless/evaluate.py --write-train-stats "$DATA/paper/train_stats.json" --input "$DATA/train-384"
        cp "$DATA/paper/log.csv" "$OUT/paper_log.csv"
        cp "$DATA/paper/val.csv" "$OUT/paper_val.csv"
        $PY headless/evaluate.py --split test --input "$DATA" --device cuda --jobs 12 \
            --checkpoint "$DATA/paper/best.pt" --quiet --out "$OUT/paper_eval"
        ;;
    ablation)
        # Training only: the six runs train side by side on the GPU. Their weights come back as
        # float16 ($OUT/ablation_RUN.pt); copied to out/ablation/RUN/model.pt on any machine
        # (loading casts them back to float32), `headless/ablation.py --stage evaluate` scores them
        # on the canonical test splits.
        pbrdfs train
        render_split train-engine --count "${ABL_RENDER:-1200}" --pbrdfs "$DATA/pbrdfs-train" | tail -1
        render_split train-engine-white --count "${ABL_SCENES:-300}" --pbrdfs "$DATA/pbrdfs-train" | tail -1
        t0=$SECONDS
        for r in white spectral polar full analytic expanded; do
            $PY headless/ablation.py --input "$DATA" --out "$DATA/ablation" --scenes "${ABL_SCENES:-300}" \
                --steps 500 --runs "$r" --stage train --device cuda --quiet >"$DATA/train_$r.log" 2>&1 &
        done
        wait
        stamp "trained six runs side by side in $((SECONDS - t0)) s"
        tail -n 2 "$DATA"/train_*.log
        $PY -c "
import sys, torch
for r in sys.argv[2:]:
    d = torch.load(f'$DATA/ablation/{r}/model.pt', weights_only=True, map_location='cpu')
    d['model'] = {k: v.half() if v.is_floating_point() else v for k, v in d['model'].items()}
    torch.save(d, f'{sys.argv[1]}/ablation_{r}.pt')
" "$OUT" white spectral polar full analytic expanded
        ;;
    *)
        echo "unknown stage $stage" >&2
        exit 2
        ;;
    esac
done
stamp done
