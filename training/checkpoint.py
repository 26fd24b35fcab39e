"""Training checkpoints: atomic, pickle-free, resumable.

Layout of ``ckpt_dir``::

    checkpoint-0000100/              one complete checkpoint (filled in a hidden temporary
        model/                       sibling, then renamed: it exists whole or not at all)
            config.json ...          the model's ``save_pretrained`` (architecture + weights)
        ema/                         optional: ``save_pretrained`` with the averaged weights
        state.safetensors            optimizer (and EMA) tensors, flattened
        state.json                   their non-tensor parts, with a tensor's place marked
        rng.safetensors              torch CPU (and CUDA) generator states
        trainer_state.json           step, history, run config, elapsed seconds,
                                     Python / numpy RNG states
    latest                           the newest complete checkpoint's name (atomic file)
    loss.png                         the loss curve (``training.plot``; atomic file)

``latest`` is replaced only once its checkpoint is complete, so a crash at any point
leaves the previous one usable. Older checkpoints are deleted after that: all but the
newest ``keep`` (counting the new one), sparing every multiple of ``keep_every`` steps
(snapshots, e.g. to compare a run's weights at equal budgets). Nothing is pickled:
tensors go to safetensors, everything else to JSON.

The EMA (optional) is any object with diffusers' ``EMAModel`` interface: ``state_dict()``,
``load_state_dict()``, ``store`` / ``copy_to`` / ``restore`` over the model's trainable
parameters (``trainable_parameters``), the list it was built on.
"""

from __future__ import annotations

import dataclasses
import json
import random
import re
import shutil
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from materials.io.atomic import atomic_file, atomic_folder
from training.config import config_of, differences

__all__ = [
    "MODEL_DIR",
    "EMA_DIR",
    "TrainerState",
    "save_checkpoint",
    "load_checkpoint",
    "latest_checkpoint",
    "read_trainer_state",
    "check_resumed_run",
    "load_init_from",
    "restore_rng_state",
    "checkpoint_step",
    "trainable_parameters",
    "flatten_state",
    "unflatten_state",
]

#: Sub-folders of a checkpoint that ``from_pretrained`` reads.
MODEL_DIR = "model"
EMA_DIR = "ema"
_NAME = "checkpoint-{:07d}"
_NAME_RE = re.compile(r"^checkpoint-(\d{7,})$")
_MARKER = "trainer_state.json"


@dataclass
class TrainerState:
    """What a checkpoint restores besides the weights.

    Attributes:
        folder: the checkpoint folder.
        step: optimizer updates done.
        history: one JSON dict per logged step (``{"step": ..., "loss": ..., ...}``).
        config: the run config the checkpoint was written with (JSON).
        elapsed_s: wall-clock seconds of training up to ``step``, over all resumes.
        ema: the EMA's state dict (for ``ema.load_state_dict``), or None without one.
    """

    folder: Path
    step: int
    history: list[dict] = field(default_factory=list)
    config: dict = field(default_factory=dict)
    elapsed_s: float = 0.0
    ema: dict | None = None


def trainable_parameters(model: torch.nn.Module) -> list[torch.nn.Parameter]:
    """The parameters that train (``requires_grad``), in ``model.parameters()`` order:
    what the optimizer and the EMA are built on."""
    return [p for p in model.parameters() if p.requires_grad]


# --------------------------------------------------------------------------- flattening
def flatten_state(state: Any, prefix: str = "") -> tuple[dict[str, torch.Tensor], Any]:
    """Split a nested state (dicts, lists, tuples, tensors, JSON scalars) into
    ``{dotted.path: tensor}`` and a JSON-able skeleton in which each tensor is replaced by
    ``{"__tensor__": path}``; ``unflatten_state`` inverts it. Raises ``TypeError`` on any
    other object (nothing is pickled)."""
    tensors: dict[str, torch.Tensor] = {}

    def walk(x: Any, path: str) -> Any:
        if isinstance(x, torch.Tensor):
            tensors[path] = x.detach().cpu().contiguous()
            return {"__tensor__": path}
        if isinstance(x, dict):
            return {"__dict__": [[_key(k), walk(v, f"{path}.{k}")] for k, v in x.items()]}
        if isinstance(x, (list, tuple)):
            return {"__list__": [walk(v, f"{path}.{i}") for i, v in enumerate(x)], "tuple": isinstance(x, tuple)}
        if x is None or isinstance(x, (bool, int, float, str)):
            return x
        raise TypeError(f"cannot checkpoint a {type(x).__name__} at {path or 'the root'}")

    return tensors, walk(state, prefix)


