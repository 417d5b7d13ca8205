#!/usr/bin/env bash
# Renders the training data on every core, trains the width study on one GPU (the widths side by side),
# exports each net with its contract and copies the results out: the whole recipe in one go, for a GPU
# machine that is lent for minutes.
#
#   models/gpu-train.sh RELOCD WORK RESULTS
#
# RELOCD: a relocd binary (`cargo build --release`); WORK: scratch space for the frames (~16 GB at the
# default sizes); RESULTS: where the files to keep go (the exported models, each run's training.json and
# log, the default's weights.pt and parity fixture). The exported files also land in models/ as
# export.py writes them. Settings (environment, defaults as used for the committed default):
#
#   FRAMES=40000 VAL_FRAMES=1500    frames per kind (plain and hall realism) for training and validation
#   WIDTHS="0.5 0.75 1.0"           SqueezeNet widths trained side by side (one process each)
#   EPOCHS="30 24 20"               epochs per width, in the order of WIDTHS (the most, with a budget)
#   TRAIN_BUDGET=0                  seconds of training per width (train.py --time-budget; 0: none)
#   DEADLINE=                       or: seconds after the start by which all must be done; the training
#                                   budget is what is left after rendering, less RESERVE=150 s
#   DEFAULT_WIDTH=0.5               exported as squeezenet-half-point (the others as ...-wNNN)
#   VERSION=3                       the model version in the model ids
#   DEVICE=cuda                     train.py --device (cpu runs the same recipe on the CPU, slowly)
#   PRECISION=auto                  train.py --precision (auto: bf16 on a GPU, fp32 on the CPU)
#   INIT_ONNX=                      an fp32 ONNX file (path from models/) to continue instead of starting
#                                   from scratch (train.py --init-onnx), e.g. squeezenet-half-point.fp32.onnx
#   LR=3e-3 SEED=1                  train.py --lr and --seed (a continuation: a third of the rate, a new seed)
#   PYTHON=python3
#
# Seeds (models/README.md, "Recipe"): training 1010 (plain) and 1011 (hall realism), validation 2010
# and 2011, training seed 1; all rendered with the real robot's camera range below.
set -euo pipefail
cd "$(dirname "$0")"

relocd=$(realpath "$1") work=$2 results=$3
FRAMES=${FRAMES:-40000} VAL_FRAMES=${VAL_FRAMES:-1500}
WIDTHS=${WIDTHS:-"0.5 0.75 1.0"} EPOCHS=${EPOCHS:-"30 24 20"}
DEFAULT_WIDTH=${DEFAULT_WIDTH:-0.5} VERSION=${VERSION:-3} DEVICE=${DEVICE:-cuda} PRECISION=${PRECISION:-auto}
LR=${LR:-3e-3} SEED=${SEED:-1}
init=()
if [ -n "${INIT_ONNX:-}" ]; then
    init=(--init-onnx "$(realpath "$INIT_ONNX")")
    [ "$(wc -w <<< "$WIDTHS")" = 1 ] || { echo "INIT_ONNX continues one network: set WIDTHS to its width" >&2; exit 2; }
fi
PYTHON=${PYTHON:-python3}
# The real Nao's top camera (issue 18): crouched walk to standing, 10° up to 25° down, rolled ±5°.
CAMERA=(--camera-height 0.38,0.55 --camera-pitch=-10,25 --max-camera-roll 5)
mkdir -p "$work" "$results"
started=$SECONDS
stamp() { echo "[$((SECONDS - started)) s] $*"; }

# 1. Data, at the network's input size. relocd render uses every core (rayon).
for split in "train $FRAMES 1010" "train-realism $FRAMES 1011" "val $VAL_FRAMES 2010" "val-realism $VAL_FRAMES 2011"; do
    set -- $split
    [ -s "$work/$1/frames.jsonl" ] && continue
    extra=()
    [[ $1 == *realism ]] && extra=(--hall-realism)
    stamp "render $1: $2 frames, seed $3"
    "$relocd" render --out "$work/$1" --count "$2" --seed "$3" --width 160 --height 120 "${CAMERA[@]}" "${extra[@]}" \
        > "$work/$1.json" 2> "$work/$1.render.log"
