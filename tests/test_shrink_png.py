"""``scripts/shrink_png.py``: re-saving in place, lossless at 8 bits, rounded at fewer."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
from PIL import Image

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "shrink_png.py"


def _load():
    spec = importlib.util.spec_from_file_location("shrink_png", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_rgb_and_opaque_rgba_files_are_rewritten_losslessly(tmp_path):
    shrink_png = _load()
    rng = np.random.default_rng(0)
    rgb = (rng.random((32, 32, 3)) * 255).astype(np.uint8)
    a, b = tmp_path / "rgb.png", tmp_path / "rgba.png"
    Image.fromarray(rgb).save(a)  # an RGB file is returned unchanged by shrink(): saved after close
    Image.fromarray(np.dstack([rgb, np.full((32, 32), 255, np.uint8)])).save(b, compress_level=0)
    assert shrink_png.main([str(a), str(b)]) == 0
    for path in (a, b):
        with Image.open(path) as image:
            assert image.mode == "RGB" and np.array_equal(np.asarray(image), rgb)


def test_fewer_bits_round_to_multiples(tmp_path):
    shrink_png = _load()
    values = np.arange(256, dtype=np.uint8).reshape(16, 16)
    path = tmp_path / "ramp.png"
    Image.fromarray(np.dstack([values] * 3)).save(path, compress_level=0)
    assert shrink_png.main([str(path), "--bits", "5"]) == 0
    with Image.open(path) as image:
        out = np.asarray(image).astype(int)
    assert np.all((out % 8 == 0) | (out == 255)) and np.abs(out - values[..., None]).max() <= 4