def _key(k: Any) -> Any:
    if isinstance(k, bool) or not isinstance(k, (int, str)):
        raise TypeError(f"state dict keys must be int or str, got {k!r}")
    return k


def unflatten_state(tensors: dict[str, torch.Tensor], skeleton: Any) -> Any:
    """Inverse of ``flatten_state`` (int dict keys stay ints, tuples stay tuples)."""
    if isinstance(skeleton, dict):
        if "__tensor__" in skeleton:
            return tensors[skeleton["__tensor__"]]
        if "__dict__" in skeleton:
            return {k: unflatten_state(tensors, v) for k, v in skeleton["__dict__"]}
        if "__list__" in skeleton:
            items = [unflatten_state(tensors, v) for v in skeleton["__list__"]]
            return tuple(items) if skeleton.get("tuple") else items
    return skeleton


# --------------------------------------------------------------------------- RNG
def _rng_state() -> tuple[dict[str, torch.Tensor], dict]:
    tensors = {"torch_cpu": torch.get_rng_state()}
    if torch.cuda.is_available():
        for i, s in enumerate(torch.cuda.get_rng_state_all()):
            tensors[f"torch_cuda_{i}"] = s
    kind, keys, pos, has_gauss, cached = typing.cast(tuple, np.random.get_state())
    py_version, py_state, py_gauss = random.getstate()
    extra = {
        "numpy": [kind, keys.tolist(), int(pos), int(has_gauss), float(cached)],
        "python": [py_version, list(py_state), py_gauss],
    }
    return tensors, extra


def _set_rng_state(tensors: dict[str, torch.Tensor], extra: dict) -> None:
    torch.set_rng_state(tensors["torch_cpu"])
    cuda = [tensors[k] for k in sorted((k for k in tensors if k.startswith("torch_cuda_")), key=lambda k: int(k[11:]))]
    if cuda and torch.cuda.is_available() and len(cuda) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(cuda)
    kind, keys, pos, has_gauss, cached = extra["numpy"]
    np.random.set_state((kind, np.asarray(keys, dtype=np.uint32), pos, has_gauss, cached))
    py_version, py_state, py_gauss = extra["python"]
    random.setstate((py_version, tuple(py_state), py_gauss))


# --------------------------------------------------------------------------- folders
def checkpoint_step(folder: str | Path) -> int | None:
    """The step in a checkpoint folder's name (``checkpoint-0000100`` -> 100), else None."""
    match = _NAME_RE.match(Path(folder).name)
    return int(match.group(1)) if match else None


def latest_checkpoint(ckpt_dir: str | Path) -> Path | None:
    """The newest complete checkpoint folder in ``ckpt_dir`` (``latest``), or None.

    Raises:
        ValueError: ``ckpt_dir`` holds a checkpoint in a layout from before this module
            (the trainers' own, with a pickled ``state.pt`` or a separate optimizer file):
            it cannot be resumed, and starting over in the same folder would mix runs.
    """
    ckpt_dir = Path(ckpt_dir)
    _refuse_old_layouts(ckpt_dir)
    pointer = ckpt_dir / "latest"
    if not pointer.is_file():
        return None
    folder = ckpt_dir / pointer.read_text().strip()
    if not (folder / _MARKER).is_file():
        return None
    if not (folder / "state.safetensors").is_file():
        raise _old_layout(folder)
    return folder


