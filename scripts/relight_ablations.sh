#!/usr/bin/env bash
# Waits for the main relight_v3 run, then trains the Table-3 ablations with the same
# budget as the full model's step_000600 snapshot (600 steps, same seed and settings).
cd /work/main
source .venv/bin/activate
while pgrep -f "ckpt-dir /work/ckpt/relight_v3" > /dev/null; do sleep 10; done
for abl in wo_prior ori_ctrlnet; do
  mkdir -p /work/ckpt/abl_$abl
  date -u +%FT%TZ > /work/ckpt/abl_$abl/STARTED
  python -m relight.diffusion.train --ckpt-dir /work/ckpt/abl_$abl --steps 600 --block-out-channels 32,64,64 \
    --resolution 64 --groups-per-step 1 --lr 2e-4 --seed 0 --ckpt-every 50 --ablation $abl --threads 2 \
    > /work/ckpt/abl_$abl/log.txt 2>&1
  date -u +%FT%TZ > /work/ckpt/abl_$abl/ENDED
done
