"""Loss-curve plot: each logged quantity per step (faint) and its running mean, written
atomically as a PNG (a reader never sees half a file).

Uses matplotlib's object API (``Figure``), not pyplot: no global figure registry and no
backend switch, so it is safe to call from a training loop or a test.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

from materials.io.atomic import atomic_file

__all__ = ["plot_loss", "running_mean"]


def running_mean(values: Sequence[float] | np.ndarray, window: int) -> np.ndarray:
    """Mean of each ``window`` consecutive values: ``[len(values) - window + 1]`` float64."""
    x = np.asarray(values, dtype=np.float64)
    csum = np.concatenate([[0.0], np.cumsum(x)])
    return (csum[window:] - csum[:-window]) / window


def plot_loss(
    history: Sequence[Mapping[str, float]],
    path: str | os.PathLike,
    *,
    keys: Sequence[str] = ("loss",),
    smooth: int = 50,
    title: str = "training loss",
    ylabel: str = "loss",
) -> None:
    """Write the curves of ``history`` (one dict per step, with ``"step"`` and ``keys``)
    to the PNG ``path``; a log y axis when every value is positive. An empty history
    writes nothing."""
    rows = [h for h in history if all(k in h for k in keys)]
    if not rows:
        return
    steps = np.array([h["step"] for h in rows], dtype=np.float64)
    fig = Figure(figsize=(6.5, 3.8), dpi=100)
    ax = fig.subplots()
    positive = True
    for i, key in enumerate(keys):
        y = np.array([h[key] for h in rows], dtype=np.float64)
        positive &= bool((y > 0).all())
        color = f"C{i}"
        ax.plot(steps, y, color=color, alpha=0.25, lw=0.7)
        window = max(1, min(smooth, len(y)))
        ax.plot(steps[window - 1 :], running_mean(y, window), color=color, lw=1.6, label=f"{key} (mean of {window})")
    if positive:
        ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png")