def _old_layout(folder: Path) -> ValueError:
    return ValueError(
        f"{folder}: a checkpoint in an old layout, which cannot be resumed; use a new --ckpt-dir "
        f"(the weights in {folder / MODEL_DIR} still load with from_pretrained, and the estimator "
        f"trainer can start from them with --init-from)"
    )


def _refuse_old_layouts(ckpt_dir: Path) -> None:
    if (ckpt_dir / "latest").is_dir():  # the diffusion trainer's latest/ folder with state.pt
        raise _old_layout(ckpt_dir / "latest")
    if ckpt_dir.is_dir():
        for p in ckpt_dir.glob("step_*"):  # the Bieron trainer's step_NNNNNNN/ folders
            if (p / "state.pt").is_file():
                raise _old_layout(p)


def read_trainer_state(folder: str | Path) -> dict:
    """The JSON trainer state (step, history, config, elapsed_s, rng) of a checkpoint."""
    return json.loads((Path(folder) / _MARKER).read_text())


def check_resumed_run(folder: str | Path, cfg: Any, data_fields: typing.Sequence[str]) -> None:
    """Refuse to resume checkpoint ``folder`` with a run config ``cfg`` (a trainer's
    ``TrainConfig`` dataclass) that would train on other data or silently drop
    ``init_from``: each of ``data_fields`` must equal the saved run's value (a field a
    checkpoint predates counts as the class default, the data every earlier run used).
    Raises ``ValueError`` naming the field and what to do."""
    saved = read_trainer_state(folder)["config"]
    init_from = getattr(cfg, "init_from", None)
    if init_from is not None and saved.get("init_from") != init_from:
        # Resuming would silently drop --init-from (the checkpoint holds other weights).
        raise ValueError(
            f"{folder}: a checkpoint of another run (init_from={saved.get('init_from')!r}) is in ckpt_dir; "
            f"use a fresh --ckpt-dir for --init-from {init_from}"
            + (", or --no-resume" if hasattr(cfg, "resume") else "")
        )
    defaults = {f.name: f.default for f in dataclasses.fields(cfg)}
    for name in data_fields:
        before = saved.get(name, defaults[name])
        if isinstance(before, list):  # a tuple option, read back from JSON
            before = tuple(before)
        if before != getattr(cfg, name):
            raise ValueError(
                f"{folder}: the checkpoint was trained with {name}={before!r}, the run asks for {getattr(cfg, name)!r}; "
                f"resume with the same data, or start a fresh --ckpt-dir with --init-from"
            )


def load_init_from(
    folder: str | Path, model_cls: Any, config_cls: type, requested: Any, *, ignore: typing.Sequence[str] = ()
) -> Any:
    """The model saved in ``folder`` (``model_cls.from_pretrained``), the start of a run's
    ``--init-from``, after checking its architecture (``config_cls``, read back with
    ``training.config.config_of``) equals ``requested`` except for ``ignore``d fields.
    Raises ``FileNotFoundError`` (no ``config.json``) or ``ValueError`` (another
    architecture)."""
    folder = Path(folder)
    if not (folder / "config.json").is_file():
        raise FileNotFoundError(f"init_from: {folder} is not a saved {model_cls.__name__} (no config.json)")
    model = model_cls.from_pretrained(folder)
    changed = differences(requested, config_of(config_cls, model), ignore=ignore)
    if changed:
        raise ValueError(f"init_from: {folder} has another architecture (requested, saved): {changed}")
    return model


