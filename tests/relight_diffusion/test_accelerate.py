"""Two-process training through HF accelerate on the CPU (the multi-process path)."""

import os
import subprocess
import sys

import pytest

from training.checkpoint import latest_checkpoint, read_trainer_state


@pytest.mark.slow
def test_two_process_accelerate_smoke(tmp_path):
    env = dict(os.environ, ACCELERATE_USE_CPU="1", OMP_NUM_THREADS="1")
    # --multi_gpu with ACCELERATE_USE_CPU=1 runs real DDP over gloo on the CPU;
    # `--cpu --num_processes 2` would silently run one process.
    cmd = [
        sys.executable,
        "-m",
        "accelerate.commands.launch",
        "--multi_gpu",
        "--num_processes",
        "2",
        "--num_machines",
        "1",
        "--mixed_precision",
        "no",
        "--dynamo_backend",
        "no",
        "-m",
        "relight.diffusion.train",
        "--ckpt-dir",
        str(tmp_path),
        "--steps",
        "2",
        "--model.resolution",
        "16",
        "--model.block-out-channels",
        "8,16",
        "--ckpt-every",
        "100",
    ]
    result = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    folder = latest_checkpoint(tmp_path)
    assert [h["step"] for h in read_trainer_state(folder)["history"]] == [1, 2]
    assert list((folder / "model").glob("*.safetensors"))
