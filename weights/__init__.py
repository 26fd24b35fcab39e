"""The shipped network weights: one folder per network under one root.

Layout (diffusers' ``save_pretrained``; each folder loads with the network's
``from_pretrained``)::

    weights/
        diffusion/   RelightDiffusion: config.json, diffusion_pytorch_model.safetensors,
                     scheduler_config.json (the sampler, ``RelightPipeline.from_pretrained``)
        bieron/      BieronRelighter: config.json, diffusion_pytorch_model.safetensors
        estimator/   SVBRDFEstimator: config.json, diffusion_pytorch_model.safetensors

each with its ``TRAINING.md`` (command, seed, data, wall clock) and loss curves.

``weights_dir(name)`` is the one place a loader finds them. The root is this package's
folder (installed as package data), or the folder named by the environment variable
``DGRSISE_WEIGHTS`` (same layout), e.g. to try other weights without touching the code.

``StrictLoadingMixin`` makes a diffusers ``from_pretrained`` refuse a partial load; the
three networks use it. This package imports nothing of the project (nor torch), so every
layer may use it.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

__all__ = ["NAMES", "ENV_VAR", "weights_root", "weights_dir", "check_loading_info", "StrictLoadingMixin"]

#: The shipped networks, one folder each.
NAMES = ("diffusion", "bieron", "estimator")
#: Environment variable that replaces the root (a folder with the same layout).
ENV_VAR = "DGRSISE_WEIGHTS"
#: Every shipped folder has its architecture here (diffusers' ``ConfigMixin`` file).
_CONFIG = "config.json"


def weights_root() -> Path:
    """The folder holding one subfolder per network: ``$DGRSISE_WEIGHTS`` if set, else
    this package's folder."""
    override = os.environ.get(ENV_VAR)
    return Path(override).expanduser() if override else Path(__file__).resolve().parent


def weights_dir(name: str) -> Path:
    """The folder of the shipped network ``name`` (one of ``NAMES``).

    Raises:
        ValueError: an unknown name.
        FileNotFoundError: the folder or its ``config.json`` is missing (the message names
            the path and, if set, the environment override).

    Example:
        >>> weights_dir("estimator").name
        'estimator'
    """
    if name not in NAMES:
        raise ValueError(f"unknown weights {name!r}; known: {', '.join(NAMES)}")
    folder = weights_root() / name
    if not (folder / _CONFIG).is_file():
        source = f" (from ${ENV_VAR})" if os.environ.get(ENV_VAR) else ""
        raise FileNotFoundError(f"shipped {name} weights: {folder / _CONFIG}{source} does not exist")
    return folder


def check_loading_info(
    info: Mapping[str, Sequence],
    source: str | os.PathLike,
    model_name: str,
    *,
    may_be_missing: Callable[[str], bool] | None = None,
) -> None:
    """Refuse a partial load: diffusers' ``from_pretrained`` only logs a warning for
    checkpoint keys the model does not have, and leaves model weights the checkpoint does
    not have uninitialised (on the meta device), so a wrong file would load "fine".

    Args:
        info: the ``loading_info`` dict of ``from_pretrained(..., output_loading_info=True)``
            (``missing_keys``, ``unexpected_keys``, ``mismatched_keys``, ``error_msgs``).
        source: the folder loaded, for the message.
        model_name: the class loaded, for the message.
        may_be_missing: keys the model fills itself (e.g. frozen weights read from
            elsewhere in ``__init__``); None: every key must come from the checkpoint.
    Raises:
        ValueError: naming up to five keys of each kind.
    """
    missing = [k for k in info.get("missing_keys", []) if may_be_missing is None or not may_be_missing(k)]
    problems = {
        "missing": sorted(missing),
        "unexpected": sorted(info.get("unexpected_keys", [])),
        "mismatched": sorted(str(m[0]) for m in info.get("mismatched_keys", [])),
    }
    problems = {kind: keys for kind, keys in problems.items() if keys}
    if problems:
        detail = "; ".join(f"{len(keys)} {kind} keys, e.g. {keys[:5]}" for kind, keys in problems.items())
        raise ValueError(f"{source}: checkpoint does not match {model_name}: {detail}")


class StrictLoadingMixin:
    """Put before ``ModelMixin`` in a network's bases: its ``from_pretrained`` is diffusers'
    own, followed by ``check_loading_info`` (a missing, unexpected or mismatched key is a
    ``ValueError``). ``output_loading_info=True`` still returns ``(model, info)``.

    A subclass whose ``__init__`` fills some weights itself overrides
    ``_may_be_missing(key, config)``.
    """

    @classmethod
    def _may_be_missing(cls, key: str, config: Mapping) -> bool:
        return False

    @classmethod
    def from_pretrained(cls, pretrained_model_name_or_path, **kwargs):
        want_info = kwargs.pop("output_loading_info", False)
        # The mixin comes before ModelMixin in the subclass's bases, which provides it.
        model, info = super().from_pretrained(  # type: ignore[misc]
            pretrained_model_name_or_path, output_loading_info=True, **kwargs
        )
        check_loading_info(
            info,
            pretrained_model_name_or_path,
            cls.__name__,
            may_be_missing=lambda key: cls._may_be_missing(key, model.config),
        )
        return (model, info) if want_info else model
