"""Train ``BieronRelighter`` on rendered procedural groups (thin entry point).

    python -m relight.bieron.train --ckpt-dir runs/bieron-ckpt --steps 1000 --size 64

or ``relight train bieron ...``. Data (``materials.domain_groups.relighting_groups``, the
diffusion trainer's too): ``--domain paper`` (default), ``materials.dataset.RenderedGroups``
(one procedural material under 8 lights per group, paper light sampling, SPEC section 3);
``--domain capture``, ``CaptureDomain.relighting()`` (camera heights and offsets, crops,
exposure, white balance, noise, clipped highlights, 8-bit, JPEG; ``--textures``,
``--p-texture``, ``--p-mix``, ``--p-paper`` as for the diffusion trainer), targets the
unclipped views. ``--init-from`` starts from saved weights (e.g. ``weights/bieron``).
Input = view 0 (flash at the camera); targets = ``targets_per_group`` of views 1..7 (all
7 by default; a random subset per group trades lights for more materials per step at
the same cost).

Loss: mean L1 between the network's tone-mapped prediction and
``kernels.tonemap(target)`` (clamp then x^(1/2.2), SPEC section 2): the images the
evaluation compares (PSNR/SSIM/FLIP on tone-mapped [0, 1] images).

Optimiser: AdamW with linear warm-up, then constant or a cosine decay to
``min_lr_ratio * lr`` at ``steps`` (``training.schedule``; a function of the step, so a
resumed run continues the curve).

Checkpoints (``training.checkpoint``): every ``ckpt_every`` steps and at the end (also on
SIGTERM / SIGINT, which end the run after the current step), atomically; a rerun with the
same ``ckpt_dir`` resumes from the newest one. Each batch is drawn from a generator seeded
by (seed, step, process), so a resumed run sees the same data it would have seen without
the interruption.

Several processes (HF accelerate, e.g. ``accelerate launch --multi_gpu``) each draw
their own groups; gradients are averaged by the prepared model.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import torch
from accelerate import Accelerator

import kernels
from materials.capture_domain import CaptureDomain
from materials.dataset import GroupConfig, RenderedGroups
from materials.domain_groups import (
    RELIGHTING_DATA_OPTIONS,
    DomainGroups,
    check_data_options,
    data_options,
    relighting_groups,
)
from relight.bieron.model import BieronRelighter
from training.checkpoint import MODEL_DIR, check_resumed_run, latest_checkpoint, load_checkpoint, load_init_from
from training.config import config_of, differences, from_dict, model_config, parse, to_dict
from training.loop import Loop, resumed_line
from training.schedule import SCHEDULES, lr_factor
from training.seeding import step_generator

__all__ = ["TrainConfig", "BieronModelConfig", "main", "sample_batch", "training_loss", "parse_args"]

#: The architecture: ``BieronRelighter``'s constructor arguments (its signature is the
#: only copy of their defaults).
BieronModelConfig = model_config(BieronRelighter, name="BieronModelConfig", module=__name__)

#: Processes a run may have: each draws its batches from stream ``process`` of
#: ``training.seeding`` (the mixing the shipped run used).
MAX_PROCESSES = 64

#: The flags of the architecture before it moved under ``--model.``; accepted for one release.
DEPRECATED_FLAGS = {
    "--base-channels": "model.base_channels",
    "--channel-mults": "model.channel_mults",
    "--blocks-per-level": "model.blocks_per_level",
    "--norm-groups": "model.norm_groups",
    "--residual": "model.residual",
}


@dataclass
class TrainConfig:
    """Training run settings (every field is a command-line flag, ``_`` -> ``-``).

    Attributes:
        ckpt_dir: checkpoints and the loss curve (relative to the current folder; ``runs/``
            is ignored by git; put long runs outside the repository).
        steps: optimizer steps in total (a resumed run continues up to it); the cosine
            schedule ends at it.
        minutes: wall-clock budget of this run in minutes (0: none); the run stops after
            the step that spends it and checkpoints.
        size: crop side in pixels.
        batch: groups (materials) per step.
        targets_per_group: target views per group, drawn from views 1..7.
        lr: AdamW's peak learning rate.
        weight_decay: AdamW's weight decay.
        warmup_steps: steps of linear warm-up.
        schedule: ``cosine`` (decay to ``min_lr_ratio * lr`` at ``steps``) or ``constant``.
        min_lr_ratio: the cosine's floor, as a fraction of ``lr``.
        grad_clip: clip the gradient norm to it (0: no clipping).
        seed: seeds the model init and the batches.
        threads: torch intra-op threads (the CPU is shared).
        ckpt_every: checkpoint every this many steps (and at the end).
        keep: checkpoint folders kept.
        resume: continue from ``ckpt_dir``'s latest checkpoint when there is one.
        progress: show a progress bar.
        domain: the training data (module docstring): ``paper`` or ``capture``.
        textures: with ``capture``, a folder holding the ``REAL_DEV_TRAIN`` texture
            materials (``materials.domain_groups``); none: procedural materials only.
        p_texture: with ``capture`` and ``textures``, the probability of a texture item.
        p_mix: with ``capture``, the probability that a procedural item blends two.
        p_paper: with ``capture``, the probability of a clean paper-setup item instead.
        p_crop: with ``capture``, the probability of a window of the plane
            (``CaptureDomain.p_crop``; 0: whole planes only).
        init_from: a saved ``BieronRelighter`` folder whose weights start a new run (same
            architecture as ``model``); ignored when ``ckpt_dir`` has a checkpoint.
        model: the architecture (``BieronRelighter``'s arguments; the trainer's default
            ``residual`` is ``lambertian``).
    """

    ckpt_dir: str = "runs/bieron-ckpt"
    steps: int = 100_000
    minutes: float = 0.0
    size: int = 64
    batch: int = 8
    targets_per_group: int = 7
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    schedule: Literal["constant", "cosine"] = "cosine"
    min_lr_ratio: float = 0.05
    grad_clip: float = 1.0
    seed: int = 0
    threads: int = 1
    ckpt_every: int = 100
    keep: int = 2
    resume: bool = True
    progress: bool = True
    domain: Literal["paper", "capture"] = "paper"
    textures: str | None = None
    p_texture: float = 0.25
    p_mix: float = 0.0
    p_paper: float = 0.0
    p_crop: float = CaptureDomain.p_crop
    init_from: str | None = None
    model: BieronModelConfig = field(default_factory=lambda: BieronModelConfig(residual="lambertian"))

    def __post_init__(self) -> None:
        if isinstance(self.model, dict):
            self.model = from_dict(BieronModelConfig, self.model)
        if self.schedule not in SCHEDULES:
            raise ValueError(f"schedule must be one of {SCHEDULES}, got {self.schedule!r}")
        if not 1 <= self.targets_per_group <= 7:
            raise ValueError(f"targets_per_group must be in 1..7 (views 1..7), got {self.targets_per_group}")
        check_data_options(**data_options(self))
        for name in ("batch", "steps", "ckpt_every", "keep"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")


def sample_batch(data: RenderedGroups | DomainGroups, cfg: TrainConfig, step: int, process: int = 0) -> dict:
    """The batch of ``step``: ``photo [B, 3, H, W]``, ``light_pos [B, T, 3]``, ``camera_pos [B, 3]``,
    ``target [B, T, 3, H, W]`` (linear radiance: a capture-domain item's unclipped
    ``clean`` views), deterministic in (seed, step, process)."""
    gen = step_generator(cfg.seed, step, stream=process, streams=MAX_PROCESSES)
    index = torch.randint(0, len(data), (cfg.batch,), generator=gen)
    items = [data[int(i)] for i in index]
    views = torch.stack([torch.randperm(7, generator=gen)[: cfg.targets_per_group] + 1 for _ in items])
    return {
        "photo": torch.stack([it["images"][0] for it in items]),
        "light_pos": torch.stack([it["light_pos"][v] for it, v in zip(items, views)]),
        "camera_pos": torch.stack([it["camera_pos"][0] for it in items]),
        "target": torch.stack([it.get("clean", it["images"])[v] for it, v in zip(items, views)]),
    }


def training_loss(model, batch: dict) -> torch.Tensor:
    """Mean L1 between the prediction and the tone-mapped target (module docstring)."""
    pred = model(batch["photo"], batch["light_pos"], batch["camera_pos"])
    return (pred - kernels.tonemap(batch["target"])).abs().mean()


def main(cfg: TrainConfig) -> dict:
    """Train (or resume) and return a summary dict (step, elapsed_s, final_loss_mean50, checkpoint)."""
    torch.set_num_threads(cfg.threads)
    accelerator = Accelerator(cpu=not torch.cuda.is_available())
    torch.manual_seed(cfg.seed)

    folder = latest_checkpoint(cfg.ckpt_dir) if cfg.resume else None
    if folder is not None:
        check_resumed_run(folder, cfg, RELIGHTING_DATA_OPTIONS)
        model = BieronRelighter.from_pretrained(folder / MODEL_DIR)
        changed = differences(cfg.model, config_of(BieronModelConfig, model))
        if changed:
            raise ValueError(
                f"{folder}: checkpoint architecture differs from the requested one (requested, saved): {changed}"
            )
    elif cfg.init_from is not None:
        model = load_init_from(cfg.init_from, BieronRelighter, BieronModelConfig, cfg.model)
    else:
        model = BieronRelighter(**dataclasses.asdict(cfg.model))
    optimizer = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    start, history, elapsed = 0, [], 0.0
    if folder is not None:
        state = load_checkpoint(folder, optimizer=optimizer)
        start, history, elapsed = state.step, state.history, state.elapsed_s
        accelerator.print(resumed_line(state))
    model, optimizer = accelerator.prepare(model, optimizer)
    config = GroupConfig(size=cfg.size, views=8, seed=cfg.seed)
    data = relighting_groups(config, **data_options(cfg))

    def step_fn(step: int) -> tuple[torch.Tensor, dict]:
        batch = sample_batch(data, cfg, step, accelerator.process_index)
        loss = training_loss(model, {k: v.to(accelerator.device) for k, v in batch.items()})
        return loss, {"loss": float(loss.detach())}

    def lr(step: int) -> float:
        kind = cfg.schedule
        return cfg.lr * lr_factor(kind, step, total=cfg.steps, warmup=cfg.warmup_steps, floor=cfg.min_lr_ratio)

    loop = Loop(
        accelerator,
        model,
        optimizer,
        lr=lr,
        steps=cfg.steps,
        minutes=cfg.minutes,
        grad_clip=cfg.grad_clip,
        ckpt_dir=cfg.ckpt_dir,
        config=to_dict(cfg),
        ckpt_every=cfg.ckpt_every,
        keep=cfg.keep,
        desc="bieron",
        progress=cfg.progress,
        ylabel="L1 on tone-mapped images",
        title="BieronRelighter training loss",
    )
    step = loop.run(step_fn, start=start, history=history, elapsed_s=elapsed)
    recent = [h["loss"] for h in history[-50:]]
    summary = {
        "step": step,
        "elapsed_s": round(history[-1]["elapsed_s"], 1) if history else 0.0,
        "final_loss_mean50": sum(recent) / len(recent) if recent else None,
        "checkpoint": str(loop.last_checkpoint) if loop.last_checkpoint else None,
    }
    accelerator.print(json.dumps(summary))
    return summary


def parse_args(argv: Sequence[str] | None = None, *, prog: str = "python -m relight.bieron.train") -> TrainConfig:
    """``TrainConfig`` from command-line flags (one per field; ``--model.x`` nested)."""
    return parse(TrainConfig, argv, prog=prog, description=__doc__.split("\n\n")[0], aliases=DEPRECATED_FLAGS)


if __name__ == "__main__":
    main(parse_args())
