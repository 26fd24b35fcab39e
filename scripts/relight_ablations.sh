#!/usr/bin/env bash
# Table-3-style ablations (README "Ablations"; committed results in results/relight_ablations/).
#
#   scripts/relight_ablations.sh CKPT_ROOT [OUT_ROOT]      (or CKPT_ROOT=... in the environment)
#
# Trains the `wo_prior` and `ori_ctrlnet` ablations of the tiny diffusion relighter with the
# budget of the full model's step_000600 snapshot (600 steps, the same seed, data and
# settings, base "photo"), into CKPT_ROOT/abl_<name>/, then evaluates each with one sample
# on the 16 held-out materials into OUT_ROOT/abl_<name>/ (default: runs/relight_ablations
# under the repository root). The `full` row is evaluated too when its snapshot
# CKPT_ROOT/relight_v3/step_000600/model exists: the 600-step snapshot (`--keep-every 300`)
# of the base="photo" run in weights/diffusion/TRAINING.md ("Earlier checkpoints").
# PYTHON selects the interpreter (default .venv/bin/python).
set -euo pipefail
cd "$(dirname "$0")/.."
CKPT_ROOT="${1:-${CKPT_ROOT:-}}"
if [ -z "$CKPT_ROOT" ]; then
    echo "usage: $0 CKPT_ROOT [OUT_ROOT]  (or set CKPT_ROOT)" >&2
    exit 2
fi
OUT_ROOT="${2:-runs/relight_ablations}"
PYTHON="${PYTHON:-.venv/bin/python}"

for abl in wo_prior ori_ctrlnet; do
    ckpt="$CKPT_ROOT/abl_$abl"
    mkdir -p "$ckpt"
    date -u +%FT%TZ > "$ckpt/STARTED"
    "$PYTHON" -m relight.diffusion.train --ckpt-dir "$ckpt" --steps 600 --block-out-channels 32,64,64 \
        --resolution 64 --groups-per-step 1 --lr 2e-4 --seed 0 --ckpt-every 50 --ablation "$abl" --threads 2 \
        > "$ckpt/log.txt" 2>&1
    date -u +%FT%TZ > "$ckpt/ENDED"
    "$PYTHON" -m matcap.cli eval relighting --out "$OUT_ROOT/abl_$abl" --count 16 --methods diffusion \
        --checkpoint "diffusion=$ckpt/latest/model" --samples 1 --overwrite
done

full="$CKPT_ROOT/relight_v3/step_000600/model"
if [ -d "$full" ]; then
    "$PYTHON" -m matcap.cli eval relighting --out "$OUT_ROOT/abl_full600" --count 16 --methods input,diffusion \
        --checkpoint "diffusion=$full" --samples 1 --overwrite
else
    echo "no $full: the full row is not evaluated" >&2
fi
