#!/usr/bin/env bash
# CUDA check of the Warp kernels on a machine with an NVIDIA GPU: the kernel tests' CUDA
# cases (forward and gradients against the pure-torch twins, run on the GPU) and the
# kernel benchmark with --device cuda (Warp beside eager torch and torch.compile on the
# same GPU). The benchmark runs with --no-compile (its Warp compile-time measurement
# compiles the CPU modules) and on five of its cases: torch.compile's Triton build of
# each case's peer takes about a minute there.
#
# Usage: bash benchmarks/cuda_check.sh OUT_DIR
# Needs: a python (${PYTHON:-python3}) whose torch sees CUDA and which imports warp-lang;
# run from the repository root. Each step's log goes to OUT_DIR; a failing step does not
# stop the later ones (the exit code is the number of failed steps).
set -u
set -o pipefail
out=${1:?usage: bash benchmarks/cuda_check.sh OUT_DIR}
py=${PYTHON:-python3}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
failed=0

echo "== devices"
nvidia-smi -L 2>&1 | tee "$out/devices.txt"
"$py" - <<'EOF' 2>&1 | tee -a "$out/devices.txt" || failed=$((failed + 1))
import torch
import warp as wp

wp.init()
assert torch.cuda.is_available(), "torch sees no CUDA device"
print("torch", torch.__version__, "on", torch.cuda.get_device_name(0))
print("warp", wp.__version__, "devices", [str(d) for d in wp.get_devices()])
EOF

echo "== kernel tests, CUDA cases"
# -k cuda: the CPU cases already run in CI; these are the same tests with device="cuda".
timeout 200 "$py" -m pytest tests/kernels -q -k cuda -p no:cacheprovider -o addopts="--import-mode=importlib" \
    2>&1 | tee "$out/tests_cuda.log" | tail -40 || failed=$((failed + 1))

echo "== kernel benchmark, --device cuda"
timeout 220 "$py" benchmarks/bench_kernels.py --device cuda --threads 16 --no-peak --no-compile \
    --cases render_fwd,render_fwd_bwd,translate_fwd_bwd,rendering_loss_fwd_bwd,render_fwd_sweep_512 --out "$out/kernels_cuda.json" \
    2>&1 | tee "$out/bench_cuda.log" | tail -60 || failed=$((failed + 1))

echo "== failed steps: $failed"
exit "$failed"