done
stamp "decode frames into the npz caches"
for split in train train-realism val val-realism; do
    "$PYTHON" -c "import sys; from relocnet.data import load_recording; load_recording(sys.argv[1])" "$work/$split"
done

# 2. Train the widths side by side.
name_of() {
    if [ "$1" = "$DEFAULT_WIDTH" ]; then echo squeezenet-half-point; else awk -v w="$1" 'BEGIN { printf "squeezenet-half-point-w%03d\n", w * 100 + 0.5 }'; fi
}
epochs=($EPOCHS) pids=() index=0
budget=${TRAIN_BUDGET:-0}
[ -n "${DEADLINE:-}" ] && budget=$((DEADLINE - (SECONDS - started) - ${RESERVE:-150}))
[ "$budget" -ge 0 ] || { stamp "no time left to train (budget $budget s)"; exit 1; }
for width in $WIDTHS; do
    name=$(name_of "$width")
    stamp "train $name: width $width, at most ${epochs[$index]} epochs on $DEVICE, budget $budget s"
    PYTHONUNBUFFERED=1 "$PYTHON" train.py --train "$work/train" "$work/train-realism" --val "$work/val" "$work/val-realism" \
        --arch squeezenet --width "$width" --representation half-point --epochs "${epochs[$index]}" --seed "$SEED" \
        --lr "$LR" "${init[@]}" --device "$DEVICE" --precision "$PRECISION" --threads 2 --time-budget "$budget" \
        --out "$work/runs/$name" > "$work/$name.log" 2>&1 &
    pids+=($!)
    index=$((index + 1))
done
# The last line of each run's log every 30 s, while they train.
(while sleep 30; do for width in $WIDTHS; do
    name=$(name_of "$width"); stamp "$name: $(tail -n 1 "$work/$name.log" | cut -c 1-240)"; done; done) &
watcher=$!
status=0
for pid in "${pids[@]}"; do wait "$pid" || status=1; done
kill "$watcher"
for width in $WIDTHS; do name=$(name_of "$width"); stamp "$name:"; tail -n 3 "$work/$name.log" | cut -c 1-700; done
for width in $WIDTHS; do
    name=$(name_of "$width")
    cp "$work/$name.log" "$results/"
    [ -f "$work/runs/$name/training.json" ] && cp "$work/runs/$name/training.json" "$results/$name.training.json"
done
[ "$status" = 0 ] || { stamp "a training run failed (logs in $results)"; exit 1; }
stamp "trained"

# 3. Export each with its contract (the default with its parity fixture), side by side, and keep the results.
pids=()
for width in $WIDTHS; do
    name=$(name_of "$width")
    stamp "export $name"
    "$PYTHON" export.py --run "$work/runs/$name" --calibration "$work/val" "$work/val-realism" --name "$name" \
        --data "1010:$FRAMES:black" --data "1011:$FRAMES:hall-realism" --version "$VERSION" --keep-fp32 \
        "${CAMERA[@]}" > "$work/$name.export.log" 2>&1 &
    pids+=($!)
done
for pid in "${pids[@]}"; do wait "$pid" || status=1; done
for width in $WIDTHS; do
    name=$(name_of "$width")
    cat "$work/$name.export.log"
    cp "$work/$name.export.log" "$name.fp32.onnx" "$results/" || status=1
    if [ "$name" = squeezenet-half-point ]; then
        cp "$name.int8.onnx" "fixtures/parity/$name.json" "$results/" || status=1
        cp "$work/runs/$name/weights.pt" "$results/$name.weights.pt"
    fi
done
[ "$status" = 0 ] || { stamp "an export failed (logs in $results)"; exit 1; }
stamp "done"
