"""The step loop the trainers share: learning rate, backward through accelerate, clipping,
EMA, history, progress bar, log lines, checkpoints every N steps and at the end, a
wall-clock budget, and a clean stop on SIGTERM / SIGINT.

What a step computes stays in the trainer: ``Loop.run(step_fn)`` calls
``step_fn(step) -> (loss, record)`` for ``step = start, start + 1, ...`` and does the rest.
A trainer's ``main`` reads: build or resume the model, build the optimizer, prepare with
accelerate, ``Loop(...).run(step_fn)``.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import torch
from tqdm.auto import tqdm

from training.checkpoint import TrainerState, save_checkpoint, trainable_parameters
from training.plot import plot_loss
from training.schedule import set_lr

__all__ = ["Loop", "resumed_line"]


def resumed_line(state: TrainerState) -> str:
    """The line a trainer prints when it resumes (one wording for all of them)."""
    return f"resumed from step {state.step} of {state.folder} ({state.elapsed_s / 60:.1f} min trained)"


class Loop:
    """One training run's loop (module docstring).

    Args:
        accelerator: an ``accelerate.Accelerator``; ``model`` and ``optimizer`` are
            already prepared by it.
        model, optimizer: the (prepared) model and optimizer.
        lr: the learning rate of the update at a step (``training.schedule``).
        steps: the run's total; the loop ends there.
        ckpt_dir: checkpoints and ``loss.png`` go here (``training.checkpoint``).
        config: the run config (JSON dict), stored in every checkpoint.
        ckpt_every: checkpoint every this many steps (and always at the end).
        keep, keep_every: checkpoints kept (``save_checkpoint``).
        minutes: wall-clock budget of this run (0: none); checked after each step, so a
            run does at least one step. A resumed run gets the budget anew.
        grad_clip: clip the gradient norm to it (0: no clipping).
        ema: optional EMA (diffusers' ``EMAModel``) built on the unwrapped model's
            ``trainable_parameters``; stepped after each update.
        desc: the progress bar's label.
        progress: show a progress bar (main process only).
        log_every: print the mean of ``log_keys`` every this many steps (0: never).
        log_keys: the history keys logged and plotted.
        ylabel, title: of the loss plot.
    """

    def __init__(
        self,
        accelerator,
        model: torch.nn.Module,
        optimizer: torch.optim.Optimizer,
        *,
        lr: Callable[[int], float],
        steps: int,
        ckpt_dir: str | Path,
        config: dict,
        ckpt_every: int,
        keep: int = 2,
        keep_every: int = 0,
        minutes: float = 0.0,
        grad_clip: float = 0.0,
        ema=None,
        desc: str = "train",
        progress: bool = True,
        log_every: int = 0,
        log_keys: Sequence[str] = ("loss",),
        ylabel: str = "loss",
        title: str = "training loss",
    ):
        if ckpt_every < 1:
            raise ValueError(f"ckpt_every must be at least 1, got {ckpt_every}")
        self.accelerator, self.model, self.optimizer, self.ema = accelerator, model, optimizer, ema
        self.lr, self.steps, self.minutes, self.grad_clip = lr, steps, minutes, grad_clip
        self.ckpt_dir, self.config = Path(ckpt_dir), config
        self.ckpt_every, self.keep, self.keep_every = ckpt_every, keep, keep_every
        self.desc, self.progress, self.log_every, self.log_keys = desc, progress, log_every, tuple(log_keys)
        self.ylabel, self.title = ylabel, title
        self.ema_params = trainable_parameters(accelerator.unwrap_model(model)) if ema is not None else None
        self.last_checkpoint: Path | None = None

    # ------------------------------------------------------------------ pieces
    def update(self, loss: torch.Tensor, step: int) -> float:
        """One optimizer update at ``step``: set the rate, backward, clip, step, EMA.
        Returns the rate used."""
        lr = self.lr(step)
        set_lr(self.optimizer, lr)
        self.optimizer.zero_grad(set_to_none=True)
        self.accelerator.backward(loss)
        if self.grad_clip > 0:
            self.accelerator.clip_grad_norm_(self.model.parameters(), self.grad_clip)
        self.optimizer.step()
        if self.ema is not None:
            self.ema.step(self.ema_params)
        return lr

    def checkpoint(self, step: int, history: list[dict], elapsed_s: float) -> None:
        """Save (main process), plot the loss; every process waits for it."""
        accel = self.accelerator
        accel.wait_for_everyone()
        if accel.is_main_process:
            self.last_checkpoint = save_checkpoint(
                self.ckpt_dir,
                step=step,
                model=accel.unwrap_model(self.model),
                optimizer=self.optimizer,
                history=history,
                config=self.config,
                elapsed_s=elapsed_s,
                ema=self.ema,
                keep=self.keep,
                keep_every=self.keep_every,
            )
            self.plot(history, self.ckpt_dir / "loss.png")
        accel.wait_for_everyone()

    def plot(self, history: list[dict], path: Path) -> None:
        plot_loss(history, path, keys=self.log_keys, ylabel=self.ylabel, title=self.title)

    def _due(self, step: int) -> bool:
        return step % self.ckpt_every == 0 or bool(self.keep_every and step % self.keep_every == 0)

    # ------------------------------------------------------------------ the loop
    def run(
        self,
        step_fn: Callable[[int], tuple[torch.Tensor, dict[str, float]]],
        *,
        start: int = 0,
        history: list[dict] | None = None,
        elapsed_s: float = 0.0,
    ) -> int:
        """Train from ``start`` until ``steps``, the budget, a stop signal, or the end of
        the data (``step_fn`` raising ``StopIteration``); checkpoint at the end. Appends
        ``{"step", **record, "elapsed_s"}`` to ``history`` per step; returns the last step."""
        history = [] if history is None else history
        accel = self.accelerator
        begin = time.monotonic()
        budget_s = self.minutes * 60 if self.minutes > 0 else float("inf")
        step, saved = start, start
        bar = tqdm(
            total=self.steps,
            initial=start,
            desc=self.desc,
            disable=not (self.progress and accel.is_local_main_process),
            mininterval=5.0,
            dynamic_ncols=True,
        )
        tick = time.perf_counter()
        self.model.train()
        with _StopOnSignal() as stop:
            while step < self.steps:
                try:
                    loss, record = step_fn(step)
                except StopIteration:
                    accel.print(f"{self.desc}: the data ran out at step {step}")
                    break
                lr = self.update(loss, step)
                step += 1
                elapsed = elapsed_s + time.monotonic() - begin
                history.append({"step": step, **record, "elapsed_s": round(elapsed, 2)})
                bar.update(1)
                recent = history[-50:]
                bar.set_postfix(loss=f"{sum(h['loss'] for h in recent) / len(recent):.4f}", lr=f"{lr:.2e}")
                if self.log_every and step % self.log_every == 0:
                    window = history[-self.log_every :]
                    per_step = (time.perf_counter() - tick) / len(window)
                    tick = time.perf_counter()
                    means = " ".join(f"{k} {sum(h[k] for h in window) / len(window):.4f}" for k in self.log_keys)
                    accel.print(f"step {step} {means} lr {lr:.2e} {per_step:.2f} s/step", flush=True)
                if self._due(step):
                    self.checkpoint(step, history, elapsed)
                    saved = step
                if time.monotonic() - begin > budget_s:
                    accel.print(f"{self.desc}: the {self.minutes:g}-minute budget is spent at step {step}")
                    break
                if stop.is_set():
                    accel.print(f"{self.desc}: stopped by a signal at step {step}")
                    break
        bar.close()
        if step > saved:
            self.checkpoint(step, history, elapsed_s + time.monotonic() - begin)
        if start >= self.steps:
            accel.print(f"{self.desc}: nothing to do, {self.ckpt_dir} is at step {start} >= steps {self.steps}")
        return step


class _StopOnSignal:
    """Within the block, SIGTERM / SIGINT set a flag (the loop ends after the step in
    progress and checkpoints) instead of killing the process; the previous handlers come
    back on exit. Only the main thread can install handlers; elsewhere the flag stays unset."""

    def __enter__(self) -> threading.Event:
        self.flag, self.previous = threading.Event(), {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                self.previous[sig] = signal.signal(sig, lambda *_: self.flag.set())
        return self.flag

    def __exit__(self, *exc) -> None:
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)
