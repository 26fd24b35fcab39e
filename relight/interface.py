"""The common relighting interface: every relighting model and baseline is a ``Relighter``.

One call relights B flash photos to K target lights each::

    relit = relighter.relight(photo, light_pos, camera_pos)   # [B, K, 3, H, W]

- ``photo``: ``[B, 3, H, W]`` linear radiance (not tone-mapped), lit by a point light at
  the camera (the phone flash; SPEC section 1), float32 or float64, finite, >= 0.
- ``light_pos``: ``[B, K, 3]`` target point-light positions, scene units of the
  ``dgrsise`` preset (plane of side 4 at z = 0; SPEC section 2), above the plane.
- ``camera_pos``: ``[B, 3]`` camera positions (also the input light: the flash), above
  the plane; the camera does not move.
- returns ``[B, K, 3, H, W]`` linear radiance, same dtype and device as ``photo``.
- ``generator``: a ``torch.Generator`` for stochastic relighters (diffusion); the
  deterministic ones ignore it.

``Relighter.relight`` validates once at this boundary (``kernels.checks``: ``ValueError`` /
``TypeError`` naming the argument) and then calls the subclass's ``_relight`` with valid
inputs, positions cast to the photo's dtype.

Registry: ``get_relighter(name, checkpoint=None)`` builds a relighter by name;
``register_relighter(name, factory)`` adds one, ``relighter_names()`` lists them. A name
not registered yet is looked up by importing ``relight.<name>``, which registers itself
on import (so the diffusion model, ``relight.diffusion``, plugs in as ``"diffusion"``
without this module knowing it). Built in:

- ``"input"``: the photo unchanged for every target (the trivial baseline).
- ``"lambertian"``: the analytic baseline (``LambertianRelighter``).
- ``"bieron"``: ``relight.bieron.BieronRelighter`` behind ``NetworkRelighter``; with no
  checkpoint, the shipped weights, ``weights.weights_dir("bieron")``.
"""

from __future__ import annotations

import importlib
import os
from abc import ABC, abstractmethod
from collections.abc import Callable
from pathlib import Path

import torch

import kernels
from kernels.checks import check_above_plane, check_finite, check_same, check_shape
from kernels.presets import RenderPreset, get_preset
from relight.detail import detail_relight
from relight.shading import lambertian_relight
from weights import weights_dir, weights_root

__all__ = [
    "Relighter",
    "InputRelighter",
    "LambertianRelighter",
    "NetworkRelighter",
    "check_relight_inputs",
    "get_relighter",
    "register_relighter",
    "relighter_names",
    "SHIPPED_WEIGHTS",
]

#: Deprecated (kept for one release): the shipped weights' root at import time. Loaders
#: resolve ``weights.weights_dir(name)`` at call time instead.
SHIPPED_WEIGHTS = weights_root()

#: Side of the whole planes the shipped Bieron-style weights were trained on
#: (``weights/bieron/TRAINING.md``: ``GroupConfig`` size 64).
BIERON_NATIVE_SIZE = 64


def check_relight_inputs(photo, light_pos, camera_pos) -> tuple[int, int, int, int]:
    """Validate a ``relight`` call (module docstring); return (B, K, H, W).

    Raises:
        TypeError: a non-tensor or a dtype other than float32/float64.
        ValueError: a wrong shape (the message gives the expected symbolic shape), NaN or
            inf, negative radiance, a light or camera on or below the plane, or
            mismatched devices; naming the argument.
    """
    dims = check_shape(photo, "B 3 H W", name="photo")
    if photo.numel() == 0:
        raise ValueError(f"photo must be non-empty, got shape {tuple(photo.shape)}")
    check_finite(photo=photo)
    if bool((photo < 0).any()):
        raise ValueError("photo holds negative values; expected linear radiance >= 0")
    check_shape(light_pos, "B K 3", name="light_pos", dims=dims)
    if dims["K"] == 0:
        raise ValueError("light_pos must hold at least one target light (K >= 1)")
    check_shape(camera_pos, "B 3", name="camera_pos", dims=dims)
    check_same("photo", photo, dtype=False, light_pos=light_pos, camera_pos=camera_pos)
    check_finite(light_pos=light_pos, camera_pos=camera_pos)
    check_above_plane("light_pos", light_pos)
    check_above_plane("camera_pos", camera_pos)
    return dims["B"], dims["K"], dims["H"], dims["W"]


