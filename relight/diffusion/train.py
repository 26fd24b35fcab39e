"""Train the relighting diffusion model: ``python -m relight.diffusion.train``.

Thin entry point: a typed config and ``main(cfg)``; model logic lives in
``relight.diffusion.model`` and the step in ``relight.diffusion.objective``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from accelerate import Accelerator
from diffusers.training_utils import EMAModel
from torch.utils.data import DataLoader
from tqdm.auto import tqdm

from materials.dataset import TRAIN_SEEDS, GroupConfig, RenderedGroups
from relight.diffusion.config import TINY_TRAINING_DEFAULTS
from relight.diffusion.model import RelightDiffusion, make_train_scheduler
from relight.diffusion.objective import diffusion_loss

__all__ = ["TrainConfig", "main"]


@dataclass
class TrainConfig:
    """Training run settings (one group = one material under 8 lights)."""

    ckpt_dir: str = "/tmp/dgrsise-relight-ckpt"
    steps: int = 1000
    minutes: float = 0.0  # wall-clock budget; 0 = none
    groups_per_step: int = 1
    resolution: int = 64
    block_out_channels: str = "32,64,128"
    lr: float = 2e-4
    # "constant", or "cosine": constant until lr_decay_from, then cosine to zero at `steps`
    # (a function of the step alone, so a resumed run continues the same curve).
    lr_schedule: str = "constant"
    lr_decay_from: int = 0
    # Exponential moving average of the weights (0 = off), saved beside the model as
    # `ema/`: at lr 2e-4 and one group a step, checkpoints 5 steps apart differed by 0.7 dB
    # held-out PSNR (one-step sampling; 6900 vs 6905 steps of the shipped run).
    ema_decay: float = 0.0
    # Share of targets trained at the last timestep from pure noise, as one-step sampling
    # asks the model (relight.diffusion.objective.diffusion_loss); 0 = uniform timesteps.
    # The shipped weights' stage 2 used 0.5 (weights/diffusion/TRAINING.md).
    terminal_fraction: float = 0.0
    seed: int = 0
    ablation: str = "full"
    base: str = "photo"  # tiny preset: residual relative to the photo or its Lambertian relighting
    preset: str = "tiny"
    sd21_path: str = ""  # local diffusers folder of Stable Diffusion 2.1 (preset sd21)
    ckpt_every: int = 50
    keep_every: int = 0  # also keep a copy of the checkpoint every N steps (0 = none), e.g. for same-budget ablations
    threads: int = 0  # torch threads; 0 = leave torch's default

    def __post_init__(self) -> None:
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"lr_schedule must be one of {LR_SCHEDULES}, got {self.lr_schedule!r}")
        if self.lr_schedule == "cosine" and not 0 <= self.lr_decay_from < self.steps:
            raise ValueError(f"lr_decay_from must lie in [0, steps), got {self.lr_decay_from} with steps {self.steps}")
        if not 0 <= self.ema_decay < 1:
            raise ValueError(f"ema_decay must lie in [0, 1), got {self.ema_decay}")
        if not 0 <= self.terminal_fraction <= 1:
            raise ValueError(f"terminal_fraction must lie in [0, 1], got {self.terminal_fraction}")


LR_SCHEDULES = ("constant", "cosine")


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """The learning rate for the update that takes the model from ``step`` to ``step + 1``."""
    if cfg.lr_schedule == "constant" or step < cfg.lr_decay_from:
        return cfg.lr
    t = min(1.0, (step - cfg.lr_decay_from) / max(1, cfg.steps - cfg.lr_decay_from))
    return cfg.lr * 0.5 * (1 + math.cos(math.pi * t))


def _trainable(model: torch.nn.Module) -> list[torch.nn.Parameter]:
    return [p for p in model.parameters() if p.requires_grad]


def _save_model(model, folder: Path, ema: EMAModel | None) -> None:
    """``folder/model`` (the trained weights) and, with EMA, ``folder/ema`` (the averaged ones)."""
    model.save_pretrained(folder / "model")
    if ema is not None:
        params = _trainable(model)
        ema.store(params)
        ema.copy_to(params)
        try:
            model.save_pretrained(folder / "ema")
        finally:
            ema.restore(params)


def _save(ckpt: Path, model, optimizer, step: int, history: list, accel: Accelerator, ema: EMAModel | None) -> None:
    """Atomic checkpoint: write a temporary sibling folder, then swap it in."""
    tmp = ckpt.with_name(ckpt.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    _save_model(accel.unwrap_model(model), tmp, ema)
    state = {"optimizer": optimizer.state_dict(), "step": step, "rng": torch.get_rng_state()}
    if ema is not None:
        state["ema"] = ema.state_dict()
    torch.save(state, tmp / "state.pt")
    (tmp / "history.json").write_text(json.dumps(history))
    old = ckpt.with_name(ckpt.name + ".old")
    if ckpt.exists():
        os.replace(ckpt, old)
    os.replace(tmp, ckpt)
    shutil.rmtree(old, ignore_errors=True)


def _plot(history: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [h[0] for h in history]
    losses = [h[1] for h in history]
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.plot(steps, losses, lw=0.6)
    ax.set_xlabel("step")
    ax.set_ylabel("v-prediction MSE")
    ax.set_yscale("log")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(cfg: TrainConfig) -> Path:
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    accel = Accelerator(cpu=not torch.cuda.is_available())
    torch.manual_seed(cfg.seed)
    ckpt = Path(cfg.ckpt_dir) / "latest"
    ckpt.parent.mkdir(parents=True, exist_ok=True)
    if (ckpt / "model").is_dir():
        model = RelightDiffusion.from_pretrained(ckpt / "model")
    else:
        channels = tuple(int(c) for c in cfg.block_out_channels.split(","))
        # The tiny preset's switches (photo_concat, residual, data_scale) at the values a new
        # run uses; this run's flags (channels, base, ...) override the rest of the table.
        new_run = TINY_TRAINING_DEFAULTS if cfg.preset == "tiny" else {}
        model = RelightDiffusion(
            **{
                **new_run,
                "preset": cfg.preset,
                "sd21_path": cfg.sd21_path or None,
                "resolution": cfg.resolution,
                "ablation": cfg.ablation,
                "block_out_channels": channels,
                "base": cfg.base,
            }
        )
    optimizer = torch.optim.AdamW(_trainable(model), lr=cfg.lr)
    step, history, state = 0, [], {}
    if (ckpt / "state.pt").is_file():
        state = torch.load(ckpt / "state.pt", weights_only=False)
        optimizer.load_state_dict(state["optimizer"])
        step = state["step"]
        torch.set_rng_state(state["rng"])
        history = json.loads((ckpt / "history.json").read_text())
    data = RenderedGroups(TRAIN_SEEDS, GroupConfig(size=cfg.resolution, views=8, seed=cfg.seed))
    # Items past the resumed step come next: the loader starts at the step's offset.
    loader = DataLoader(
        torch.utils.data.Subset(data, range(step * cfg.groups_per_step, len(data))),
        batch_size=cfg.groups_per_step,
        shuffle=False,
        num_workers=0,
    )
    model, optimizer, loader = accel.prepare(model, optimizer, loader)
    ema, trained = None, _trainable(accel.unwrap_model(model))
    if cfg.ema_decay:  # after prepare: the average lives on the model's device
        # It starts from the current weights (a resumed run without one starts it there).
        ema = EMAModel(trained, decay=cfg.ema_decay)
        if "ema" in state:
            ema.load_state_dict(state["ema"])
            ema.to(device=accel.device)
            ema.decay = cfg.ema_decay  # the flag wins over the stored value
    scheduler = make_train_scheduler()
    start = time.time()
    bar = tqdm(total=cfg.steps, initial=step, desc="train relight", disable=not accel.is_local_main_process)
    model.train()
    for batch in loader:
        if step >= cfg.steps or (cfg.minutes and time.time() - start > cfg.minutes * 60):
            break
        loss = diffusion_loss(model, scheduler, batch, terminal_fraction=cfg.terminal_fraction)
        optimizer.zero_grad(set_to_none=True)
        accel.backward(loss)
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(cfg, step)
        optimizer.step()
        if ema is not None:
            ema.step(trained)
        step += 1
        history.append((step, float(loss.detach())))
        bar.update(1)
        bar.set_postfix(loss=f"{history[-1][1]:.4f}", lr=f"{learning_rate(cfg, step - 1):.1e}")
        if step % cfg.ckpt_every == 0 and accel.is_main_process:
            _save(ckpt, model, optimizer, step, history, accel, ema)
            _plot(history, Path(cfg.ckpt_dir) / "loss.png")
        if cfg.keep_every and step % cfg.keep_every == 0 and accel.is_main_process:
            kept = Path(cfg.ckpt_dir) / f"step_{step:06d}"
            shutil.rmtree(kept, ignore_errors=True)
            _save_model(accel.unwrap_model(model), kept, ema)
    if accel.is_main_process:
        _save(ckpt, model, optimizer, step, history, accel, ema)
        _plot(history, Path(cfg.ckpt_dir) / "loss.png")
    bar.close()
    return ckpt


def parse_args(argv: list[str] | None = None) -> TrainConfig:
    """Build a ``TrainConfig`` from ``--field value`` flags (``_`` -> ``-``)."""
    parser = argparse.ArgumentParser(prog="relight train relight", description=__doc__)
    for f in dataclasses.fields(TrainConfig):
        parser.add_argument(f"--{f.name.replace('_', '-')}", type=type(f.default), default=f.default)
    return TrainConfig(**vars(parser.parse_args(argv)))


if __name__ == "__main__":
    main(parse_args())
