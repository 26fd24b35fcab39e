"""Boundary validation shared by every public function of the project (kornia style).

One helper, ``check_shape``, checks that an argument is a tensor of an allowed dtype
whose shape matches a symbolic pattern such as ``"B 3 H W"``; symbolic dims are bound in
a ``dims`` dict passed from call to call, so ``H`` must agree between the photo and the
maps. Checks run once, in the public functions (``kernels``, ``materials``, the
relighters, the estimator, the pipelines), and raise:

- ``TypeError``: not a tensor, or a dtype outside the allowed set;
- ``ValueError``: a shape that does not match, NaN or inf, a mismatched device, a
  position on or below the material plane; every message names the argument, and for
  shapes the expected symbolic shape and the shape given.

Example:
    >>> import torch
    >>> from kernels.checks import ShapeDims, check_shape
    >>> dims = ShapeDims()
    >>> check_shape(torch.zeros(2, 3, 8, 8), "B 3 H W", name="photo", dims=dims)
    {'B': 2, 'H': 8, 'W': 8}
    >>> check_shape(torch.zeros(2, 1, 8, 4), "B 1 H W", name="mask", dims=dims)
    Traceback (most recent call last):
    ...
    ValueError: mask must have shape [B, 1, H, W], got (2, 1, 8, 4): W is 4, but 8 in photo
"""

from __future__ import annotations

from collections.abc import Collection

import torch

__all__ = [
    "check_shape",
    "ShapeDims",
    "check_same",
    "check_finite",
    "check_above_plane",
    "broadcast_positions",
    "FLOAT_DTYPES",
    "FLOATING_DTYPES",
]

#: The dtypes the kernels compute in (and the default of ``check_shape``).
FLOAT_DTYPES: tuple[torch.dtype, ...] = (torch.float32, torch.float64)
#: Every floating-point dtype torch has (half, bfloat16, float8 variants included): for
#: networks that run in whatever precision they were cast to.
FLOATING_DTYPES: frozenset[torch.dtype] = frozenset(
    t for t in (getattr(torch, n) for n in dir(torch)) if isinstance(t, torch.dtype) and t.is_floating_point
)


