"""The one data model for materials and captures, used by every part of the project.

Layouts (SPEC section 2; all tensors are float32 unless stated):

- ``Material``: SVBRDF maps, linear values, channels first, with any leading batch
  dims ``[..., C, H, W]`` (one material ``[C, H, W]``, a batch ``[B, C, H, W]``):
  diffuse ``[..., 3, H, W]`` linear RGB albedo in [0, 1]; normal ``[..., 3, H, W]`` unit
  tangent-space vectors (OpenGL, +x right, +y up, +z out of the plane); roughness
  ``[..., 1, H, W]`` in [0, 1] (alpha = roughness^2); specular ``[..., 3, H, W]``
  linear RGB F0 in [0, 1].
- ``Capture``: V photos of one material, ``images [V, 3, H, W]`` linear radiance
  (not tone-mapped), with per-image ``light_pos [V, 3]`` and ``camera_pos [V, 3]`` in
  scene units of ``preset`` (possibly overridden by ``plane_size`` / ``intensity``).
  Multi-view *batches* stack captures as ``[B, V, C, H, W]``.

Decoding and encoding (sRGB, (n+1)/2 normals, tone mapping) happen at the file
boundary only (``materials.io``), never here.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import torch

from kernels.checks import ShapeDims, check_above_plane, check_finite, check_shape

__all__ = ["Material", "Capture", "MAP_CHANNELS", "MapError"]

#: Channels of each map, in the canonical order used for stacking ([D, N, R, S] = 10).
MAP_CHANNELS: dict[str, int] = {"diffuse": 3, "normal": 3, "roughness": 1, "specular": 3}


class MapError(ValueError):
    """A material or capture holds maps of the wrong shape, range or values."""


@dataclass(frozen=True)
class Material:
    """SVBRDF maps of one material or a batch of them (shapes in the module docstring)."""

    diffuse: torch.Tensor
    normal: torch.Tensor
    roughness: torch.Tensor
    specular: torch.Tensor

    def __post_init__(self) -> None:
        ref = self.diffuse
        dims = ShapeDims()  # batch dims and H, W must agree across the maps
        for name, channels in MAP_CHANNELS.items():
            t = getattr(self, name)
            try:  # a non-tensor stays a TypeError; a shape error is a MapError
                check_shape(t, f"*batch {channels} H W", name=f"Material.{name}", dims=dims, dtypes=None)
            except ValueError as exc:
                raise MapError(str(exc)) from None
            if t.device != ref.device or t.dtype != ref.dtype:
                raise MapError(f"Material.{name} is {t.dtype} on {t.device}; diffuse is {ref.dtype} on {ref.device}")

    # ------------------------------------------------------------------ properties
    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the maps."""
        return tuple(self.diffuse.shape[-2:])  # type: ignore[return-value]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(self.diffuse.shape[:-3])

    @property
    def device(self) -> torch.device:
        return self.diffuse.device

    @property
    def dtype(self) -> torch.dtype:
        return self.diffuse.dtype

    # ------------------------------------------------------------------ conversions
    def maps(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def to(self, *args, **kwargs) -> Material:
        return Material(**{k: v.to(*args, **kwargs) for k, v in self.maps().items()})

    def map_tensors(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(diffuse, normal, roughness, specular), the argument order of ``kernels.render``."""
        return self.diffuse, self.normal, self.roughness, self.specular

    def stacked(self) -> torch.Tensor:
        """All maps concatenated on the channel dim: ``[..., 10, H, W]`` (D, N, R, S)."""
        return torch.cat(list(self.map_tensors()), dim=-3)

    @staticmethod
    def from_stacked(x: torch.Tensor) -> Material:
        """Inverse of :meth:`stacked`."""
        if x.dim() < 3 or x.shape[-3] != 10:
            raise MapError(f"stacked maps must have shape [..., 10, H, W], got {tuple(x.shape)}")
        d, n, r, s = torch.split(x, [3, 3, 1, 3], dim=-3)
        return Material(d, n, r, s)

    @staticmethod
    def stack(materials: list[Material]) -> Material:
        """Stack unbatched materials ``[C, H, W]`` into one batch ``[B, C, H, W]``."""
        if not materials:
            raise ValueError("cannot stack an empty list of materials")
        return Material(**{k: torch.stack([getattr(m, k) for m in materials]) for k in MAP_CHANNELS})

    def __getitem__(self, index) -> Material:
        """Index the batch dims (e.g. ``batch[0]`` is one material)."""
        if not self.batch_shape:
            raise IndexError("an unbatched Material cannot be indexed")
        return Material(**{k: v[index] for k, v in self.maps().items()})

    def crop(self, top: int, left: int, height: int, width: int) -> Material:
        return Material(**{k: v[..., top : top + height, left : left + width] for k, v in self.maps().items()})

    # ------------------------------------------------------------------ checks
    def validate(self, *, source: str = "material") -> Material:
        """Check values (finite, ranges, unit normals); raise ``MapError`` naming the map.

        Ranges allow a small slack (``RANGE_SLACK``) for 8-bit and half-float rounding.
        """
        for name, t in self.maps().items():
            if not torch.isfinite(t).all():
                bad = int((~torch.isfinite(t)).sum())
                raise MapError(f"{source}: {name} map has {bad} NaN or inf values")
        for name in ("diffuse", "roughness", "specular"):
            t = getattr(self, name)
            lo, hi = float(t.min()), float(t.max())
            if lo < -RANGE_SLACK or hi > 1.0 + RANGE_SLACK:
                raise MapError(f"{source}: {name} values must lie in [0, 1], found [{lo:.4g}, {hi:.4g}]")
        norm = self.normal.norm(dim=-3)
        worst = float((norm - 1.0).abs().max())
        if worst > NORMAL_SLACK:
            raise MapError(f"{source}: normal map is not unit length (max |len - 1| = {worst:.3g})")
        if float(self.normal[..., 2, :, :].min()) < -NORMAL_SLACK:
            raise MapError(f"{source}: normal map points into the surface (negative z)")
        return self


#: Value slack for [0, 1] maps: one 8-bit quantisation step (1/255 ~ 0.0039) rounded up.
RANGE_SLACK = 4e-3
#: Unit-length slack for normals decoded from 8-bit PNGs: (n+1)/2 quantisation moves
#: each component by up to 1/255, i.e. |len - 1| up to about sqrt(3) / 255 ~ 0.007.
NORMAL_SLACK = 1e-2


@dataclass(frozen=True)
class Capture:
    """V photos of one material with per-image light and camera positions.

    Attributes:
        images: ``[V, 3, H, W]`` linear radiance (the tone map is undone at load time).
        light_pos: ``[V, 3]`` point-light positions, scene units.
        camera_pos: ``[V, 3]`` camera positions, scene units.
        preset: name of the render preset (``kernels.PRESETS``) the positions live in.
        plane_size: side of the photographed plane in scene units (None: the preset's).
        intensity: light intensity per channel (None: the preset's).
        meta: free-form provenance (source format, file names), JSON-serialisable.
    """

    images: torch.Tensor
    light_pos: torch.Tensor
    camera_pos: torch.Tensor
    preset: str = "dgrsise"
    plane_size: float | None = None
    intensity: tuple[float, float, float] | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        # Every problem with a capture, a non-tensor included, is a MapError (a ValueError).
        try:
            dims = check_shape(self.images, "V 3 H W", name="Capture.images", dtypes=None)
            for name in ("light_pos", "camera_pos"):  # one position per image
                check_shape(getattr(self, name), "V 3", name=f"Capture.{name}", dims=dims, dtypes=None)
            check_finite(**{"Capture.images": self.images})
            check_above_plane("Capture.light_pos", self.light_pos)
            check_above_plane("Capture.camera_pos", self.camera_pos)
        except (TypeError, ValueError) as exc:
            raise MapError(str(exc)) from None

    @property
    def num_views(self) -> int:
        return self.images.shape[0]

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.images.shape[-2:])  # type: ignore[return-value]

    def to(self, *args, **kwargs) -> Capture:
        return replace(
            self,
            images=self.images.to(*args, **kwargs),
            light_pos=self.light_pos.to(*args, **kwargs),
            camera_pos=self.camera_pos.to(*args, **kwargs),
        )

    def render_kwargs(self) -> dict:
        """Keyword arguments for ``kernels.render`` matching this capture's scene."""
        kw: dict = {"preset": self.preset}
        if self.plane_size is not None:
            kw["plane_size"] = self.plane_size
        if self.intensity is not None:
            kw["intensity"] = self.intensity
        return kw
