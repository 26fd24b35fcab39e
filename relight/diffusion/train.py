"""Train the relighting diffusion model: ``python -m relight.diffusion.train`` or
``relight train diffusion``.

Thin entry point: a typed config and ``main(cfg)``; model logic lives in
``relight.diffusion.model``, the step in ``relight.diffusion.objective``, checkpoints,
the loop, the schedule and the command line in ``training``.

Data order: one group (a material under 8 lights) per step in ``TRAIN_SEEDS`` order, so
step ``t`` trains on groups ``t * groups_per_step ...``; a resumed run continues there with
the torch RNG state of its checkpoint (noise, timesteps and the feature shuffle), so it
equals an uninterrupted run.

Data: ``--domain paper`` (the paper's clean renders, ``RenderedGroups``; every run before
the option) or ``capture`` (``DomainGroups`` with ``CaptureDomain.relighting()``: the
photo as the capture pipeline hands it to the relighter, exposure, white balance, noise,
clipped highlights, 8-bit and JPEG, camera heights, offsets and crops of the plane, and
the unclipped views as targets; issue 16). ``--init-from`` starts a new run from saved
weights (e.g. the shipped model) instead of an initialisation.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import torch
from accelerate import Accelerator
from diffusers.training_utils import EMAModel
from torch.utils.data import DataLoader, Subset

from materials.capture_domain import CaptureDomain
from materials.dataset import GroupConfig, RenderedGroups
from materials.domain_groups import (
    DATA_DOMAINS,
    RELIGHTING_DATA_OPTIONS,
    DomainGroups,
    check_data_options,
    data_options,
    relighting_groups,
)
from relight.diffusion.config import TINY_TRAINING_DEFAULTS
from relight.diffusion.model import RelightDiffusion, make_train_scheduler
from relight.diffusion.objective import diffusion_loss
from training.checkpoint import (
    MODEL_DIR,
    check_resumed_run,
    latest_checkpoint,
    load_checkpoint,
    load_init_from,
    restore_rng_state,
    trainable_parameters,
)
from training.config import config_of, differences, from_dict, model_config, parse, to_dict
from training.loop import Loop, resumed_line
from training.schedule import SCHEDULES, lr_factor

__all__ = ["TrainConfig", "DiffusionModelConfig", "main", "parse_args", "learning_rate", "training_data", "DOMAINS"]

#: ``TrainConfig.domain``'s values.
DOMAINS = DATA_DOMAINS

#: What a new run of the tiny preset builds where ``RelightDiffusion``'s signature keeps the
#: behaviour of old checkpoints: the three tiny-preset switches of
#: ``TINY_TRAINING_DEFAULTS`` (the shipped model's), with the rest of that table
#: (channels, base) left to the flags, whose defaults are the signature's.
NEW_RUN_DEFAULTS = {k: TINY_TRAINING_DEFAULTS[k] for k in ("photo_concat", "residual", "data_scale")}

#: The architecture: ``RelightDiffusion``'s constructor arguments.
DiffusionModelConfig = model_config(
    RelightDiffusion, name="DiffusionModelConfig", defaults=NEW_RUN_DEFAULTS, module=__name__
)

#: The architecture flags from before they moved under ``--model.``; accepted for one release.
DEPRECATED_FLAGS = {
    "--resolution": "model.resolution",
    "--block-out-channels": "model.block_out_channels",
    "--ablation": "model.ablation",
    "--base": "model.base",
    "--preset": "model.preset",
    "--sd21-path": "model.sd21_path",
}


def _new_model(arch: DiffusionModelConfig) -> RelightDiffusion:
    return RelightDiffusion(**dataclasses.asdict(arch))


@dataclass
class TrainConfig:
    """Training run settings (one group = one material under 8 lights).

    Attributes:
        ckpt_dir: checkpoints and the loss curve (relative to the current folder; ``runs/``
            is ignored by git; put long runs outside the repository). A rerun with the
            same folder resumes from its latest checkpoint.
        steps: optimizer steps in total (a resumed run continues up to it).
        minutes: wall-clock budget of this run in minutes (0: none); the run stops after
            the step that spends it and checkpoints.
        groups_per_step: groups (materials, all 8 views are targets) per step.
        lr: AdamW's learning rate.
        lr_schedule: ``constant``, or ``cosine``: constant until ``lr_decay_from``, then a
            cosine to zero at ``steps`` (a function of the step alone, so a resumed run
            continues the same curve).
        lr_decay_from: the step the cosine starts at.
        ema_decay: exponential moving average of the weights (0: off), saved beside the
            model as ``ema/``: at lr 2e-4 and one group a step, checkpoints 5 steps apart
            differed by 0.7 dB held-out PSNR (one-step sampling; 6900 vs 6905 steps of the
            shipped run).
        terminal_fraction: share of targets trained at the last timestep from pure noise,
            as one-step sampling asks the model (``relight.diffusion.objective``); 0:
            uniform timesteps. The shipped weights' stage 2 used 0.5
            (``weights/diffusion/TRAINING.md``).
        seed: seeds the model init and the torch RNG (noise, timesteps, shuffles).
        ckpt_every: checkpoint every this many steps (and at the end).
        keep_checkpoints: checkpoint folders kept (besides the ``keep_every`` snapshots).
        keep_every: also keep the checkpoint of every multiple of this many steps (0:
            none), e.g. for same-budget ablations or choosing a snapshot afterwards.
        threads: torch threads (0: leave torch's default).
        domain: the training data (module docstring): ``paper`` or ``capture``.
        textures: with ``capture``, a folder of real-texture material folders of which the
            ``REAL_DEV_TRAIN`` ones are used (``materials.domain_groups``); none:
            procedural materials only.
        p_texture: with ``capture`` and ``textures``, the probability of a texture item.
        p_mix: with ``capture``, the probability that a procedural item blends two.
        p_paper: with ``capture``, the probability that an item is the paper's clean
            render instead (keeps what the shipped model was trained on in the stream).
        p_crop: with ``capture``, the probability that an item shows a random window of
            the plane (``CaptureDomain.p_crop``); 0 trains on whole planes only, what
            the relighter's default ``large="global"`` mode gives the model.
        init_from: a saved ``RelightDiffusion`` folder (``save_pretrained``, e.g.
            ``weights/diffusion``) whose weights start a new run; its architecture must
            equal ``model``. Ignored when ``ckpt_dir`` has a checkpoint (the run resumes).
        model: the architecture (``RelightDiffusion``'s arguments; ``NEW_RUN_DEFAULTS``).
    """

    ckpt_dir: str = "runs/diffusion-ckpt"
    steps: int = 1000
    minutes: float = 0.0
    groups_per_step: int = 1
    lr: float = 2e-4
    lr_schedule: Literal["constant", "cosine"] = "constant"
    lr_decay_from: int = 0
    ema_decay: float = 0.0
    terminal_fraction: float = 0.0
    seed: int = 0
    ckpt_every: int = 50
    keep_checkpoints: int = 1
    keep_every: int = 0
    threads: int = 0
    domain: Literal["paper", "capture"] = "paper"
    textures: str | None = None
    p_texture: float = 0.25
    p_mix: float = 0.0
    p_paper: float = 0.0
    p_crop: float = CaptureDomain.p_crop
    init_from: str | None = None
    model: DiffusionModelConfig = field(default_factory=DiffusionModelConfig)

    def __post_init__(self) -> None:
        if isinstance(self.model, dict):
            self.model = from_dict(DiffusionModelConfig, self.model)
        if self.lr_schedule not in SCHEDULES:
            raise ValueError(f"lr_schedule must be one of {SCHEDULES}, got {self.lr_schedule!r}")
        if self.lr_schedule == "cosine" and not 0 <= self.lr_decay_from < self.steps:
            raise ValueError(f"lr_decay_from must lie in [0, steps), got {self.lr_decay_from} with steps {self.steps}")
        if not 0 <= self.ema_decay < 1:
            raise ValueError(f"ema_decay must lie in [0, 1), got {self.ema_decay}")
        if not 0 <= self.terminal_fraction <= 1:
            raise ValueError(f"terminal_fraction must lie in [0, 1], got {self.terminal_fraction}")
        check_data_options(**data_options(self))
        for name in ("steps", "groups_per_step", "ckpt_every", "keep_checkpoints"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """The learning rate for the update that takes the model from ``step`` to ``step + 1``."""
    return cfg.lr * lr_factor(cfg.lr_schedule, step, total=cfg.steps, decay_from=cfg.lr_decay_from)


def training_data(cfg: TrainConfig) -> RenderedGroups | DomainGroups:
    """The training groups of ``cfg.domain`` over ``TRAIN_SEEDS``, 8 views at the model's
    resolution (``TrainConfig.domain``; ``materials.domain_groups.relighting_groups``)."""
    config = GroupConfig(size=cfg.model.resolution, views=8, seed=cfg.seed)
    return relighting_groups(config, **data_options(cfg))


def _initial_model(cfg: TrainConfig) -> RelightDiffusion:
    """A new run's model: ``cfg.init_from``'s weights (same architecture) or a fresh one."""
    if cfg.init_from is None:
        return _new_model(cfg.model)
    # sd21_path is where the frozen weights are read from, not the architecture.
    return load_init_from(cfg.init_from, RelightDiffusion, DiffusionModelConfig, cfg.model, ignore=("sd21_path",))


def main(cfg: TrainConfig) -> Path | None:
    """Train (or resume) and return the last checkpoint folder (None on other processes)."""
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    accel = Accelerator(cpu=not torch.cuda.is_available())
    torch.manual_seed(cfg.seed)
    folder = latest_checkpoint(cfg.ckpt_dir)
    if folder is not None:
        check_resumed_run(folder, cfg, RELIGHTING_DATA_OPTIONS)
        model = RelightDiffusion.from_pretrained(folder / MODEL_DIR)
        # sd21_path is where the frozen weights are read from, not the architecture.
        changed = differences(cfg.model, config_of(DiffusionModelConfig, model), ignore=("sd21_path",))
        if changed:
            raise ValueError(
                f"{folder}: checkpoint architecture differs from the requested one (requested, saved): {changed}"
            )
    else:
        model = _initial_model(cfg)
    optimizer = torch.optim.AdamW(trainable_parameters(model), lr=cfg.lr)
    state = None
    if folder is not None:
        state = load_checkpoint(folder, optimizer=optimizer, restore_rng=False)  # the RNG: below
        accel.print(resumed_line(state))
    start = state.step if state else 0
    data = training_data(cfg)
    # Items past the resumed step come next: the loader starts at the step's offset.
    loader = DataLoader(
        Subset(data, range(start * cfg.groups_per_step, len(data))),
        batch_size=cfg.groups_per_step,
        shuffle=False,
        num_workers=0,
    )
    model, optimizer, loader = accel.prepare(model, optimizer, loader)
    ema = None
    if cfg.ema_decay:  # after prepare: the average lives on the model's device
        # It starts from the current weights (a resumed run without one starts it there).
        ema = EMAModel(trainable_parameters(accel.unwrap_model(model)), decay=cfg.ema_decay)
        if state is not None and state.ema is not None:
            ema.load_state_dict(state.ema)
            ema.to(device=accel.device)
            ema.decay = cfg.ema_decay  # the flag wins over the stored value
    scheduler = make_train_scheduler()
    # The loader draws a seed from the torch RNG when its first batch is fetched, in an
    # uninterrupted run before step 0: so fetch it now, then restore the checkpoint's RNG
    # state, and the noise of step N is the same as without the interruption.
    batches = iter(loader)
    first = next(batches, None)
    batches = itertools.chain([first] if first is not None else [], batches)
    if folder is not None:
        restore_rng_state(folder)

    def step_fn(step: int) -> tuple[torch.Tensor, dict]:
        loss = diffusion_loss(model, scheduler, next(batches), terminal_fraction=cfg.terminal_fraction)
        return loss, {"loss": float(loss.detach())}

    loop = Loop(
        accel,
        model,
        optimizer,
        lr=lambda step: learning_rate(cfg, step),
        steps=cfg.steps,
        minutes=cfg.minutes,
        ckpt_dir=cfg.ckpt_dir,
        config=to_dict(cfg),
        ckpt_every=cfg.ckpt_every,
        keep=cfg.keep_checkpoints,
        keep_every=cfg.keep_every,
        ema=ema,
        desc="diffusion",
        ylabel="v-prediction MSE",
        title="relighting diffusion training",
    )
    loop.run(step_fn, start=start, history=state.history if state else [], elapsed_s=state.elapsed_s if state else 0.0)
    return loop.last_checkpoint or latest_checkpoint(cfg.ckpt_dir)


def parse_args(argv: Sequence[str] | None = None, *, prog: str = "python -m relight.diffusion.train") -> TrainConfig:
    """Build a ``TrainConfig`` from ``--field value`` flags (``--model.x`` nested; ``_`` -> ``-``)."""
    return parse(TrainConfig, argv, prog=prog, description=__doc__.split("\n\n")[0], aliases=DEPRECATED_FLAGS)


if __name__ == "__main__":
    main(parse_args())
