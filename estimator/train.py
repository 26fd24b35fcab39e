"""Train the SVBRDF estimator on rendered procedural materials (thin entry point).

    python -m estimator.train --steps 4000 --size 64 --batch-size 8 \
        --ckpt-dir /work/ckpt/estimator --num-threads 1

or ``estimator.train.main(TrainConfig(...))``. Model, loss and checkpoint logic live in
``estimator.model``, ``estimator.losses`` and ``estimator.checkpoint``; this file only
wires them: HF accelerate (single-process CPU, or multi-GPU / multi-node with
``accelerate launch``), the data, the step loop, logging, checkpoints and resume.

Each step draws one view count N uniform in [min_views, max_views] for the whole batch; the views
are view 0 (the flash photo, always) plus N - 1 of the group's other views at random.
Batches, view subsets and loss lights come from generators seeded by (seed, step), so a
resumed run sees exactly the data it would have seen without the interruption.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
import typing
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch.utils.data import DataLoader, Sampler
from tqdm.auto import tqdm

from estimator.checkpoint import latest_checkpoint, load_checkpoint, read_trainer_state, save_checkpoint
from estimator.config import EstimatorConfig
from estimator.losses import MAP_WEIGHT, NORMAL_LOSSES, NORMAL_WEIGHT, RENDER_WEIGHT, estimator_loss
from estimator.model import SVBRDFEstimator
from materials.dataset import TRAIN_SEEDS, GroupConfig, RenderedGroups
from materials.io.atomic import atomic_file, atomic_folder
from materials.types import Material

__all__ = ["TrainConfig", "main", "select_views", "StepBatchSampler", "plot_history", "parse_args"]


@dataclass
class TrainConfig:
    """Training run settings (every field is a ``--flag`` of ``python -m estimator.train``).

    Attributes:
        seed: seeds the model init, batches, view subsets and loss lights.
        steps: optimizer steps in total (a resumed run continues up to it).
        batch_size: materials per step (each seen in N views).
        size: crop side in pixels; must be a multiple of ``model.downsample_factor``.
        source_size: resolution materials are generated at before the scale-and-crop;
            None: ``2 * size``, which keeps the default data's crop-to-material ratio
            (``GroupConfig``: 128 crops of 256 materials) at a lower resolution, and
            generates 1.5x faster than 256 at size 64.
        lr, weight_decay, warmup_steps: AdamW, linear warm-up then cosine decay to
            ``min_lr_ratio * lr`` at ``steps``.
        max_views: the largest N (views of a group; view 0 is the flash photo).
        min_views: the smallest N (1: every count; 8 with ``max_views`` 8: always all
            views, e.g. a phase that trains what only several views reveal).
        map_weight, render_weight, normal_weight: loss weights (``estimator.losses``).
        normal_loss: ``"mse"`` or ``"l1"``, the normal map's term (``estimator.losses``).
        init_from: a saved estimator folder (``save_pretrained``) whose weights start the
            run, e.g. the shipped model for a fine-tuning run; its architecture must equal
            ``model``, or be ``model`` without the shading branch (the branch then starts
            from its initialisation, ``_load_initial_weights``). A resumed run of the same
            fine-tuning continues from its checkpoint; resuming a checkpoint of another run
            is refused. The optimizer and schedule start fresh.
        out_dir: where the final model, loss curve and history are exported.
        ckpt_dir: training checkpoints (keep it outside the repository).
        ckpt_every, log_every: in steps.
        keep_checkpoints: how many checkpoint folders to keep.
        resume: continue from ``ckpt_dir``'s latest checkpoint when there is one.
        num_threads: ``torch.set_num_threads`` (None: leave torch's default).
        progress: show a tqdm bar.
        model: the architecture (``--model.base-channels`` etc.).
    """

    seed: int = 0
    steps: int = 4000
    batch_size: int = 8
    size: int = 64
    source_size: int | None = None
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    min_lr_ratio: float = 0.1
    max_views: int = 8
    min_views: int = 1
    map_weight: float = MAP_WEIGHT
    render_weight: float = RENDER_WEIGHT
    normal_weight: float = NORMAL_WEIGHT
    normal_loss: str = "mse"
    init_from: str | None = None
    out_dir: str = "runs/estimator"
    ckpt_dir: str = "/work/ckpt/estimator"
    ckpt_every: int = 100
    log_every: int = 10
    keep_checkpoints: int = 2
    resume: bool = True
    num_threads: int | None = None
    progress: bool = True
    model: EstimatorConfig = field(default_factory=EstimatorConfig)

    def __post_init__(self) -> None:
        if isinstance(self.model, dict):
            self.model = EstimatorConfig(**self.model)
        for name in ("steps", "batch_size", "max_views", "min_views", "ckpt_every", "log_every", "keep_checkpoints"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.normal_loss not in NORMAL_LOSSES:
            raise ValueError(f"normal_loss must be one of {NORMAL_LOSSES}, got {self.normal_loss!r}")
        if self.min_views > self.max_views:
            raise ValueError(f"min_views ({self.min_views}) must not exceed max_views ({self.max_views})")
        if self.size % self.model.downsample_factor:
            raise ValueError(f"size {self.size} must be a multiple of {self.model.downsample_factor} (model levels)")
        if self.source_size is None:
            self.source_size = 2 * self.size

    def group_config(self) -> GroupConfig:
        return GroupConfig(size=self.size, views=self.max_views, source_size=self.source_size, seed=self.seed)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _step_generator(seed: int, step: int, stream: int) -> torch.Generator:
    return torch.Generator().manual_seed((seed * 1_000_003 + step) * 8 + stream)


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
            g = _step_generator(self.seed, t, stream=0)
            yield torch.randint(0, self.num_items, (self.batch_size,), generator=g).tolist()


def _lr_lambda(cfg: TrainConfig):
    def f(step: int) -> float:
        if step < cfg.warmup_steps:
            return (step + 1) / cfg.warmup_steps
        t = min(1.0, (step - cfg.warmup_steps) / max(1, cfg.steps - cfg.warmup_steps))
        return cfg.min_lr_ratio + (1 - cfg.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * t))

    return f


def plot_history(history: list[dict], path: str | Path, *, smooth: int = 25) -> None:
    """Write a loss-curve PNG (total, map L1, rendering; moving average of ``smooth``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not history:
        return
    steps = torch.tensor([h["step"] for h in history], dtype=torch.float64)
    fig, ax = plt.subplots(figsize=(7, 4))
    for key in ("loss", "map", "render"):
        y = torch.tensor([h[key] for h in history], dtype=torch.float64)
        k = max(1, min(smooth, len(y)))
        ys = torch.nn.functional.avg_pool1d(y[None, None], k, stride=1)[0, 0]
        ax.plot(steps[k - 1 :].numpy(), ys.numpy(), label=f"{key} (avg {k})")
    ax.set_xlabel("step")
    ax.set_ylabel("loss")
    ax.set_yscale("log")
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title("SVBRDF estimator training")
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)


def _load_initial_weights(model: SVBRDFEstimator, cfg: TrainConfig) -> None:
    """Copy the weights of the saved estimator ``cfg.init_from`` into ``model``.

    The saved architecture must equal ``cfg.model``, or be it without the shading branch
    (a checkpoint from before the branch, or one saved with ``shading_channels=0``): then
    every saved weight is copied and the branch keeps its initialisation, whose
    zero-initialised head leaves the model's output equal to the saved model's.
    """
    folder = Path(cfg.init_from)
    if not (folder / "config.json").is_file():
        raise FileNotFoundError(f"init_from: {folder} is not a saved estimator (no config.json)")
    source = SVBRDFEstimator.from_pretrained(folder)
    saved = source.arch
    with_branch = dataclasses.replace(saved, shading_channels=cfg.model.shading_channels)
    grows = saved.shading_channels == 0 and with_branch == cfg.model
    if saved != cfg.model and not grows:
        raise ValueError(f"init_from: {folder} has architecture {saved}, the run asks for {cfg.model}")
    missing, unexpected = model.load_state_dict(source.state_dict(), strict=False)
    if unexpected or not all(k.startswith(("shading.", "shading_head.")) for k in missing):
        raise RuntimeError(f"init_from: {folder}: unexpected weights {unexpected}, missing {missing}")


def main(cfg: TrainConfig) -> Path:
    """Train (or resume) and return the folder of the exported final model."""
    from accelerate import Accelerator
    from accelerate.utils import set_seed

    if cfg.num_threads is not None:
        torch.set_num_threads(cfg.num_threads)
    accelerator = Accelerator()
    set_seed(cfg.seed)
    ckpt_dir, out_dir = Path(cfg.ckpt_dir), Path(cfg.out_dir)

    model = SVBRDFEstimator(**cfg.model.to_dict())
    optimizer = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, _lr_lambda(cfg))

    start, history = 0, []
    folder = latest_checkpoint(ckpt_dir) if cfg.resume else None
    if folder is not None:
        saved_cfg = read_trainer_state(folder)["config"]
        if cfg.init_from is not None and saved_cfg.get("init_from") != cfg.init_from:
            # Resuming would silently drop --init-from (the checkpoint holds other weights).
            raise ValueError(
                f"{folder}: a checkpoint of another run (init_from={saved_cfg.get('init_from')!r}) is in ckpt_dir; "
                f"use a fresh --ckpt-dir for --init-from {cfg.init_from}, or --no-resume"
            )
        saved = EstimatorConfig.from_saved(saved_cfg["model"])
        saved_loss = saved_cfg.get("normal_loss", "l1")  # runs from before the option used L1
        if saved_loss != cfg.normal_loss:
            accelerator.print(
                f"warning: {folder} was trained with --normal-loss {saved_loss}; continuing with {cfg.normal_loss}"
            )
        if saved != cfg.model:
            raise ValueError(f"{folder}: checkpoint architecture {saved} differs from the requested {cfg.model}")
        state = load_checkpoint(folder, model=model, optimizer=optimizer, scheduler=scheduler)
        start, history = state["step"], state["history"]
        accelerator.print(f"resumed from {folder} at step {start}")
    elif cfg.init_from is not None:
        _load_initial_weights(model, cfg)
        accelerator.print(f"started from the weights in {cfg.init_from}")

    dataset = RenderedGroups(TRAIN_SEEDS, cfg.group_config())
    loader = DataLoader(
        dataset, batch_sampler=StepBatchSampler(len(dataset), cfg.batch_size, cfg.seed, start, cfg.steps), num_workers=0
    )
    model, optimizer, loader, scheduler = accelerator.prepare(model, optimizer, loader, scheduler)

    def checkpoint(step: int) -> None:
        accelerator.wait_for_everyone()
        if accelerator.is_main_process:
            save_checkpoint(
                ckpt_dir,
                model=accelerator.unwrap_model(model),
                optimizer=optimizer,
                scheduler=scheduler,
                step=step,
                history=history,
                config=cfg.to_dict(),
                keep=cfg.keep_checkpoints,
            )
            plot_history(history, ckpt_dir / "loss.png")

    model.train()
    bar = tqdm(
        total=cfg.steps,
        initial=start,
        disable=not cfg.progress or not accelerator.is_main_process,
        desc="estimator",
        mininterval=5.0,
    )
    step, tick = start, time.perf_counter()
    for batch in loader:
        views = select_views(
            batch["images"].shape[1], cfg.max_views, _step_generator(cfg.seed, step, stream=1), cfg.min_views
        )
        pred = model(batch["images"][:, views], batch["light_pos"][:, views], batch["camera_pos"][:, views])
        parts = estimator_loss(
            pred,
            Material.from_stacked(batch["maps"]),
            map_weight=cfg.map_weight,
            render_weight=cfg.render_weight,
            normal_weight=cfg.normal_weight,
            normal_loss=cfg.normal_loss,
            generator=_step_generator(cfg.seed, step, stream=2),
        )
        optimizer.zero_grad(set_to_none=True)
        accelerator.backward(parts["loss"])
        optimizer.step()
        scheduler.step()
        step += 1
        record = {k: float(v.detach()) for k, v in parts.items()}
        history.append({"step": step, "views": len(views), **record})
        bar.update(1)
        bar.set_postfix(loss=f"{record['loss']:.4f}", views=len(views))
        if step % cfg.log_every == 0:
            recent = history[-cfg.log_every :]
            elapsed = time.perf_counter() - tick
            tick = time.perf_counter()
            mean = {k: sum(h[k] for h in recent) / len(recent) for k in ("loss", "map", "render")}
            accelerator.print(
                f"step {step} loss {mean['loss']:.4f} map {mean['map']:.4f} render {mean['render']:.4f} "
                f"lr {scheduler.get_last_lr()[0]:.2e} {elapsed / len(recent):.2f} s/step",
                flush=True,
            )
        if step % cfg.ckpt_every == 0 or step == cfg.steps:
            checkpoint(step)
    bar.close()
    if start >= cfg.steps:
        accelerator.print(f"nothing to do: {ckpt_dir} is already at step {start} >= steps {cfg.steps}")

    final = out_dir / "model"
    if accelerator.is_main_process:
        out_dir.mkdir(parents=True, exist_ok=True)
        with atomic_folder(final, overwrite=True, marker="config.json") as tmp:
            accelerator.unwrap_model(model).save_pretrained(tmp, safe_serialization=True)
        with atomic_file(out_dir / "history.json") as tmp:
            tmp.write_text(json.dumps({"config": cfg.to_dict(), "history": history}))
        plot_history(history, out_dir / "loss.png")
    return final


