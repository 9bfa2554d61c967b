#!/usr/bin/env bash
# One chunk of the next model's run (issue 29 item 4): on a bare GPU machine (or the CPU), set up,
# render the first COUNT scenes of train-next and VAL_COUNT of val-next (deterministic seeds: every
# lease renders the same scenes), pack them, continue the run from the committed chunk state
# (runs/next, network/chunk_state.py), train for the seconds the lease has left, and write the new
# chunk state and its curves to EXPORT. The lease procedure and the `run` call: docs/gpu_lease.md.
#
#   bash tools/gpu_chunk.sh                                   # a GPU lease (SETUP=1: unpack .whl, .gpu)
#   DEVICE=cpu VARIANT=llvm RENDER=0 DATA=out/splits EXPORT=runs/next STOP=N bash tools/gpu_chunk.sh
#                                                             # the CPU chunk (`make next-chunk`)
#
# Stages (a killed chunk reruns the script and continues each one):
#   1. setup (SETUP=1): tools/gpu_machine.sh setup (.whl/site.tar.xz) and the mesh corpus from
#      .gpu/meshes.tar.xz into corpora/ (tools/gpu_site.sh builds both);
#   2. (RENDER=1) the pBRDF library of train-data (PBRDF_COUNT tables, seed 12000), then val-next and
#      train-next by SHARDS processes with the VARIANT variant (--resume: rendered samples are kept;
#      RESOLUTION/SPP override the split's 192 px / 16 spp only for rehearsals);
#   3. headless/pack.py of both into PACKS at the model's IMAGE_SIZE (--resume; PACK=0 trains on the EXRs);
#   4. network.chunk_state.seed_run: RUN continues the chunk state STATE (bf16 weights, fresh AdamW,
#      the learning rate re-warmed over REWARM steps); without a state the run starts from INIT;
#      a RUN that already holds a newer checkpoint.pt (a killed chunk, the CPU run) resumes exactly;
#   5. headless/train.py to STEPS total (the cosine horizon of the whole run), ending after step STOP
#      (if set) or when the lease's LEASE_S seconds (counted from this script's start, less RESERVE_S
#      for stage 6) are spent: --time-budget stops validated and saved;
#   6. EXPORT: state.pt, best.pt (bf16), state.json (one row per chunk), log.csv.gz, val.csv, curves.png,
#      and OUT/timings.txt: 7 files, within what a lease brings back.
set -euo pipefail
T0=$SECONDS
OUT=${OUT:-out/gpu-chunk}
EXPORT=${EXPORT:-$OUT}
STATE=${STATE:-runs/next}
DATA=${DATA:-${GPU_DATA:-/tmp/gpu-data}}
PACKS=${PACKS:-$DATA/packs}
RUN=${RUN:-$DATA/runs/next}
PY=${PY:-python3}
DEVICE=${DEVICE:-cuda}
VARIANT=${VARIANT:-cuda}
SHARDS=${SHARDS:-16}
RENDER=${RENDER:-1}
COUNT=${COUNT:-2000}
VAL_COUNT=${VAL_COUNT:-64}
PBRDF_COUNT=${PBRDF_COUNT:-200}
CONFIG=${CONFIG:-small}
IMAGE_SIZE=${IMAGE_SIZE:-192}
OVERRIDES=${OVERRIDES:-image_size=$IMAGE_SIZE canonical_size=128 train_pixels=2048 infer_chunk=8192 light_input=true}
INIT=${INIT:-models/small/model.pt}
STEPS=${STEPS:-20000}
STOP=${STOP:-}
BATCH=${BATCH:-8}
LR=${LR:-2e-4}
WARMUP=${WARMUP:-200}
REWARM=${REWARM:-50}
WD=${WD:-0.05}
SEED=${SEED:-0}
CKPT_EVERY=${CKPT_EVERY:-250}
VAL_SAMPLES=${VAL_SAMPLES:-$VAL_COUNT}
WORKERS=${WORKERS:-8}
LEASE_S=${LEASE_S:-560}
RESERVE_S=${RESERVE_S:-40}
mkdir -p "$OUT" "$EXPORT" "$DATA"
export PYTHONUNBUFFERED=1 PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
declare -A TOOK
stamp() { echo "== $(date -u +%H:%M:%S) +$((SECONDS - T0)) s $*" | tee -a "$OUT/timings.txt"; }
samples() { find "$DATA/$1/samples" -maxdepth 1 -name '*.exr' 2>/dev/null | wc -l || true; }

render() {  # split count [render.py arguments]: SHARDS processes into $DATA/split
    local split=$1 count=$2 before
    shift 2
    before=$(samples "$split")
    local extra=()
    [ -n "${RESOLUTION:-}" ] && extra+=(--resolution "$RESOLUTION")
    [ -n "${SPP:-}" ] && extra+=(--spp "$SPP")
    local pids=()
    for k in $(seq 0 $((SHARDS - 1))); do
        $PY headless/render.py --split "$split" --count "$count" --variant "$VARIANT" --out "$DATA/$split" \
            --shard "$k/$SHARDS" --resume --quiet "${extra[@]}" "$@" &
        pids+=($!)
    done
    for p in "${pids[@]}"; do wait "$p"; done  # a failed shard fails the chunk
    stamp "rendered $split: $(samples "$split") samples ($(($(samples "$split") - before)) new)"
}

