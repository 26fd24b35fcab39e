"""Train the SVBRDF estimator on rendered procedural materials (thin entry point).

    python -m estimator.train --steps 4000 --size 64 --batch-size 8 \
        --ckpt-dir runs/estimator-ckpt --num-threads 1

or ``relight train estimator ...``, or ``estimator.train.main(TrainConfig(...))``. Model
and loss live in ``estimator.model`` and ``estimator.losses``; checkpoints, the step loop,
the schedule and the command line in ``training``. This file only wires them: the data,
the step, resume and ``--init-from``, the export.

The data is ``--domain paper`` (the paper's clean renders, ``RenderedGroups``) or
``capture`` (``DomainGroups``: capture-domain geometry and photometric randomisation,
optionally with real textures). Each step draws one view count N uniform in
[min_views, max_views] for the whole batch; the views are view 0 (the flash photo,
always) plus N - 1 of the group's other views at random. Batches, view subsets and loss
lights come from generators seeded by (seed, step), so a resumed run sees exactly the
data it would have seen without the interruption.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from estimator.config import TRAINING_DEFAULTS
from estimator.losses import MAP_WEIGHT, NORMAL_LOSSES, NORMAL_WEIGHT, RENDER_WEIGHT, estimator_loss
from estimator.model import SVBRDFEstimator
from materials.capture_domain import CaptureDomain
from materials.dataset import TRAIN_SEEDS, GroupConfig, RenderedGroups
from materials.domain_groups import (
    DATA_DOMAINS,
    DATA_OPTIONS,
    DomainGroups,
    check_data_options,
    data_options,
    training_texture_folders,
)
from materials.io.atomic import atomic_file, atomic_folder
from materials.relit_pool import RelitMixedGroups
from materials.types import Material
from training.checkpoint import MODEL_DIR, check_resumed_run, latest_checkpoint, load_checkpoint, read_trainer_state
from training.config import config_of, differences, from_dict, model_config, parse, to_dict
from training.loop import Loop, resumed_line
from training.schedule import warmup_cosine
from training.seeding import step_generator

__all__ = [
    "TrainConfig",
    "EstimatorModelConfig",
    "main",
    "select_views",
    "StepBatchSampler",
    "parse_args",
    "training_data",
    "DOMAINS",
]

#: ``TrainConfig.domain``'s values.
DOMAINS = DATA_DOMAINS

#: The architecture: ``SVBRDFEstimator``'s constructor arguments (its signature is the
#: only copy of their defaults), with what a new run builds (``TRAINING_DEFAULTS``: the
#: shading branch, which the signature leaves out for checkpoints saved before it).
EstimatorModelConfig = model_config(
    SVBRDFEstimator, name="EstimatorModelConfig", defaults=TRAINING_DEFAULTS, module=__name__
)


@dataclass
class TrainConfig:
    """Training run settings (every field is a ``--flag`` of ``python -m estimator.train``).

    Attributes:
        seed: seeds the model init, batches, view subsets and loss lights.
        steps: optimizer steps in total (a resumed run continues up to it).
        minutes: wall-clock budget of this run in minutes (0: none); the run stops after
            the step that spends it, checkpoints and exports.
        batch_size: materials per step (each seen in N views).
        size: crop side in pixels; must be a multiple of 2 ** (levels - 1) of ``model``.
        source_size: resolution materials are generated at before the scale-and-crop;
            none: ``2 * size``, which keeps the default data's crop-to-material ratio
            (``GroupConfig``: 128 crops of 256 materials) at a lower resolution, and
            generates 1.5x faster than 256 at size 64.
        lr: AdamW's peak learning rate.
        weight_decay: AdamW's weight decay.
        warmup_steps: steps of linear warm-up; then a cosine decay to
            ``min_lr_ratio * lr`` at ``steps``.
        min_lr_ratio: the final learning rate as a fraction of ``lr``.
        max_views: the largest N (views of a group; view 0 is the flash photo).
        min_views: the smallest N (1: every count; 8 with ``max_views`` 8: always all
            views, e.g. a phase that trains what only several views reveal).
        domain: the training data. ``paper``: ``RenderedGroups`` (the paper's clean
            renders: camera at height 4-8, no falloff, unclipped linear images; the stream
            of every run before this option). ``capture``: ``DomainGroups`` with
            ``CaptureDomain()`` (camera heights and offsets, flash falloff, exposure and
            white balance, noise, clipped highlights, 8-bit and JPEG, crops of the plane;
            ``materials.capture_domain``). The loss does not depend on the inputs'
            lighting, so only the data changes.
        textures: with ``capture``, a folder holding real-texture material folders
            (``load_texture_folder``), of which the ``REAL_DEV_TRAIN`` ones are used (e.g.
            ``../shared/data/real-dev/materials``; ``REAL_DEV_VALIDATION`` stays held
            out); none: procedural materials only.
        p_texture: with ``capture`` and ``textures``, the probability that an item is a
            crop of a real texture.
        p_mix: with ``capture``, the probability that a procedural item blends two
            procedural materials.
        p_paper: with ``capture``, the probability that an item is rendered in the
            paper's clean setup instead (``DomainGroups``' ``p_paper``): keeps the clean,
            unclipped inputs a capture-only fine-tune forgets.
        camera_height: with ``capture``, ``CaptureDomain.camera_height`` (``LO,HI``, the
            log-uniform range of the capture items' camera height, plane units): a
            fine-tune can weight a geometry, e.g. the MaterialGAN captures' far phone
            (height about 9.76, issue 16), without touching the other randomisation.
        relit_pool: a relit pool file (``materials.relit_pool``,
            ``scripts/make_relit_pool.py``): a share ``p_relit`` of the items are the
            pool's paper-domain groups with views 1.. made by a relighter instead of
            rendered, so the estimator learns what relit views are worth (issue 15, item
            5); the other items come from ``domain``'s stream. The pool's ``size`` and
            ``views`` must equal ``size`` and ``max_views``. With ``model.generated_flag``
            the relit views are marked generated (``SVBRDFEstimator``'s ``generated``).
        p_relit: with ``relit_pool``, the share of relit items.
        map_weight, render_weight, normal_weight: loss weights (``estimator.losses``).
        normal_loss: ``mse`` or ``l1``, the normal map's term (``estimator.losses``).
        init_from: a saved estimator folder (``save_pretrained``) whose weights start the
            run, e.g. the shipped model for a fine-tuning run; its architecture must equal
            ``model``, or be ``model`` without the shading branch (the branch then starts
            from its initialisation). A resumed run of the same fine-tuning continues from
            its checkpoint; resuming a checkpoint of another run is refused. The optimizer
            and schedule start fresh.
        out_dir: where the final model, loss curve and history are exported (relative to
            the current folder).
        ckpt_dir: training checkpoints (relative to the current folder; ``runs/`` is
            ignored by git; put long runs outside the repository).
        ckpt_every: checkpoint every this many steps (and at the end).
        log_every: print the mean losses every this many steps.
        keep_checkpoints: how many checkpoint folders to keep.
        resume: continue from ``ckpt_dir``'s latest checkpoint when there is one.
        num_threads: ``torch.set_num_threads`` (none: leave torch's default).
        progress: show a progress bar.
        model: the architecture (``SVBRDFEstimator``'s arguments).
    """

    seed: int = 0
    steps: int = 4000
    minutes: float = 0.0
    batch_size: int = 8
    size: int = 64
    source_size: int | None = None
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    min_lr_ratio: float = 0.1
    max_views: int = 8
    min_views: int = 1
    domain: Literal["paper", "capture"] = "paper"
    textures: str | None = None
    p_texture: float = 0.25
    p_mix: float = 0.0
    p_paper: float = 0.0
    camera_height: tuple[float, ...] = CaptureDomain.camera_height
    relit_pool: str | None = None
    p_relit: float = 0.5
    map_weight: float = MAP_WEIGHT
    render_weight: float = RENDER_WEIGHT
    normal_weight: float = NORMAL_WEIGHT
    normal_loss: Literal["mse", "l1"] = "mse"
    init_from: str | None = None
    out_dir: str = "runs/estimator"
    ckpt_dir: str = "runs/estimator-ckpt"
    ckpt_every: int = 100
    log_every: int = 10
    keep_checkpoints: int = 2
    resume: bool = True
    num_threads: int | None = None
    progress: bool = True
    model: EstimatorModelConfig = field(default_factory=EstimatorModelConfig)

    def __post_init__(self) -> None:
        if not isinstance(self.model, EstimatorModelConfig):  # a dict (JSON) or another config of the same fields
            data = self.model if isinstance(self.model, dict) else dataclasses.asdict(self.model)
            self.model = from_dict(EstimatorModelConfig, data)
        for name in ("steps", "batch_size", "max_views", "min_views", "ckpt_every", "log_every", "keep_checkpoints"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.normal_loss not in NORMAL_LOSSES:
            raise ValueError(f"normal_loss must be one of {NORMAL_LOSSES}, got {self.normal_loss!r}")
        check_data_options(**data_options(self, (*DATA_OPTIONS, "p_relit")))
        self.camera_height = tuple(float(h) for h in self.camera_height)  # a list when read back from JSON
        if len(self.camera_height) != 2:
            raise ValueError(f"camera_height must be LO,HI, got {self.camera_height}")
        if self.domain == "paper" and self.camera_height != CaptureDomain.camera_height:
            raise ValueError("camera_height needs domain='capture' (the paper's data has its own heights, 4-8)")
        self.capture_domain()  # checks the range
        if self.min_views > self.max_views:
            raise ValueError(f"min_views ({self.min_views}) must not exceed max_views ({self.max_views})")
        factor = 2 ** (len(self.model.channel_mults) - 1)
        if self.size % factor:
            raise ValueError(f"size {self.size} must be a multiple of {factor} (model levels)")
        if self.source_size is None:
            self.source_size = 2 * self.size

    def capture_domain(self) -> CaptureDomain:
        """The capture domain of ``domain='capture'`` items: ``CaptureDomain()`` with this
        run's ``camera_height``."""
        lo, hi = self.camera_height
        return CaptureDomain(camera_height=(lo, hi))

    def group_config(self) -> GroupConfig:
        return GroupConfig(size=self.size, views=self.max_views, source_size=self.source_size, seed=self.seed)

    def to_dict(self) -> dict:
        return to_dict(self)


def training_data(cfg: TrainConfig) -> Dataset:
    """The training groups of ``cfg.domain`` over ``TRAIN_SEEDS`` (``TrainConfig.domain``),
    mixed with a relit pool's items when ``cfg.relit_pool`` is set."""
    base = _domain_data(cfg)
    if cfg.relit_pool is None:
        return base
    data = RelitMixedGroups(cfg.relit_pool, cfg.p_relit, TRAIN_SEEDS, base=base)
    if (data.config.size, data.config.views) != (cfg.size, cfg.max_views):
        raise ValueError(
            f"relit_pool {cfg.relit_pool} holds {data.config.views} views of {data.config.size} px; "
            f"the run asks for {cfg.max_views} of {cfg.size}"
        )
    return data


def _domain_data(cfg: TrainConfig) -> Dataset:
    if cfg.domain == "paper":
        return RenderedGroups(TRAIN_SEEDS, cfg.group_config())
    textures = training_texture_folders(cfg.textures) if cfg.textures is not None else []
    return DomainGroups(
        TRAIN_SEEDS,
        cfg.group_config(),
        cfg.capture_domain(),
        textures=textures,
        p_texture=cfg.p_texture,
        p_mix=cfg.p_mix,
        p_paper=cfg.p_paper,
    )


def select_views(total: int, max_views: int, generator: torch.Generator, min_views: int = 1) -> list[int]:
    """View 0 plus N - 1 others drawn without replacement, N uniform in
    [min(min_views, hi), hi] with hi = min(max_views, total)."""
    hi = min(max_views, total)
    n = int(torch.randint(min(min_views, hi), hi + 1, (1,), generator=generator))
    others = (torch.randperm(total - 1, generator=generator)[: n - 1] + 1).sort().values
    return [0, *others.tolist()]


class StepBatchSampler(Sampler[list[int]]):
    """Batches of dataset indices for steps ``start..steps-1``, batch ``t`` drawn from a
    generator seeded by ``(seed, t)`` (so resuming at step t continues the same stream)."""

    def __init__(self, num_items: int, batch_size: int, seed: int, start: int, steps: int):
        self.num_items, self.batch_size, self.seed = num_items, batch_size, seed
        self.start, self.steps = start, steps

    def __len__(self) -> int:
        return max(0, self.steps - self.start)

    def __iter__(self):
        for t in range(self.start, self.steps):
            g = step_generator(self.seed, t, stream=0)
            yield torch.randint(0, self.num_items, (self.batch_size,), generator=g).tolist()


def _load_initial_weights(model: SVBRDFEstimator, cfg: TrainConfig) -> None:
    """Copy the weights of the saved estimator ``cfg.init_from`` into ``model``.

    The saved architecture must equal ``cfg.model``, or be it without the shading branch
    (a checkpoint from before the branch, or one saved with ``shading_channels=0``) and/or
    without the generated-view flag: then every saved weight is copied and the new parts
    keep their initialisation (the branch's zero-initialised head, the flag's zero
    vectors), which leaves the model's output equal to the saved model's.
    """
    folder = Path(cfg.init_from)
    if not (folder / "config.json").is_file():
        raise FileNotFoundError(f"init_from: {folder} is not a saved estimator (no config.json)")
    source = SVBRDFEstimator.from_pretrained(folder)
    saved = config_of(EstimatorModelConfig, source)
    grown = saved
    if saved.shading_channels == 0:
        grown = dataclasses.replace(grown, shading_channels=cfg.model.shading_channels)
    if not saved.generated_flag:
        grown = dataclasses.replace(grown, generated_flag=cfg.model.generated_flag)
    if grown != cfg.model:
        raise ValueError(f"init_from: {folder} has architecture {saved}, the run asks for {cfg.model}")
    missing, unexpected = model.load_state_dict(source.state_dict(), strict=False)
    if unexpected or not all(k.startswith(("shading.", "shading_head.", "generated_embed.")) for k in missing):
        raise RuntimeError(f"init_from: {folder}: unexpected weights {unexpected}, missing {missing}")


def generated_views(batch: dict, views: list[int]) -> torch.Tensor:
    """``[B, len(views)]`` bool: True for the selected views a relighter made (views 1.. of
    a relit pool item, ``batch["relit"]``); all False for batches without that key."""
    relit = batch.get("relit")
    b = batch["images"].shape[0]
    if relit is None:
        return torch.zeros(b, len(views), dtype=torch.bool)
    later = torch.tensor([v > 0 for v in views])
    return relit.bool().reshape(b, 1) & later.reshape(1, -1)


def _resume_model(folder: Path, cfg: TrainConfig, print_fn) -> SVBRDFEstimator:
    """The model of checkpoint ``folder``, after checking it belongs to this run."""
    check_resumed_run(folder, cfg, (*DATA_OPTIONS, "camera_height", "relit_pool", "p_relit"))
    saved_cfg = read_trainer_state(folder)["config"]
    model = SVBRDFEstimator.from_pretrained(folder / MODEL_DIR)
    changed = differences(cfg.model, config_of(EstimatorModelConfig, model))
    if changed:
        raise ValueError(
            f"{folder}: checkpoint architecture differs from the requested one (requested, saved): {changed}"
        )
    if saved_cfg.get("normal_loss", cfg.normal_loss) != cfg.normal_loss:
        print_fn(
            f"warning: {folder} was trained with --normal-loss {saved_cfg['normal_loss']}; continuing with {cfg.normal_loss}"
        )
    return model


def main(cfg: TrainConfig) -> Path:
    """Train (or resume) and return the folder of the exported final model."""
    from accelerate import Accelerator
    from accelerate.utils import set_seed

    if cfg.num_threads is not None:
        torch.set_num_threads(cfg.num_threads)
    accelerator = Accelerator()
    set_seed(cfg.seed)
    ckpt_dir, out_dir = Path(cfg.ckpt_dir), Path(cfg.out_dir)

    folder = latest_checkpoint(ckpt_dir) if cfg.resume else None
    if folder is not None:
        model = _resume_model(folder, cfg, accelerator.print)
    else:
        model = SVBRDFEstimator(**dataclasses.asdict(cfg.model))
        if cfg.init_from is not None:
            _load_initial_weights(model, cfg)
            accelerator.print(f"started from the weights in {cfg.init_from}")
    optimizer = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    start, history, elapsed = 0, [], 0.0
    if folder is not None:
        state = load_checkpoint(folder, optimizer=optimizer)
        start, history, elapsed = state.step, state.history, state.elapsed_s
        accelerator.print(resumed_line(state))

    dataset = training_data(cfg)
    loader = DataLoader(
        dataset, batch_sampler=StepBatchSampler(len(dataset), cfg.batch_size, cfg.seed, start, cfg.steps), num_workers=0
    )
    model, optimizer, loader = accelerator.prepare(model, optimizer, loader)
    batches = iter(loader)

    def step_fn(step: int) -> tuple[torch.Tensor, dict]:
        batch = next(batches)
        views = select_views(
            batch["images"].shape[1], cfg.max_views, step_generator(cfg.seed, step, stream=1), cfg.min_views
        )
        generated = generated_views(batch, views)
        pred = model(
            batch["images"][:, views], batch["light_pos"][:, views], batch["camera_pos"][:, views], generated=generated
        )
        parts = estimator_loss(
            pred,
            Material.from_stacked(batch["maps"]),
            map_weight=cfg.map_weight,
            render_weight=cfg.render_weight,
            normal_weight=cfg.normal_weight,
            normal_loss=cfg.normal_loss,
            generator=step_generator(cfg.seed, step, stream=2),
        )
        return parts["loss"], {"views": len(views), **{k: float(v.detach()) for k, v in parts.items()}}

    loop = Loop(
        accelerator,
        model,
        optimizer,
        lr=lambda step: cfg.lr * warmup_cosine(step, total=cfg.steps, warmup=cfg.warmup_steps, floor=cfg.min_lr_ratio),
        steps=cfg.steps,
        minutes=cfg.minutes,
        ckpt_dir=ckpt_dir,
        config=cfg.to_dict(),
        ckpt_every=cfg.ckpt_every,
        keep=cfg.keep_checkpoints,
        desc="estimator",
        progress=cfg.progress,
        log_every=cfg.log_every,
        log_keys=("loss", "map", "render"),
        title="SVBRDF estimator training",
    )
    loop.run(step_fn, start=start, history=history, elapsed_s=elapsed)

    final = out_dir / "model"
    if accelerator.is_main_process:
        out_dir.mkdir(parents=True, exist_ok=True)
        with atomic_folder(final, overwrite=True, marker="config.json") as tmp:
            accelerator.unwrap_model(model).save_pretrained(tmp, safe_serialization=True)
        with atomic_file(out_dir / "history.json") as tmp:
            tmp.write_text(json.dumps({"config": cfg.to_dict(), "history": history}))
        loop.plot(history, out_dir / "loss.png")
    return final


def parse_args(argv: Sequence[str] | None = None, *, prog: str = "python -m estimator.train") -> TrainConfig:
    """Build a ``TrainConfig`` from command-line flags (one per field; ``--model.x`` nested)."""
    return parse(TrainConfig, argv, prog=prog, description=__doc__.split("\n\n")[0])


if __name__ == "__main__":
    main(parse_args())
