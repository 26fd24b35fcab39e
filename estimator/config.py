"""A training run's view of the estimator's architecture.

``SVBRDFEstimator``'s ``@register_to_config`` signature is the only copy of the
architecture (fields, defaults, checks). ``EstimatorConfig`` is generated from it: a
frozen dataclass with one field per argument, for the trainer, which nests it in its
``TrainConfig`` (one ``--model.*`` flag per field) and compares a checkpoint's architecture
with the requested one. Its defaults are the model's, except ``TRAINING_DEFAULTS``: what
a new run builds. ``from_saved`` reads a saved config: a field it lacks takes the model's
default, which is what checkpoints saved before the field existed were.
"""

from __future__ import annotations

import dataclasses
import inspect
import typing
from collections.abc import Mapping

from estimator.model import SVBRDFEstimator

__all__ = ["EstimatorConfig", "TRAINING_DEFAULTS", "TINY_TEST_CONFIG"]

#: Arguments of the shipped estimator that differ from ``SVBRDFEstimator``'s defaults:
#: the shading branch (``estimator/DESIGN.md``, "Shading branch"; ``weights/estimator``).
TRAINING_DEFAULTS: dict = {"shading_channels": 16}


def _signature_fields() -> list[tuple[str, type, dataclasses.Field]]:
    hints = typing.get_type_hints(SVBRDFEstimator.__init__)
    params = list(inspect.signature(SVBRDFEstimator.__init__).parameters.values())[1:]  # after self
    return [
        (p.name, hints[p.name], dataclasses.field(default=TRAINING_DEFAULTS.get(p.name, p.default))) for p in params
    ]


def _post_init(self) -> None:
    # Saved configs hold lists (JSON); the dataclass compares and hashes tuples.
    object.__setattr__(self, "channel_mults", tuple(int(m) for m in self.channel_mults))


def _to_dict(self) -> dict:
    """The fields as keyword arguments of ``SVBRDFEstimator``."""
    return dataclasses.asdict(self)


def _downsample_factor(self) -> int:
    """H and W must be multiples of this (``SVBRDFEstimator.downsample_factor``)."""
    return 2 ** (len(self.channel_mults) - 1)


def _from_saved(cls, saved: Mapping) -> EstimatorConfig:
    """From a saved config (a checkpoint's ``config.json``, a model's ``config``, a trainer
    state): an absent field takes ``SVBRDFEstimator``'s default (the architecture of
    checkpoints saved before it existed, e.g. no shading branch), keys that are not
    fields (``_class_name``, ...) are ignored."""
    defaults = {name: p.default for name, p in inspect.signature(SVBRDFEstimator.__init__).parameters.items()}
    names = [f.name for f in dataclasses.fields(cls)]
    return cls(**{name: saved.get(name, defaults[name]) for name in names})


EstimatorConfig = dataclasses.make_dataclass(
    "EstimatorConfig",
    _signature_fields(),
    frozen=True,
    namespace={
        "__module__": __name__,
        "__post_init__": _post_init,
        "__doc__": "Frozen dataclass of ``SVBRDFEstimator``'s arguments (module docstring); "
        "defaults: the model's, with ``TRAINING_DEFAULTS``.",
        "to_dict": _to_dict,
        "downsample_factor": property(_downsample_factor),
        "from_saved": classmethod(_from_saved),
    },
)

#: The tiny architecture used by the fast tests (32 x 32 images, a few thousand params).
TINY_TEST_CONFIG = EstimatorConfig(
    base_channels=8, channel_mults=(1, 2, 4), adapter_width=8, norm_groups=4, shading_channels=4
)
