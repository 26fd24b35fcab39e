"""Train ``BieronRelighter`` on rendered procedural groups (thin entry point).

    python -m relight.bieron.train --ckpt-dir /work/ckpt/bieron --minutes 50 --size 64

Data: ``materials.dataset.RenderedGroups`` (one procedural material under 8 lights per
group, paper light sampling, SPEC section 3). Input = view 0 (flash at the camera);
targets = ``targets_per_group`` of views 1..7 (all 7 by default; a random subset per
group trades lights for more materials per step at the same cost).

Loss: mean L1 between the network's tone-mapped prediction and
``kernels.tonemap(target)`` (clamp then x^(1/2.2), SPEC section 2): the images the
evaluation compares (PSNR/SSIM/FLIP on tone-mapped [0, 1] images).

Optimiser: AdamW with linear warm-up, then constant or cosine decay; the cosine's
progress is ``max(step / steps, elapsed / budget)``, so a wall-clock budget
(``--minutes``) still ends at the low learning rate.

Checkpoints (``relight.bieron.checkpoint``): every ``ckpt_minutes`` of wall clock (and
at the end, also on SIGTERM / SIGINT, which end the run after the current step), atomically; a rerun with the same ``ckpt_dir`` resumes from the newest one.
Each batch is drawn from a generator seeded by (seed, step, process), so a resumed run
sees the same data it would have seen without the interruption.

Several processes (HF accelerate, e.g. ``accelerate launch --multi_gpu``) each draw
their own groups; gradients are averaged by the prepared model.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from accelerate import Accelerator
from tqdm.auto import tqdm

import kernels
from materials.dataset import TRAIN_SEEDS, GroupConfig, RenderedGroups
from relight.bieron.checkpoint import latest_checkpoint, load_state, save_checkpoint
from relight.bieron.model import BieronRelighter

__all__ = ["TrainConfig", "main", "sample_batch", "training_loss", "parse_args", "plot_loss_curve"]


@dataclass
class TrainConfig:
    """Training run settings (every field is a command-line flag, ``_`` -> ``-``)."""

    ckpt_dir: str = "/work/ckpt/bieron"
    steps: int = 100_000  # upper bound; --minutes usually ends the run first
    minutes: float = 0.0  # wall-clock budget of this run (0: none)
    size: int = 64
    batch: int = 8  # groups (materials) per step
    targets_per_group: int = 7
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    schedule: str = "cosine"  # "cosine" or "constant"
    min_lr_ratio: float = 0.05  # cosine floor, as a fraction of lr
    grad_clip: float = 1.0
    seed: int = 0
    threads: int = 1  # torch intra-op threads (the CPU is shared)
    ckpt_minutes: float = 5.0
    keep: int = 2  # checkpoint folders kept
    base_channels: int = 32
    channel_mults: tuple[int, ...] = (1, 2, 4, 4)
    blocks_per_level: int = 1
    norm_groups: int = 8
    residual: str = "lambertian"  # BieronRelighter output parameterisation ("none": plain)
    resume: bool = True
    progress: bool = True

    def __post_init__(self) -> None:
        self.channel_mults = tuple(int(m) for m in self.channel_mults)
        if self.schedule not in ("cosine", "constant"):
            raise ValueError(f"schedule must be 'cosine' or 'constant', got {self.schedule!r}")
        if not 1 <= self.targets_per_group <= 7:
            raise ValueError(f"targets_per_group must be in 1..7 (views 1..7), got {self.targets_per_group}")
        if self.batch < 1 or self.steps < 1:
            raise ValueError(f"batch and steps must be positive, got {self.batch}, {self.steps}")

    def model_kwargs(self) -> dict:
        return dict(
            base_channels=self.base_channels,
            channel_mults=self.channel_mults,
            blocks_per_level=self.blocks_per_level,
            norm_groups=self.norm_groups,
            residual=self.residual,
        )


def sample_batch(data: RenderedGroups, cfg: TrainConfig, step: int, process: int = 0) -> dict:
    """The batch of ``step``: ``photo [B, 3, H, W]``, ``light_pos [B, T, 3]``, ``camera_pos [B, 3]``,
    ``target [B, T, 3, H, W]`` (linear radiance), deterministic in (seed, step, process)."""
    gen = torch.Generator().manual_seed((cfg.seed * 1_000_003 + step) * 64 + process)
    index = torch.randint(0, len(data), (cfg.batch,), generator=gen)
    items = [data[int(i)] for i in index]
    views = torch.stack([torch.randperm(7, generator=gen)[: cfg.targets_per_group] + 1 for _ in items])
    return {
        "photo": torch.stack([it["images"][0] for it in items]),
        "light_pos": torch.stack([it["light_pos"][v] for it, v in zip(items, views)]),
        "camera_pos": torch.stack([it["camera_pos"][0] for it in items]),
        "target": torch.stack([it["images"][v] for it, v in zip(items, views)]),
    }


def training_loss(model, batch: dict) -> torch.Tensor:
    """Mean L1 between the prediction and the tone-mapped target (module docstring)."""
    pred = model(batch["photo"], batch["light_pos"], batch["camera_pos"])
    return (pred - kernels.tonemap(batch["target"])).abs().mean()


def _lr_factor(cfg: TrainConfig, step: int, elapsed: float) -> float:
    warm = min(1.0, (step + 1) / max(1, cfg.warmup_steps))
    if cfg.schedule == "constant":
        return warm
    progress = step / cfg.steps
    if cfg.minutes > 0:
        progress = max(progress, elapsed / (cfg.minutes * 60))
    cos = 0.5 * (1 + math.cos(math.pi * min(1.0, progress)))
    return warm * (cfg.min_lr_ratio + (1 - cfg.min_lr_ratio) * cos)


def plot_loss_curve(history: dict, path: Path) -> None:
    """Loss per step (faint) and its running mean over 50 steps, log scale, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    loss = torch.tensor(history["loss"], dtype=torch.float64)
    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=100)
    if len(loss):
        steps = torch.arange(1, len(loss) + 1)
        ax.plot(steps, loss, color="tab:blue", alpha=0.25, lw=0.8, label="step")
        w = min(50, len(loss))
        smooth = torch.nn.functional.avg_pool1d(loss[None, None], w, stride=1)[0, 0]
        ax.plot(steps[w - 1 :], smooth, color="tab:blue", lw=1.8, label=f"mean of {w}")
        ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("L1 on tone-mapped images")
    ax.set_title("BieronRelighter training loss")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp)
    plt.close(fig)
    tmp.replace(path)