class Relighter(ABC):
    """A relighting method: flash photo -> the same material under K point lights.

    Subclasses implement ``_relight`` (inputs already validated, see the module
    docstring); callers use ``relight``.
    """

    #: Registry name (for tables and file names).
    name: str = "relighter"

    def relight(
        self,
        photo: torch.Tensor,
        light_pos: torch.Tensor,
        camera_pos: torch.Tensor,
        *,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """Relight ``photo [B, 3, H, W]`` (linear, flash at ``camera_pos [B, 3]``) to the
        point lights ``light_pos [B, K, 3]``: ``[B, K, 3, H, W]`` linear radiance, the
        photo's dtype and device (module docstring)."""
        b, k, h, w = check_relight_inputs(photo, light_pos, camera_pos)
        out = self._relight(photo, light_pos.to(photo.dtype), camera_pos.to(photo.dtype), generator=generator)
        if tuple(out.shape) != (b, k, 3, h, w):
            raise RuntimeError(f"{type(self).__name__} returned {tuple(out.shape)}, expected {(b, k, 3, h, w)}")
        return out

    @abstractmethod
    def _relight(self, photo, light_pos, camera_pos, *, generator=None) -> torch.Tensor: ...


class InputRelighter(Relighter):
    """Baseline: the input photo, unchanged, for every target light."""

    name = "input"

    def _relight(self, photo, light_pos, camera_pos, *, generator=None):
        return photo[:, None].expand(-1, light_pos.shape[1], -1, -1, -1).clone()


class LambertianRelighter(Relighter):
    """Analytic baseline: treat the photo as Lambertian on a flat plane and re-shade it
    (``relight.shading.lambertian_relight``: relit = photo * shade(light) / shade(flash),
    exact for a flat diffuse material; any other keeps its flash highlight).

    Args:
        preset: scene conventions (plane size, falloff) of the positions.
    """

    name = "lambertian"

    def __init__(self, preset: str | RenderPreset = "dgrsise"):
        self.preset = get_preset(preset)

    def _relight(self, photo, light_pos, camera_pos, *, generator=None):
        return lambertian_relight(photo, light_pos, camera_pos, self.preset)


class NetworkRelighter(Relighter):
    """A trained deterministic network (``BieronRelighter``) behind the interface:
    eval mode, no gradients, the photo padded by edge replication to the network's size
    multiple and cropped back, the tone-mapped prediction clamped to [0, 1] and
    inverse-tone-mapped to linear radiance (so the output is capped at 1).

    A photo larger than ``native_size`` (the side of the planes it was trained on): with
    ``large="whole"`` (default) the network runs fully convolutionally on it; with
    ``"global"`` it relights the whole plane area-averaged to ``native_size`` and the
    photo's detail comes from the Lambertian re-shading at full size (``relight.detail``;
    at 256 px on 8 held-out materials 30.5 dB against 27.9 whole,
    ``results/relight_detail/``). The default stays ``"whole"``: that is the network as
    Bieron et al. run it, and the row the tables have compared since 2026-12-02.
    """

    name = "bieron"
    #: ``large`` values this relighter accepts (``relight.detail.LARGE_MODES``).
    large_modes = ("whole", "global")

    def __init__(self, model, *, large: str = "whole", native_size: int = BIERON_NATIVE_SIZE):
        if large not in self.large_modes:
            raise ValueError(f"large must be one of {self.large_modes}, got {large!r}")
        self.model = model.eval()
        self.large = large
        self.native_size = native_size

    def _relight(self, photo, light_pos, camera_pos, *, generator=None):
        if self.large == "global" and photo.shape[-1] > self.native_size:
            preset = get_preset("dgrsise").with_overrides(plane_size=float(self.model.config.plane_size))
            return detail_relight(self._network, photo, light_pos, camera_pos, size=self.native_size, preset=preset)
        return self._network(photo, light_pos, camera_pos)

    def _network(self, photo, light_pos, camera_pos):
        m = self.model.size_multiple
        h, w = photo.shape[-2:]
        ph, pw = (-h) % m, (-w) % m
        dtype = next(self.model.parameters()).dtype
        device = next(self.model.parameters()).device
        x = photo.to(device, dtype)
        if ph or pw:
            # Replicated borders keep the pixel grid of the unpadded photo at the same
            # plane positions only approximately; sizes that are multiples avoid it.
            x = torch.nn.functional.pad(x, (0, pw, 0, ph), mode="replicate")
        with torch.no_grad():
            y = self.model(x, light_pos.to(device, dtype), camera_pos.to(device, dtype))
        y = y[..., :h, :w]
        return kernels.inverse_tonemap(y.clamp(0, 1)).to(photo.device, photo.dtype)


def _load_bieron(checkpoint: str | os.PathLike | None) -> Relighter:
    from relight.bieron.model import BieronRelighter

    folder = Path(checkpoint) if checkpoint is not None else weights_dir("bieron")
    if not (folder / "config.json").is_file():
        # A training checkpoint folder (step_NNNNNNN) holds the model under model/.
        if (folder / "model" / "config.json").is_file():
            folder = folder / "model"
        else:
            raise FileNotFoundError(f"{folder}: no BieronRelighter checkpoint (config.json) there")
    return NetworkRelighter(BieronRelighter.from_pretrained(folder))


def _no_checkpoint(name: str, cls: type[Relighter]) -> Callable[[str | None], Relighter]:
    def factory(checkpoint=None) -> Relighter:
        if checkpoint is not None:
            raise ValueError(f"relighter {name!r} takes no checkpoint, got {checkpoint!r}")
        return cls()

    return factory


_REGISTRY: dict[str, Callable[[str | os.PathLike | None], Relighter]] = {
    "input": _no_checkpoint("input", InputRelighter),
    "lambertian": _no_checkpoint("lambertian", LambertianRelighter),
    "bieron": _load_bieron,
}


def register_relighter(name: str, factory: Callable[[str | os.PathLike | None], Relighter]) -> None:
    """Add (or replace) a relighter: ``factory(checkpoint_or_None) -> Relighter``."""
    if not name or not isinstance(name, str):
        raise ValueError(f"relighter name must be a non-empty string, got {name!r}")
    _REGISTRY[name] = factory


def relighter_names(*, discover: bool = False) -> list[str]:
    """Names ``get_relighter`` accepts, in registration order. With ``discover``, first
    import every subpackage of ``relight`` so plugins that register on import appear; a
    subpackage that fails to import is skipped with a warning."""
    if discover:
        import pkgutil
        import warnings

        import relight

        for info in pkgutil.iter_modules(relight.__path__):
            if info.ispkg:
                try:
                    importlib.import_module(f"relight.{info.name}")
                except Exception as exc:  # a broken plugin must not hide the others
                    warnings.warn(f"relight.{info.name} failed to import: {exc}", stacklevel=2)
    return list(_REGISTRY)


def get_relighter(name: str, checkpoint: str | os.PathLike | None = None) -> Relighter:
    """Build the relighter ``name`` (``relighter_names()``), from ``checkpoint`` if it
    takes one (None: its shipped weights).

    Raises:
        ValueError: unknown name. FileNotFoundError: no checkpoint where one is needed.
    """
    if name not in _REGISTRY and isinstance(name, str) and name.isidentifier():
        try:
            importlib.import_module(f"relight.{name}")  # a plugin registers itself on import
        except ModuleNotFoundError as exc:
            if exc.name != f"relight.{name}":
                raise
    if name not in _REGISTRY:
        raise ValueError(f"unknown relighter {name!r}; known: {', '.join(_REGISTRY)}")
    relighter = _REGISTRY[name](checkpoint)
    relighter.name = name
    return relighter