class ShapeDims(dict):
    """Symbolic dims bound so far (``{"B": 2, "H": 64}``), remembering which argument
    bound each (``sources``), so a mismatch message can say where the other size came
    from. A plain dict works too; its messages then say "bound earlier"."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.sources: dict[str, str] = {}


def _tokens(shape: str) -> list[str]:
    tokens = shape.replace(",", " ").split()
    if sum(t.startswith("*") for t in tokens) > 1:
        raise ValueError(f"shape pattern {shape!r} has more than one variadic (*) token")
    for t in tokens:
        if not (t.isdigit() or t.isidentifier() or t == "*" or (t[:1] == "*" and t[1:].isidentifier())):
            raise ValueError(f"shape pattern {shape!r}: bad token {t!r} (use ints, names, * or *name)")
    return tokens


def _bind(dims: dict, sources: dict, key: str, value, name: str) -> str | None:
    """Bind ``key`` to ``value``, or return why it cannot (None when it agrees)."""
    if key not in dims:
        dims[key] = value
        sources[key] = name
        return None
    if dims[key] == value:
        return None
    where = sources.get(key)
    return f"{key} is {value}, but {dims[key]} {'in ' + where if where else 'bound earlier'}"


def check_shape(
    x,
    shape: str | tuple[str, ...],
    *,
    name: str,
    dims: dict | None = None,
    dtypes: Collection[torch.dtype] | None = FLOAT_DTYPES,
    finite: bool = False,
) -> dict:
    """Check that ``x`` is a tensor of shape ``shape`` (symbolic) and an allowed dtype.

    Args:
        x: the argument to check.
        shape: whitespace- or comma-separated dims: an integer (that exact size), a name
            (``B``, ``H``, ...: any size, bound on first sight in ``dims`` and required
            to agree afterwards), ``*`` (any number of leading or trailing dims) or
            ``*name`` (the same, bound as a tuple: ``"*batch 3 H W"``). A tuple of
            patterns accepts any of them (the first that matches binds its dims):
            ``("3", "K 3", "B K 3")``.
        name: the argument's name, for messages.
        dims: symbolic dims bound so far (updated in place), a ``ShapeDims`` (or a
            plain dict); pass the same one to the checks of arguments that share dims.
            None: a fresh one.
        dtypes: allowed dtypes (default float32 and float64; ``FLOATING_DTYPES`` for any
            floating-point dtype; None for any dtype).
        finite: also reject NaN and inf (``check_finite``).
    Returns:
        ``dims``, with this argument's dims bound (e.g. ``{"B": 2, "H": 64, "W": 64}``).
    Raises:
        TypeError: ``x`` is not a tensor, or its dtype is not allowed.
        ValueError: the shape does not match (the message gives the expected symbolic
            shape, the shape given and the dim that differs), or NaN/inf with ``finite``.
    """
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if dtypes is not None and x.dtype not in dtypes:
        allowed = (
            "a floating-point tensor"
            if dtypes is FLOATING_DTYPES
            else " or ".join(str(d).removeprefix("torch.") for d in dtypes)
        )
        raise TypeError(f"{name} must be {allowed}, got {x.dtype}")
    dims = ShapeDims() if dims is None else dims
    patterns = [_tokens(s) for s in ((shape,) if isinstance(shape, str) else shape)]
    given, sources = tuple(x.shape), getattr(dims, "sources", {})
    reasons: list[str] = []
    for tokens in patterns:
        trial, trial_sources = dict(dims), dict(sources)
        why = _match(given, tokens, trial, trial_sources, name)
        if why is None:
            dims.update(trial)
            sources.update(trial_sources)
            break
        reasons.append(why)
    else:
        shown = [f"[{', '.join(t)}]" for t in patterns]
        expected = shown[0] if len(shown) == 1 else f"{', '.join(shown[:-1])} or {shown[-1]}"
        # With alternatives, the reason of the one of the same rank (if any) is the useful one.
        same_rank = [r for t, r in zip(patterns, reasons) if "*" not in "".join(t) and len(t) == len(given)]
        why = reasons[0] if len(patterns) == 1 else (same_rank[0] if same_rank else f"{len(given)} dims")
        raise ValueError(f"{name} must have shape {expected}, got {given}: {why}")
    if finite:
        check_finite(**{name: x})
    return dims


def _match(given: tuple[int, ...], tokens: list[str], dims: dict, sources: dict, name: str) -> str | None:
    star = next((i for i, t in enumerate(tokens) if t.startswith("*")), None)
    fixed = len(tokens) - (star is not None)
    if star is None and len(given) != fixed:
        return f"{len(given)} dims, expected {fixed}"
    if star is not None and len(given) < fixed:
        return f"{len(given)} dims, expected at least {fixed}"
    if star is None:
        pairs = list(enumerate(tokens))
    else:
        tail = len(tokens) - star - 1
        pairs = list(enumerate(tokens[:star])) + [(len(given) - tail + j, t) for j, t in enumerate(tokens[star + 1 :])]
        key = tokens[star][1:]
        if key:
            why = _bind(dims, sources, key, tuple(given[star : len(given) - tail]), name)
            if why:
                return why
    for i, t in pairs:
        if t.isdigit():
            if given[i] != int(t):
                return f"dim {i} is {given[i]}, expected {t}"
        else:
            why = _bind(dims, sources, t, given[i], name)
            if why:
                return why
    return None


def check_same(ref_name: str, ref: torch.Tensor, *, dtype: bool = True, **others: torch.Tensor) -> None:
    """Check that every tensor in ``others`` has ``ref``'s device (and, with ``dtype``,
    its dtype: a ``TypeError``)."""
    for name, t in others.items():
        if dtype and t.dtype != ref.dtype:
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


def check_above_plane(name: str, pos: torch.Tensor) -> None:
    """Raise ``ValueError`` when a position ``[..., 3]`` lies on or below the material
    plane (z <= 0): the plane is lit and seen from above only (SPEC section 2)."""
    if bool((pos[..., 2] <= 0).any()):
        raise ValueError(f"{name} has a position on or below the material plane (z must be > 0)")


def broadcast_positions(name: str, pos, batch: int, ref: torch.Tensor, num: int | None = None) -> torch.Tensor:
    """Accept positions ``[3]``, ``[K, 3]``, ``[1, K, 3]`` or ``[B, K, 3]``; return
    ``[B, K, 3]`` (an expand, so autograd reduces gradients back to the input's shape).

    ``num``: the K the result must have (positions of one kind broadcast over the
    other's K, e.g. one camera for all lights); None accepts any K.
    """
    check_shape(pos, ("3", "K 3", "B K 3"), name=name)
    check_same("the maps", ref, **{name: pos})
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
