"""Training checkpoints: atomic, pickle-free, resumable.

Layout of ``ckpt_dir``::

    checkpoint-000100/               one complete checkpoint (written to a hidden temp
        model/                       folder, then renamed: it exists whole or not at all)
            config.json              ``save_pretrained`` (diffusers): architecture + weights
            diffusion_pytorch_model.safetensors
        optimizer.safetensors        optimizer + LR-scheduler tensors (flattened state dicts)
        optimizer.json               their non-tensor parts (param groups, steps)
        rng.safetensors              torch CPU (and CUDA) generator states
        trainer_state.json           step, loss history, train config, Python/numpy RNG
    latest                           name of the newest complete checkpoint (atomic file)
    loss.png                         loss curve (atomic file)

``latest`` is replaced only after its checkpoint folder is complete, so a crash at any
point leaves the previous checkpoint usable; older checkpoints beyond ``keep`` are deleted
after that. Nothing is pickled: tensors go to safetensors, the rest to JSON.
"""

from __future__ import annotations

import json
import random
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from materials.io.atomic import atomic_file, atomic_folder

__all__ = [
    "save_checkpoint",
    "load_checkpoint",
    "latest_checkpoint",
    "read_trainer_state",
    "flatten_state",
    "unflatten_state",
]

_PREFIX = "checkpoint-"


def flatten_state(state: Any, prefix: str = "") -> tuple[dict[str, torch.Tensor], Any]:
    """Split a nested state dict into ``{dotted.path: tensor}`` and a JSON-able skeleton
    in which each tensor is replaced by ``{"__tensor__": path}``."""
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
    """Inverse of ``flatten_state``."""
    if isinstance(skeleton, dict):
        if "__tensor__" in skeleton:
            return tensors[skeleton["__tensor__"]]
        if "__dict__" in skeleton:
            return {k: unflatten_state(tensors, v) for k, v in skeleton["__dict__"]}
        if "__list__" in skeleton:
            items = [unflatten_state(tensors, v) for v in skeleton["__list__"]]
            return tuple(items) if skeleton.get("tuple") else items
    return skeleton


def _rng_state() -> tuple[dict[str, torch.Tensor], dict]:
    tensors = {"torch_cpu": torch.get_rng_state()}
    if torch.cuda.is_available():
        for i, s in enumerate(torch.cuda.get_rng_state_all()):
            tensors[f"torch_cuda_{i}"] = s
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    py_version, py_state, py_gauss = random.getstate()
    extra = {
        "numpy": [kind, keys.tolist(), int(pos), int(has_gauss), float(cached)],
        "python": [py_version, list(py_state), py_gauss],
    }
    return tensors, extra


def _set_rng_state(tensors: dict[str, torch.Tensor], extra: dict) -> None:
    torch.set_rng_state(tensors["torch_cpu"])
    cuda = [tensors[k] for k in sorted(k for k in tensors if k.startswith("torch_cuda_"))]
    if cuda and torch.cuda.is_available() and len(cuda) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(cuda)
    kind, keys, pos, has_gauss, cached = extra["numpy"]
    np.random.set_state((kind, np.asarray(keys, dtype=np.uint32), pos, has_gauss, cached))
    py_version, py_state, py_gauss = extra["python"]
    random.setstate((py_version, tuple(py_state), py_gauss))


def latest_checkpoint(ckpt_dir: str | Path) -> Path | None:
    """The newest complete checkpoint folder in ``ckpt_dir``, or None."""
    pointer = Path(ckpt_dir) / "latest"
    if not pointer.is_file():
        return None
    folder = Path(ckpt_dir) / pointer.read_text().strip()
    return folder if (folder / "trainer_state.json").is_file() else None


def read_trainer_state(folder: str | Path) -> dict:
    """The JSON trainer state (step, history, config, rng) of a checkpoint folder."""
    return json.loads((Path(folder) / "trainer_state.json").read_text())


def save_checkpoint(
    ckpt_dir: str | Path,
    *,
    model,
    optimizer: torch.optim.Optimizer,
    scheduler: torch.optim.lr_scheduler.LRScheduler | None,
    step: int,
    history: list[dict],
    config: dict,
    keep: int = 2,
) -> Path:
    """Write one checkpoint atomically (module docstring) and return its folder."""
    ckpt_dir = Path(ckpt_dir)
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    name = f"{_PREFIX}{step:07d}"
    with atomic_folder(ckpt_dir / name, overwrite=True, marker="trainer_state.json") as tmp:
        model.save_pretrained(tmp / "model", safe_serialization=True)
        opt = {"optimizer": optimizer.state_dict(), "scheduler": scheduler.state_dict() if scheduler else None}
        tensors, skeleton = flatten_state(opt)
        save_file(tensors, str(tmp / "optimizer.safetensors"))
        (tmp / "optimizer.json").write_text(json.dumps(skeleton))
        rng_tensors, rng_extra = _rng_state()
        save_file(rng_tensors, str(tmp / "rng.safetensors"))
        state = {"step": step, "history": history, "config": config, "rng": rng_extra}
        (tmp / "trainer_state.json").write_text(json.dumps(state))
    with atomic_file(ckpt_dir / "latest") as tmp:
        tmp.write_text(name + "\n")
    old = sorted(p for p in ckpt_dir.glob(f"{_PREFIX}*") if p.is_dir() and p.name != name)
    for p in old[: max(0, len(old) - (keep - 1))]:
        shutil.rmtree(p, ignore_errors=True)
    return ckpt_dir / name


def load_checkpoint(
    folder: str | Path,
    *,
    model,
    optimizer: torch.optim.Optimizer | None = None,
    scheduler: torch.optim.lr_scheduler.LRScheduler | None = None,
    restore_rng: bool = True,
) -> dict:
    """Load weights (strictly), optimizer/scheduler state and RNG states from ``folder``
    into the given objects; return the trainer state (step, history, config)."""
    folder = Path(folder)
    weights = next((folder / "model").glob("*.safetensors"), None)
    if weights is None:
        raise FileNotFoundError(f"{folder / 'model'}: no safetensors weights")
    model.load_state_dict(load_file(str(weights)), strict=True)
    opt = unflatten_state(
        load_file(str(folder / "optimizer.safetensors")), json.loads((folder / "optimizer.json").read_text())
    )
    if optimizer is not None:
        optimizer.load_state_dict(opt["optimizer"])
    if scheduler is not None and opt["scheduler"] is not None:
        scheduler.load_state_dict(opt["scheduler"])
    state = read_trainer_state(folder)
    if restore_rng:
        _set_rng_state(load_file(str(folder / "rng.safetensors")), state["rng"])
    return state