def main(cfg: TrainConfig) -> dict:
    """Train (or resume) and return a summary dict (step, elapsed_s, final_loss, checkpoint)."""
    torch.set_num_threads(cfg.threads)
    accelerator = Accelerator(cpu=not torch.cuda.is_available())
    ckpt_dir = Path(cfg.ckpt_dir)
    torch.manual_seed(cfg.seed)

    step, prior_elapsed, history = 0, 0.0, {"loss": [], "elapsed_s": []}
    last = latest_checkpoint(ckpt_dir) if cfg.resume else None
    if last is not None:
        model = BieronRelighter.from_pretrained(last / "model")
        state, history = load_state(last)
        step, prior_elapsed = int(state["step"]), float(state["elapsed_s"])
    else:
        model = BieronRelighter(**cfg.model_kwargs())
    optimizer = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    if last is not None:
        optimizer.load_state_dict(state["optimizer"])
        torch.set_rng_state(state["rng"])
        accelerator.print(f"resumed from {last} (step {step}, {prior_elapsed / 60:.1f} min)")
    model, optimizer = accelerator.prepare(model, optimizer)
    model.train()

    data = RenderedGroups(TRAIN_SEEDS, GroupConfig(size=cfg.size, views=8, seed=cfg.seed))
    start = time.monotonic()
    last_save = start
    budget_s = cfg.minutes * 60 if cfg.minutes > 0 else math.inf

    def elapsed() -> float:
        return prior_elapsed + time.monotonic() - start

    def checkpoint() -> Path | None:
        path = None
        if accelerator.is_main_process:
            state = {
                "step": step,
                "elapsed_s": elapsed(),
                "optimizer": optimizer.state_dict(),
                "rng": torch.get_rng_state(),
                "config": json.dumps(dataclasses.asdict(cfg)),
            }
            path = save_checkpoint(ckpt_dir, accelerator.unwrap_model(model), state, history, keep=cfg.keep)
            plot_loss_curve(history, ckpt_dir / "loss_curve.png")
        accelerator.wait_for_everyone()
        return path

    bar = tqdm(
        total=cfg.steps,
        initial=step,
        disable=not (cfg.progress and accelerator.is_main_process),
        mininterval=10,
        desc="bieron",
        dynamic_ncols=True,
    )
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    path = None
    # The budget is per run: a resumed run gets cfg.minutes more (prior_elapsed is kept
    # only for the learning-rate schedule and the record).
    while step < cfg.steps and time.monotonic() - start < budget_s and not stop.is_set():
        for group in optimizer.param_groups:
            group["lr"] = cfg.lr * _lr_factor(cfg, step, time.monotonic() - start)
        batch = sample_batch(data, cfg, step, accelerator.process_index)
        batch = {k: v.to(accelerator.device) for k, v in batch.items()}
        loss = training_loss(model, batch)
        optimizer.zero_grad(set_to_none=True)
        accelerator.backward(loss)
        if cfg.grad_clip > 0:
            accelerator.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        optimizer.step()
        step += 1
        history["loss"].append(float(loss.detach()))
        history["elapsed_s"].append(round(elapsed(), 2))
        bar.update(1)
        recent = history["loss"][-50:]
        bar.set_postfix(loss=f"{sum(recent) / len(recent):.4f}", lr=f"{optimizer.param_groups[0]['lr']:.2e}")
        if cfg.ckpt_minutes > 0 and time.monotonic() - last_save >= cfg.ckpt_minutes * 60:
            path = checkpoint()
            last_save = time.monotonic()
    bar.close()
    for sig, handler in previous.items():
        signal.signal(sig, handler)
    path = checkpoint()
    recent = history["loss"][-50:]
    summary = {
        "step": step,
        "elapsed_s": round(elapsed(), 1),
        "final_loss_mean50": sum(recent) / len(recent) if recent else None,
        "checkpoint": str(path) if path else None,
    }
    accelerator.print(json.dumps(summary))
    return summary


def _flag_type(field: dataclasses.Field):
    default = field.default
    if isinstance(default, bool):
        return None
    if isinstance(default, tuple):
        return lambda s: tuple(int(v) for v in s.split(","))
    return type(default)


def parse_args(argv: list[str] | None = None) -> TrainConfig:
    """``TrainConfig`` from command-line flags (one per field)."""
    parser = argparse.ArgumentParser(prog="python -m relight.bieron.train", description=__doc__.split("\n\n")[0])
    for f in dataclasses.fields(TrainConfig):
        flag = "--" + f.name.replace("_", "-")
        if isinstance(f.default, bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=f.default)
        else:
            parser.add_argument(flag, type=_flag_type(f), default=f.default, help=f"default: {f.default}")
    return TrainConfig(**vars(parser.parse_args(argv)))


if __name__ == "__main__":
    main(parse_args(sys.argv[1:]))
