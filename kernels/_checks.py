"""Boundary validation shared by the public kernel functions.

Checks run once, in the public functions, and raise ``TypeError`` (wrong type or dtype)
or ``ValueError`` (shape, device, non-finite values) naming the argument.
"""

from __future__ import annotations

import torch

__all__ = ["check_tensor", "check_same", "check_finite", "broadcast_positions"]

_FLOATS = (torch.float32, torch.float64)


def check_tensor(name: str, t, *, dims: int | None = None, channels: int | None = None) -> torch.Tensor:
    """Check that ``t`` is a float32/float64 tensor with ``dims`` dims and ``channels`` at dim 1."""
    if not isinstance(t, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
    if t.dtype not in _FLOATS:
        raise TypeError(f"{name} must be float32 or float64, got {t.dtype}")
    if dims is not None and t.dim() != dims:
        raise ValueError(f"{name} must have {dims} dims, got shape {tuple(t.shape)}")
    if channels is not None and t.shape[1] != channels:
        raise ValueError(f"{name} must have {channels} channel(s) at dim 1, got shape {tuple(t.shape)}")
    return t


def check_same(ref_name: str, ref: torch.Tensor, **others: torch.Tensor) -> None:
    """Check that every tensor in ``others`` has ``ref``'s dtype and device."""
    for name, t in others.items():
        if t.dtype != ref.dtype:
            raise TypeError(f"{name} is {t.dtype} but {ref_name} is {ref.dtype}; use one dtype")
        if t.device != ref.device:
            raise ValueError(f"{name} is on {t.device} but {ref_name} is on {ref.device}; use one device")


def check_finite(**tensors: torch.Tensor) -> None:
    """Raise ``ValueError`` naming the first argument that holds NaN or inf."""
    for name, t in tensors.items():
        # One reduction first: a NaN or inf anywhere makes the sum non-finite. The
        # elementwise test (a 1-byte mask and a second pass, ~10% of a forward render at
        # B=4, 256 x 256 on one core) only runs when the sum is not finite, which finite
        # values can also cause by overflowing it.
        if bool(torch.isfinite(t.detach().sum())):
            continue
        if not bool(torch.isfinite(t).all()):
            bad = int((~torch.isfinite(t)).sum())
            raise ValueError(f"{name} holds {bad} NaN or inf value(s)")


def broadcast_positions(name: str, pos, batch: int, ref: torch.Tensor, num: int | None = None) -> torch.Tensor:
    """Accept positions ``[3]``, ``[K, 3]``, ``[1, K, 3]`` or ``[B, K, 3]``; return
    ``[B, K, 3]`` (an expand, so autograd reduces gradients back to the input's shape).

    ``num``: the K the result must have (positions of one kind broadcast over the
    other's K, e.g. one camera for all lights); None accepts any K.
    """
    check_tensor(name, pos)
    check_same("the maps", ref, **{name: pos})
    if pos.shape[-1:] != (3,) or pos.dim() > 3:
        raise ValueError(f"{name} must have shape [3], [K, 3] or [B, K, 3], got {tuple(pos.shape)}")
    if pos.dim() == 1:
        pos = pos[None, None]
    elif pos.dim() == 2:
        pos = pos[None]
    if pos.shape[0] not in (1, batch):
        raise ValueError(f"{name} has batch size {pos.shape[0]}, the maps have {batch}")
    k = pos.shape[1] if num is None else num
    if pos.shape[1] not in (1, k):
        raise ValueError(f"{name} has {pos.shape[1]} positions, expected 1 or {k}")
    check_finite(**{name: pos})
    return pos.expand(batch, k, 3)