def save_checkpoint(
    ckpt_dir: str | Path,
    *,
    step: int,
    model,
    optimizer: torch.optim.Optimizer,
    history: list[dict],
    config: dict,
    elapsed_s: float = 0.0,
    ema=None,
    keep: int = 2,
    keep_every: int = 0,
) -> Path:
    """Write one checkpoint atomically (module docstring) and return its folder.

    Args:
        ckpt_dir: the run's checkpoint folder (created).
        step: optimizer updates done; names the folder.
        model: the unwrapped model (``save_pretrained``).
        optimizer: its ``state_dict()`` is saved (tensors flattened, no pickle).
        history, config: JSON-able; stored in ``trainer_state.json``.
        elapsed_s: training wall clock so far.
        ema: optional EMA (module docstring); its weights go to ``ema/``, its state
            beside the optimizer's.
        keep: checkpoints kept, the new one included (at least 1).
        keep_every: also keep every checkpoint whose step is a multiple of it (0: none).
    """
    if keep < 1:
        raise ValueError(f"keep must be at least 1, got {keep}")
    ckpt_dir = Path(ckpt_dir)
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    name = _NAME.format(step)
    with atomic_folder(ckpt_dir / name, overwrite=True, marker=_MARKER) as tmp:
        model.save_pretrained(tmp / MODEL_DIR)
        if ema is not None:
            params = trainable_parameters(model)
            ema.store(params)
            ema.copy_to(params)
            try:
                model.save_pretrained(tmp / EMA_DIR)
            finally:
                ema.restore(params)
        state = {"optimizer": optimizer.state_dict(), "ema": ema.state_dict() if ema is not None else None}
        tensors, skeleton = flatten_state(state)
        save_file(tensors, str(tmp / "state.safetensors"))
        (tmp / "state.json").write_text(json.dumps(skeleton))
        rng_tensors, rng_extra = _rng_state()
        save_file(rng_tensors, str(tmp / "rng.safetensors"))
        trainer = {"step": step, "elapsed_s": elapsed_s, "history": history, "config": config, "rng": rng_extra}
        (tmp / _MARKER).write_text(json.dumps(trainer))
    with atomic_file(ckpt_dir / "latest") as tmp:
        tmp.write_text(name + "\n")
    _prune(ckpt_dir, step, keep, keep_every)
    return ckpt_dir / name


def _prune(ckpt_dir: Path, step: int, keep: int, keep_every: int) -> None:
    """Delete checkpoints older than ``step`` beyond the newest ``keep - 1``, sparing
    multiples of ``keep_every``. Later steps (left by an abandoned run in the same
    folder) are not this run's to delete."""
    older = sorted(
        (s, p) for p in ckpt_dir.iterdir() if p.is_dir() and (s := checkpoint_step(p)) is not None and s < step
    )
    prunable = [(s, p) for s, p in older if not (keep_every and s % keep_every == 0)]
    for _, p in prunable[: max(0, len(prunable) - (keep - 1))]:
        shutil.rmtree(p, ignore_errors=True)


def restore_rng_state(folder: str | Path) -> None:
    """Set the torch (CPU, CUDA), numpy and Python RNG states saved in a checkpoint.

    ``load_checkpoint`` does it unless told not to; a trainer that consumes random
    numbers between loading and its first step (a ``DataLoader`` draws a seed from the
    torch RNG when its first batch is fetched) calls this after them instead, so that
    the resumed stream continues exactly where the checkpoint left it.
    """
    _set_rng_state(load_file(str(Path(folder) / "rng.safetensors")), read_trainer_state(folder)["rng"])


def load_checkpoint(
    folder: str | Path, *, optimizer: torch.optim.Optimizer | None = None, restore_rng: bool = True
) -> TrainerState:
    """Restore a checkpoint's optimizer state (into ``optimizer``) and RNG states (torch,
    CUDA, numpy, Python); return the rest. The model is rebuilt by the caller with
    ``Model.from_pretrained(folder / MODEL_DIR)``; an EMA is loaded with
    ``ema.load_state_dict(state.ema)`` once it exists."""
    folder = Path(folder)
    saved = unflatten_state(
        load_file(str(folder / "state.safetensors")), json.loads((folder / "state.json").read_text())
    )
    if optimizer is not None:
        optimizer.load_state_dict(saved["optimizer"])
    trainer = read_trainer_state(folder)
    if restore_rng:
        restore_rng_state(folder)
    return TrainerState(
        folder=folder,
        step=int(trainer["step"]),
        history=trainer["history"],
        config=trainer["config"],
        elapsed_s=float(trainer.get("elapsed_s", 0.0)),
        ema=saved.get("ema"),
    )