# ---------------------------------------------------------------------- command line
def _add_fields(parser: argparse.ArgumentParser, cls, prefix: str = "") -> None:
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp, name = hints[f.name], prefix + f.name
        flag = "--" + name.replace("_", "-")
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        if dataclasses.is_dataclass(tp):
            _add_fields(parser, tp, prefix=f"{name}.")
            continue
        args = typing.get_args(tp)
        base = next((a for a in args if a is not type(None)), tp) if typing.get_origin(tp) is not tuple else tp
        if base is bool:
            parser.add_argument(flag, dest=name, action=argparse.BooleanOptionalAction, default=default)
        elif typing.get_origin(tp) is tuple:
            parser.add_argument(
                flag,
                dest=name,
                type=lambda s: tuple(int(x) for x in s.split(",")),
                default=default,
                help="comma-separated, e.g. 1,2,4,8",
            )
        else:
            optional = type(None) in args
            parser.add_argument(
                flag,
                dest=name,
                default=default,
                type=(lambda s, b=base: None if s.lower() == "none" else b(s)) if optional else base,
            )


def parse_args(argv: list[str] | None = None) -> TrainConfig:
    """Build a ``TrainConfig`` from command-line flags (one per field; ``--model.x`` nested)."""
    parser = argparse.ArgumentParser(prog="python -m estimator.train", description=__doc__.split("\n\n")[0])
    _add_fields(parser, TrainConfig)
    ns = vars(parser.parse_args(argv))
    model = {k.split(".", 1)[1]: ns.pop(k) for k in list(ns) if k.startswith("model.")}
    return TrainConfig(**ns, model=EstimatorConfig(**model))


if __name__ == "__main__":
    main(parse_args())
