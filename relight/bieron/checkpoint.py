"""Training checkpoints that survive a kill: one folder per saved step, made complete in a
temporary sibling and renamed into place (``os.replace``), so a folder named
``step_NNNNNNN`` is always whole; resuming picks the newest one.

Layout of ``ckpt_dir/step_NNNNNNN/``:
    ``model/``          ``save_pretrained`` output (config.json + safetensors weights)
    ``state.pt``        optimizer state, step, elapsed seconds, torch RNG state
    ``history.json``    per-step training loss and wall-clock seconds
"""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
from pathlib import Path

import torch

__all__ = ["save_checkpoint", "latest_checkpoint", "load_state", "STEP_DIR"]

#: Name of a checkpoint folder: ``step_`` plus the zero-padded step.
STEP_DIR = "step_{:07d}"
_STEP_RE = re.compile(r"^step_(\d{7})$")


def save_checkpoint(ckpt_dir: Path, model, state: dict, history: dict, keep: int = 2) -> Path:
    """Write ``model``, ``state`` and ``history`` to ``ckpt_dir/step_<state['step']>``
    atomically, then delete all but the newest ``keep`` checkpoint folders."""
    ckpt_dir = Path(ckpt_dir)
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    final = ckpt_dir / STEP_DIR.format(int(state["step"]))
    tmp = ckpt_dir / f".{final.name}.{secrets.token_hex(4)}.tmp"
    try:
        model.save_pretrained(tmp / "model", safe_serialization=True)
        torch.save(state, tmp / "state.pt")
        (tmp / "history.json").write_text(json.dumps(history))
        if final.exists():  # the same step saved twice (resume, then stop at once)
            shutil.rmtree(final)
        os.replace(tmp, final)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    for old in _step_dirs(ckpt_dir)[:-keep]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def _step_dirs(ckpt_dir: Path) -> list[Path]:
    if not Path(ckpt_dir).is_dir():
        return []
    found = [p for p in Path(ckpt_dir).iterdir() if p.is_dir() and _STEP_RE.match(p.name)]
    return sorted(found, key=lambda p: int(_STEP_RE.match(p.name).group(1)))


def latest_checkpoint(ckpt_dir: Path) -> Path | None:
    """The newest complete checkpoint folder under ``ckpt_dir``, or None."""
    dirs = _step_dirs(ckpt_dir)
    return dirs[-1] if dirs else None


def load_state(folder: Path) -> tuple[dict, dict]:
    """``(state, history)`` of a checkpoint folder (the model is loaded with
    ``BieronRelighter.from_pretrained(folder / "model")``)."""
    folder = Path(folder)
    state = torch.load(folder / "state.pt", map_location="cpu", weights_only=True)
    history = json.loads((folder / "history.json").read_text())
    return state, history
