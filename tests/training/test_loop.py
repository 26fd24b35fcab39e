"""training.loop: the shared step loop updates with the scheduled rate, checkpoints every
N steps and at the end, and stops on the step count, the data, the wall-clock budget or
a signal, always with a checkpoint."""

import signal

import pytest
import torch
from accelerate import Accelerator
from diffusers.configuration_utils import ConfigMixin, register_to_config
from diffusers.models.modeling_utils import ModelMixin

from training.checkpoint import latest_checkpoint, read_trainer_state
from training.loop import Loop


class Line(ModelMixin, ConfigMixin):
    @register_to_config
    def __init__(self, width: int = 2):
        super().__init__()
        self.lin = torch.nn.Linear(width, 1)

    def forward(self, x):
        return self.lin(x)


def _loop(tmp_path, steps=5, **kw):
    accel = Accelerator(cpu=True)
    torch.manual_seed(0)
    model = Line()
    optimizer = torch.optim.SGD(model.parameters(), lr=0.0)
    model, optimizer = accel.prepare(model, optimizer)
    kw = {"lr": lambda step: 0.1 / (step + 1), "ckpt_every": 2, "progress": False, **kw}
    return Loop(accel, model, optimizer, steps=steps, ckpt_dir=tmp_path, config={"run": "test"}, **kw)


def _step(loop, seen):
    def step_fn(step):
        seen.append((step, loop.optimizer.param_groups[0]["lr"]))
        loss = loop.model(torch.ones(3, 2)).pow(2).mean()
        return loss, {"loss": float(loss.detach())}

    return step_fn


def test_runs_to_the_step_count_with_the_schedule_and_checkpoints(tmp_path):
    loop, seen = _loop(tmp_path), []
    assert loop.run(_step(loop, seen)) == 5
    assert [s for s, _ in seen] == [0, 1, 2, 3, 4]
    lrs = [g for _, g in seen[1:]]  # the rate set for an update is visible from the next step on
    assert lrs == pytest.approx([0.1 / (s + 1) for s in range(4)])
    assert sorted(p.name for p in tmp_path.glob("checkpoint-*")) == ["checkpoint-0000004", "checkpoint-0000005"]
    state = read_trainer_state(latest_checkpoint(tmp_path))
    assert state["config"] == {"run": "test"} and [h["step"] for h in state["history"]] == [1, 2, 3, 4, 5]
    assert (tmp_path / "loss.png").is_file()


def test_resuming_at_the_end_does_nothing(tmp_path, capsys):
    loop, seen = _loop(tmp_path), []
    assert loop.run(_step(loop, seen), start=5) == 5 and seen == []
    assert "nothing to do" in capsys.readouterr().out
    assert latest_checkpoint(tmp_path) is None


def test_the_end_of_the_data_ends_the_run_with_a_checkpoint(tmp_path):
    loop, seen = _loop(tmp_path, steps=10), []
    inner = _step(loop, seen)

    def step_fn(step):
        if step == 3:
            raise StopIteration
        return inner(step)

    assert loop.run(step_fn) == 3
    assert latest_checkpoint(tmp_path).name == "checkpoint-0000003"


def test_budget_stops_after_at_least_one_step(tmp_path):
    loop, seen = _loop(tmp_path, steps=1000, minutes=1e-9), []
    assert loop.run(_step(loop, seen)) == 1
    assert latest_checkpoint(tmp_path).name == "checkpoint-0000001"


def test_a_signal_ends_the_step_in_progress_then_checkpoints(tmp_path):
    loop, seen = _loop(tmp_path, steps=1000), []
    inner = _step(loop, seen)
    # Whatever the process started with: Python's default_int_handler in a terminal,
    # SIG_IGN when a non-interactive shell started it in the background.
    before = signal.getsignal(signal.SIGINT)

    def step_fn(step):
        if step == 2:
            signal.raise_signal(signal.SIGINT)  # as Ctrl-C or a scheduler's SIGTERM would
        return inner(step)

    assert loop.run(step_fn) == 3
    assert latest_checkpoint(tmp_path).name == "checkpoint-0000003"
    assert signal.getsignal(signal.SIGINT) is before  # the handler is put back
