"""``scripts/interpolate_weights.py``: the straight line between two checkpoints of one model."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch

from estimator.config import TINY_TEST_CONFIG
from estimator.model import SVBRDFEstimator

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "interpolate_weights.py"
#: ``torch.lerp`` and ``0.4 a + 0.6 b`` round differently: each is within 2 float32 roundings
#: (half an ulp each) of the exact value, so they differ by at most 2 ulps of the largest
#: operand; 4 ulps leaves room. A wrong alpha (0.5 or 0.7) moves weights by ~1e-2.
LERP_ULPS = 4


def _load():
    spec = importlib.util.spec_from_file_location("interpolate_weights", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _saved(folder: Path, seed: int) -> dict[str, torch.Tensor]:
    torch.manual_seed(seed)
    model = SVBRDFEstimator(**TINY_TEST_CONFIG.to_dict())
    model.save_pretrained(folder)
    return {k: v.clone() for k, v in model.state_dict().items()}


def test_interpolation_is_exact_at_the_ends_and_linear_between(tmp_path):
    interpolate = _load().interpolate
    a, b = _saved(tmp_path / "a", 0), _saved(tmp_path / "b", 1)
    for alpha in (0.0, 0.6, 1.0):
        out = tmp_path / f"mix{alpha}"
        interpolate(tmp_path / "a", tmp_path / "b", alpha, out)
        mixed = SVBRDFEstimator.from_pretrained(out).state_dict()  # loads as the model it was
        for name, x in a.items():
            if not x.is_floating_point():
                assert torch.equal(mixed[name], x), name
            elif alpha in (0.0, 1.0):
                assert torch.equal(mixed[name], x if alpha == 0.0 else b[name]), name
            else:
                scale = float(torch.maximum(x.abs(), b[name].abs()).max())
                atol = LERP_ULPS * torch.finfo(torch.float32).eps * scale
                torch.testing.assert_close(mixed[name], 0.4 * x + 0.6 * b[name], rtol=0, atol=atol)
    assert any(not torch.equal(a[k], b[k]) for k in a)  # the two ends differ


def test_interpolation_refuses_other_architectures_and_bad_alpha(tmp_path):
    interpolate = _load().interpolate
    _saved(tmp_path / "a", 0)
    torch.manual_seed(0)
    other = SVBRDFEstimator(**{**TINY_TEST_CONFIG.to_dict(), "shading_channels": 0})
    other.save_pretrained(tmp_path / "other")
    with pytest.raises(ValueError, match="different architectures"):
        interpolate(tmp_path / "a", tmp_path / "other", 0.5, tmp_path / "out")
    with pytest.raises(ValueError, match=r"alpha must lie in \[0, 1\]"):
        interpolate(tmp_path / "a", tmp_path / "a", 1.5, tmp_path / "out")