t=$SECONDS
stamp "start: device $DEVICE, variant $VARIANT, $COUNT + $VAL_COUNT scenes, state $STATE, run $RUN"
if [ "${SETUP:-0}" = 1 ]; then
    [ -f .whl/site.tar.xz ] && bash tools/gpu_machine.sh setup
    if [ ! -f corpora/meshes/.complete ] && [ -f .gpu/meshes.tar.xz ]; then
        mkdir -p corpora && tar -xJf .gpu/meshes.tar.xz -C corpora
    fi
fi
TOOK[setup]=$((SECONDS - t))
t=$SECONDS
if [ "$RENDER" = 1 ]; then
    [ -f "$DATA/pbrdfs-train/materials.json" ] ||
        $PY headless/expand_pbrdf.py --out "$DATA/pbrdfs-train" --count "$PBRDF_COUNT" --seed 12000 --quiet
    render val-next "$VAL_COUNT" --pbrdfs "$DATA/pbrdfs-train"
    render train-next "$COUNT" --pbrdfs "$DATA/pbrdfs-train"
fi
TOOK[render]=$((SECONDS - t))
t=$SECONDS
if [ "${PACK:-1}" = 1 ]; then
    for split in val-next train-next; do
        $PY headless/pack.py --input "$DATA/$split" --out "$PACKS/$split" --size "$IMAGE_SIZE" --resume --quiet
    done
    stamp "packed into $PACKS"
else  # PACK=0: the loader's workers decode the EXR samples (when packing costs more than it saves)
    PACKS=$DATA
fi
TOOK[pack]=$((SECONDS - t))

SEEDED=$($PY -c "
import json, sys
from pathlib import Path
from network.chunk_state import seed_run
step = seed_run(sys.argv[1], sys.argv[2], seed=int(sys.argv[3]), weight_decay=float(sys.argv[4]))
seeded = Path(sys.argv[2]) / 'seeded.json'
print(step, json.loads(seeded.read_text())['step'] if seeded.is_file() else 0)
" "$STATE" "$RUN" "$SEED" "$WD")
read -r START REWARM_FROM <<<"$SEEDED"
FLAGS=()
[ -f "$STATE/state.json" ] || [ -f "$RUN/checkpoint.pt" ] || FLAGS+=(--init-from "$INIT")
[ -n "$STOP" ] && FLAGS+=(--stop-after "$STOP")
[ "$DEVICE" = cuda ] && FLAGS+=(--bf16)
BUDGET=$((LEASE_S - (SECONDS - T0) - RESERVE_S))
stamp "training from step $START (re-warm from $REWARM_FROM), $BUDGET s left"
[ "$BUDGET" -ge 5 ] || { echo "error: LEASE_S=$LEASE_S leaves no time to train" >&2; exit 1; }
t=$SECONDS
# shellcheck disable=SC2086  # OVERRIDES is a list of KEY=VALUE words
$PY headless/train.py --input "$PACKS/train-next" --val "$PACKS/val-next" --config "$CONFIG" --overrides $OVERRIDES \
    --steps "$STEPS" --batch-size "$BATCH" --lr "$LR" --lr-warmup "$WARMUP" --min-lr-ratio 0.1 --weight-decay "$WD" \
    --seed "$SEED" --input-scale calibrated --checkpoint-every "$CKPT_EVERY" --val-samples "$VAL_SAMPLES" \
    --device "$DEVICE" --workers "$WORKERS" --no-tensorboard --out "$RUN" --resume --time-budget "$BUDGET" \
    --rewarm-from "$REWARM_FROM" --rewarm-steps "$REWARM" "${FLAGS[@]}" --quiet | tee -a "$OUT/timings.txt" ||
    TRAIN_RC=$?  # export what the last checkpoint holds all the same, then fail
TOOK[train]=$((SECONDS - t))
[ -f "$RUN/checkpoint.pt" ] || { echo "error: training wrote no checkpoint in $RUN" >&2; exit 1; }

CHUNK=$(printf '{"device": "%s", "variant": "%s", "scenes": %d, "val_scenes": %d, "batch": %d, "seconds": {"setup": %d, "render": %d, "pack": %d, "train": %d}}' \
    "$DEVICE" "$VARIANT" "$(samples train-next)" "$(samples val-next)" "$BATCH" "${TOOK[setup]}" "${TOOK[render]}" "${TOOK[pack]}" "${TOOK[train]}")
$PY -c "
import json, sys
from network.chunk_state import export_state
info = export_state(sys.argv[1], sys.argv[2], json.loads(sys.argv[3]), history=sys.argv[4])
print('chunk state: step', info['step'], 'in', sys.argv[2])
" "$RUN" "$EXPORT" "$CHUNK" "$STATE" | tee -a "$OUT/timings.txt"
CURVES=$(mktemp -d)
$PY tools/plot_training.py "$RUN" --out "$CURVES" >/dev/null && cp "$CURVES/curves.png" "$EXPORT/curves.png"
rm -rf "$CURVES"
stamp "done"
exit "${TRAIN_RC:-0}"
