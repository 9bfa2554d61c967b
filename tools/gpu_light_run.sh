#!/usr/bin/env bash
# One rehearsed GPU lease for the lighting-aware input (issue 27 item 1): render train-light and
# val-light, fine-tune `small` with light input from the shipped model, score it, write to $OUT.
#
#   bash tools/gpu_light_run.sh                      # on a bare CUDA machine (see tools/gpu_machine.sh setup)
#   DEVICE=cpu VARIANT=llvm COUNT=4 VAL_COUNT=2 STEPS=3 BATCH=2 WORKERS=0 EVAL_COUNT=2 EVAL_JOBS=1 PBRDF_COUNT=4 \
#       SHARDS=1 OUT=/tmp/light-rehearsal bash tools/gpu_light_run.sh   # the CPU rehearsal (15 min on 2 shared cores)
#
# Sizing for a 15-minute lease (measured elsewhere on an H100: 2,000 train-engine scenes in about 100 s,
# a `small` step at batch 1 in 0.062 s): the defaults (2,000 + 64 scenes, 1,500 steps at batch 8,
# 24 scenes per test split) are a guess to re-measure on the first lease; set STEPS from its log.csv
# seconds column, and carry $RUN back in to continue (the run resumes; its schedule spans STEPS).
#
# Stages, each resumable (a killed lease reruns the script and continues):
#   1. setup (SETUP=1 and .whl/site.tar.xz present): tools/gpu_machine.sh setup;
#   2. the pBRDF library of train-data (PBRDF_COUNT tables, seed 12000) and the first COUNT scenes of
#      train-light and VAL_COUNT of val-light, SHARDS render processes with the VARIANT variant
#      (deterministic seeds: every lease renders the same scenes);
#   3. headless/train.py: `small` at 192 px (the shipped model's overrides) + light_input=true, initialised
#      from INIT (models/small/model.pt: step 0 is exactly it), STEPS steps at BATCH, bf16 on CUDA, resuming
#      $RUN when it exists (carry it in to continue a run);
#   4. the first EVAL_COUNT scenes of test-procedural and test-pbrdf rendered here (another noise draw
#      with CUDA), headless/evaluate.py on both (the shipped model and the run's best.pt) and
#      --distance-error 0.05 0.2 on test-procedural;
#   5. $OUT: best.pt/model.pt (float32 state, about 16 MB), log.csv, val.csv, eval/, timings.txt.
set -euo pipefail
OUT=${OUT:-out/gpu-light}
DATA=${GPU_DATA:-/tmp/gpu-data}
PY=${PY:-python3}
DEVICE=${DEVICE:-cuda}
VARIANT=${VARIANT:-cuda}
SHARDS=${SHARDS:-8}
COUNT=${COUNT:-2000}
VAL_COUNT=${VAL_COUNT:-64}
PBRDF_COUNT=${PBRDF_COUNT:-200}
STEPS=${STEPS:-1500}
BATCH=${BATCH:-8}
WORKERS=${WORKERS:-6}
EVAL_COUNT=${EVAL_COUNT:-24}
EVAL_JOBS=${EVAL_JOBS:-8}
INIT=${INIT:-models/small/model.pt}
RUN=${RUN:-$DATA/runs/light-small}
mkdir -p "$OUT" "$DATA"
export PYTHONUNBUFFERED=1 PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
T0=$SECONDS
stamp() { echo "== $(date -u +%H:%M:%S) +$((SECONDS - T0)) s $*" | tee -a "$OUT/timings.txt"; }

render() {  # split count [render.py arguments]: SHARDS processes into $DATA/split
    local split=$1 count=$2
    shift 2
    for k in $(seq 0 $((SHARDS - 1))); do
        $PY headless/render.py --split "$split" --count "$count" --variant "$VARIANT" --out "$DATA/$split" \
            --shard "$k/$SHARDS" --resume --quiet "$@" &
    done
    wait
    stamp "rendered $split: $(find "$DATA/$split/samples" -maxdepth 1 -name '*.exr' | wc -l) samples"
}

if [ "${SETUP:-0}" = 1 ] && [ -f .whl/site.tar.xz ]; then
    bash tools/gpu_machine.sh setup
fi
stamp "start: device $DEVICE, variant $VARIANT, $COUNT + $VAL_COUNT scenes, $STEPS steps at batch $BATCH"
[ -f "$DATA/pbrdfs-train/materials.json" ] ||
    $PY headless/expand_pbrdf.py --out "$DATA/pbrdfs-train" --count "$PBRDF_COUNT" --seed 12000 --quiet
[ -f "$DATA/pbrdfs-test/materials.json" ] ||
    $PY headless/expand_pbrdf.py --out "$DATA/pbrdfs-test" --count "$((PBRDF_COUNT < 24 ? PBRDF_COUNT : 24))" \
        --seed 22000 --quiet
stamp "pBRDF libraries"
render val-light "$VAL_COUNT" --pbrdfs "$DATA/pbrdfs-train"
render train-light "$COUNT" --pbrdfs "$DATA/pbrdfs-train"

BF16=()
[ "$DEVICE" = cuda ] && BF16=(--bf16)
$PY headless/train.py --input "$DATA/train-light" --val "$DATA/val-light" --config small \
    --overrides image_size=192 canonical_size=128 train_pixels=2048 infer_chunk=8192 light_input=true \
    --init-from "$INIT" --steps "$STEPS" --batch-size "$BATCH" --lr 1e-4 --lr-warmup "$((STEPS / 20))" \
    --min-lr-ratio 0.1 --seed 0 --input-scale calibrated --checkpoint-every "$((STEPS / 10 > 0 ? STEPS / 10 : 1))" \
    --val-samples "$VAL_COUNT" --device "$DEVICE" --workers "$WORKERS" "${BF16[@]}" --no-tensorboard \
    --out "$RUN" --resume --quiet | tee -a "$OUT/timings.txt"
stamp "trained $RUN"
for f in model.pt best.pt log.csv val.csv; do [ -f "$RUN/$f" ] && cp "$RUN/$f" "$OUT/"; done

render test-procedural "$EVAL_COUNT"
render test-pbrdf "$EVAL_COUNT" --pbrdfs "$DATA/pbrdfs-test"
BEST="$RUN/best.pt"
[ -f "$BEST" ] || BEST="$RUN/model.pt"
EVAL_DEVICE=$DEVICE
for split in test-procedural test-pbrdf; do
    for who in shipped light; do
        ckpt=$INIT
        [ "$who" = light ] && ckpt=$BEST
        $PY headless/evaluate.py --input "$DATA/$split" --checkpoint "$ckpt" --device "$EVAL_DEVICE" --jobs "$EVAL_JOBS" \
            --train-stats models/small/train_stats.json --out "$OUT/eval/$split-$who" --quiet >/dev/null
    done
    stamp "scored $split"
done
$PY headless/evaluate.py --input "$DATA/test-procedural" --checkpoint "$BEST" --device "$EVAL_DEVICE" --jobs 1 \
    --train-stats models/small/train_stats.json --distance-error 0.05 0.2 --out "$OUT/eval/distance" --quiet >/dev/null
stamp "done"
