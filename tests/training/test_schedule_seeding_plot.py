"""training.schedule (functions of the step: warm-up, hold, cosine to a floor),
training.seeding (one seed per (seed, step, stream)) and training.plot (an atomic PNG)."""

import math

import pytest
import torch

from training.plot import plot_loss, running_mean
from training.schedule import constant, lr_factor, set_lr, warmup_cosine
from training.seeding import SEED_STRIDE, step_generator, step_seed


def test_warmup_then_cosine_to_the_floor():
    f = [warmup_cosine(s, total=100, warmup=10, floor=0.1) for s in range(120)]
    assert f[:10] == pytest.approx([(s + 1) / 10 for s in range(10)])
    assert f[10] == 1.0 and f[55] == pytest.approx(0.55) and f[100] == pytest.approx(0.1)
    assert all(a >= b for a, b in zip(f[10:], f[11:]))  # never rises after the warm-up
    assert f[119] == f[100]  # stays at the floor past the end


def test_constant_then_cosine_to_zero():
    f = [warmup_cosine(s, total=300, decay_from=100) for s in range(301)]
    assert set(f[:101]) == {1.0}
    assert math.isclose(f[200], 0.5, rel_tol=1e-12) and f[300] == pytest.approx(0.0, abs=1e-15)


def test_constant_and_the_dispatcher():
    assert [constant(s, warmup=4) for s in range(6)] == [0.25, 0.5, 0.75, 1.0, 1.0, 1.0]
    assert lr_factor("constant", 7, total=10) == 1.0
    assert lr_factor("cosine", 5, total=10) == warmup_cosine(5, total=10)
    with pytest.raises(ValueError, match="schedule"):
        lr_factor("linear", 0, total=10)
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    set_lr(opt, 0.25)
    assert opt.param_groups[0]["lr"] == 0.25


def test_step_seeds_are_distinct_and_bounded():
    seeds = {step_seed(seed, step, stream) for seed in range(3) for step in range(50) for stream in range(8)}
    assert len(seeds) == 3 * 50 * 8
    assert step_seed(2, 7, 63, streams=64) == (2 * SEED_STRIDE + 7) * 64 + 63
    with pytest.raises(ValueError, match="stream"):
        step_seed(0, 0, 8)
    with pytest.raises(ValueError, match="step"):
        step_seed(0, SEED_STRIDE)
    a, b = step_generator(1, 5, 2), step_generator(1, 5, 2)
    assert torch.equal(torch.rand(4, generator=a), torch.rand(4, generator=b))


def test_plot_writes_a_png_and_nothing_for_an_empty_history(tmp_path):
    history = [{"step": s, "loss": 1.0 / s, "map": 0.5 / s} for s in range(1, 120)]
    plot_loss(history, tmp_path / "loss.png", keys=("loss", "map"), smooth=25)
    assert (tmp_path / "loss.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    plot_loss([], tmp_path / "empty.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loss.png"]  # no temporary left either
    assert running_mean([1, 2, 3, 4], 2).tolist() == [1.5, 2.5, 3.5]
