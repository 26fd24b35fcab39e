"""The shipped BieronRelighter checkpoint: present, small, loads by default, and relights
the evaluation lights through the interface and the command line."""

from pathlib import Path

import numpy as np
import pytest
import torch

from relight.interface import SHIPPED_WEIGHTS, get_relighter

FOLDER = SHIPPED_WEIGHTS / "bieron"
#: Shipped weights must stay small enough for the repository (issue 6: "small").
MAX_BYTES = 10 * 1024 * 1024

pytestmark = pytest.mark.skipif(not (FOLDER / "config.json").is_file(), reason="no shipped bieron weights")


def test_shipped_weights_are_small_and_documented():
    files = list(FOLDER.glob("*.safetensors"))
    assert len(files) == 1 and files[0].stat().st_size < MAX_BYTES
    assert (FOLDER / "TRAINING.md").is_file()


def test_default_bieron_loads_the_shipped_weights():
    relighter = get_relighter("bieron")
    photo = torch.rand(1, 3, 32, 32) * 0.3
    light_pos = torch.tensor([[[2.0, 2.0, 4.0], [-1.0, 0.5, 7.0]]])
    camera_pos = torch.tensor([[0.0, 0.0, 4.0]])
    out = relighter.relight(photo, light_pos, camera_pos)
    assert out.shape == (1, 2, 3, 32, 32) and torch.isfinite(out).all() and (out >= 0).all() and (out <= 1).all()


def test_cli_generate_with_the_shipped_model(tmp_path):
    from matcap.cli import main
    from materials.io import write_png

    write_png(tmp_path / "p.png", np.full((64, 64, 3), 0.5, dtype=np.float32))
    assert main(["generate", str(tmp_path / "p.png"), "--model", "bieron", "--out", str(tmp_path / "g")]) == 0
    assert len(list(Path(tmp_path / "g").glob("relit_*.png"))) == 7
