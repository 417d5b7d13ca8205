#!/usr/bin/env bash
# Trains, exports and quantises the named model variants, one after the other (the recipe in README.md;
# the default model, squeezenet-half-point, is trained in two stages written out there).
#
#   models/train-variants.sh [--threads N] NAME...      e.g. models/train-variants.sh squeezenet-quarter
#
# NAME is one of the variants below. Needs the Python environment and the rendered data of README.md
# (PY, DATA, RUNS override their defaults). Each run logs to $RUNS/NAME.log.
set -euo pipefail

PY=${PY:-$HOME/.cache/relocd/venv/bin/python}
DATA=${DATA:-$HOME/.cache/relocd/data}
RUNS=${RUNS:-$HOME/.cache/relocd/runs}
THREADS=2
if [[ ${1:-} == --threads ]]; then THREADS=$2; shift 2; fi

# name: architecture width representation epochs
declare -A VARIANTS=(
  [squeezenet-half-line]="squeezenet 0.5 half-line 8"
  [squeezenet-quarter]="squeezenet 0.5 quarter 8"
  [squeezenet-full]="squeezenet 0.5 full 8"
  [alexnet-half-point]="alexnet 0.25 half-point 8"
  [alexnet-full]="alexnet 0.25 full 8"
)

cd "$(dirname "$0")"
for name in "$@"; do
  spec=${VARIANTS[$name]:?"unknown variant '$name' (known: ${!VARIANTS[*]})"}
  read -r arch width representation epochs <<<"$spec"
  "$PY" train.py --train "$DATA/train" --val "$DATA/val" --arch "$arch" --width "$width" \
    --representation "$representation" --epochs "$epochs" --seed 1 --threads "$THREADS" \
    --out "$RUNS/$name" >"$RUNS/$name.log" 2>&1
  "$PY" export.py --run "$RUNS/$name" --calibration "$DATA/val" --name "$name" \
    --data 1000:32000:black >>"$RUNS/$name.log" 2>&1
done
