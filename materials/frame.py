"""Preparing a photo for the models, with a record that maps every output back.

The models and the renderer see a square image whose side is a multiple of the
networks' downsample factor, spanning the square material plane of side
``plane_size`` (SPEC section 2: pixel (i, j) of an S x S image sits at
x = ((j + 0.5)/S - 0.5) * plane_size, y = -((i + 0.5)/S - 0.5) * plane_size). A photo
has any size and aspect ratio. ``prepare_photo`` turns one into the other and returns a
``Frame`` recording how, so that ``frame.to_photo(map)`` puts any output (maps,
re-renders, a confidence map, at the prepared resolution or any other) back on the
photo's pixel grid.

Non-square photos: the Warp kernels take one scalar ``plane_size`` and a square plane
(``kernels.presets``), so an H x W image with H != W would get non-square pixels there
(pitch plane_size/W in x and plane_size/H in y), stretching the material and moving the
highlight. So the pixel pitch is kept equal in x and y by padding the photo to a square
(``fit="pad"``, the default: nothing is lost; the padded pixels are invented by
reflection, and ``Frame.valid_mask`` says which pixels are real, so a refinement loss
can ignore the others) or cropping its centre square (``fit="crop"``: what is cut off
gets no maps). The photo then covers a centred ``photo_plane_size`` rectangle of the
plane.

Steps, in order (each recorded in the ``Frame``):

1. optional downscale (bilinear, antialiased) so the prepared side is at most
   ``max_side``;
2. pad (reflect or edge) or crop, centred, to a square of side a multiple of
   ``multiple`` (pad: the smallest one holding the photo; crop: the largest one inside).

Example:
    >>> image, frame = prepare_photo(torch.rand(3, 300, 200), multiple=8)
    >>> image.shape, frame.pad
    (torch.Size([3, 304, 304]), (2, 2, 52, 52))
    >>> frame.to_photo(image).shape
    torch.Size([3, 300, 200])
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F

from materials.types import Material

__all__ = ["Frame", "prepare_photo", "FITS", "PAD_MODES"]

#: How a photo is made square: pad it (keep everything) or crop its centre.
FITS = ("pad", "crop")
#: How padded pixels are invented. ``reflect`` mirrors about the photo's border, the
#: border pixel included (half-sample symmetric, numpy's "symmetric"), and repeats the
#: mirror for pads wider than the photo; ``edge`` repeats the border pixel.
PAD_MODES = ("reflect", "edge")


def _source_index(positions: torch.Tensor, n: int, mode: str) -> torch.Tensor:
    """Index into a length-``n`` axis for each (possibly out-of-range) position."""
    if mode == "edge":
        return positions.clamp(0, n - 1)
    m = torch.remainder(positions, 2 * n)
    return torch.where(m < n, m, 2 * n - 1 - m)


@dataclass(frozen=True)
class Frame:
    """How a prepared image relates to its photo (all sizes ``(H, W)``, pixels).

    The prepared image is a window of the (resized) photo extended by padding: its pixel
    (i, j) is the resized photo's pixel (i + top, j + left), where ``origin = (top,
    left)`` is negative where the photo was padded and positive where it was cropped.

    Attributes:
        photo_size: the photo's ``(H, W)``.
        scaled_size: the photo's size after step 1 (equal to ``photo_size`` if not resized).
        origin: ``(top, left)``, see above.
        size: the prepared image's ``(S, S)``.
        pad_mode: how padded pixels were made (``PAD_MODES``).
        plane_size: side of the square material plane the prepared image spans, scene units.
    """

    photo_size: tuple[int, int]
    scaled_size: tuple[int, int]
    origin: tuple[int, int]
    size: tuple[int, int]
    pad_mode: str = "reflect"
    plane_size: float = 4.0

    # ------------------------------------------------------------------ derived facts
    @property
    def scale(self) -> tuple[float, float]:
        """``(sy, sx)``: resized / original size per axis (1.0 without resizing)."""
        return (self.scaled_size[0] / self.photo_size[0], self.scaled_size[1] / self.photo_size[1])

    @property
    def pad(self) -> tuple[int, int, int, int]:
        """Pixels added ``(top, bottom, left, right)`` around the resized photo."""
        (top, left), (h, w), (sh, sw) = self.origin, self.scaled_size, self.size
        return (max(0, -top), max(0, top + sh - h), max(0, -left), max(0, left + sw - w))

    @property
    def crop(self) -> tuple[int, int, int, int]:
        """Pixels cut ``(top, bottom, left, right)`` off the resized photo."""
        (top, left), (h, w), (sh, sw) = self.origin, self.scaled_size, self.size
        return (max(0, top), max(0, h - top - sh), max(0, left), max(0, w - left - sw))

    @property
    def content_box(self) -> tuple[int, int, int, int]:
        """``(top, left, height, width)`` of the prepared pixels that come from the photo."""
        top, bottom, left, right = self.pad
        return (top, left, self.size[0] - top - bottom, self.size[1] - left - right)

    @property
    def pixel_pitch(self) -> float:
        """Side of one prepared pixel in scene units (the same in x and y)."""
        return self.plane_size / self.size[1]

    @property
    def photo_plane_size(self) -> tuple[float, float]:
        """``(width, height)`` of the plane area the (whole, uncropped) photo covers, scene units."""
        return (self.scaled_size[1] * self.pixel_pitch, self.scaled_size[0] * self.pixel_pitch)

    @property
    def photo_long_side(self) -> float:
        """The photo's long side on the plane, scene units (what a field of view spans)."""
        return max(self.photo_plane_size)

    def valid_mask(self, device: torch.device | str | None = None) -> torch.Tensor:
        """``[S, S]`` bool: True where the prepared pixel is the photo's, False where padded."""
        top, left, h, w = self.content_box
        mask = torch.zeros(self.size, dtype=torch.bool, device=device)
        mask[top : top + h, left : left + w] = True
        return mask

    def photo_coverage(self, device: torch.device | str | None = None) -> torch.Tensor:
        """``[H, W]`` bool on the photo's grid: True where the prepared image has the pixel
        (all True unless ``fit="crop"`` cut something off)."""
        (H, W), (sy, sx) = self.photo_size, self.scale
        (top, left), (sh, sw) = self.origin, self.size
        rows = (torch.arange(H, device=device) + 0.5) * sy - top
        cols = (torch.arange(W, device=device) + 0.5) * sx - left
        return ((rows >= 0) & (rows < sh))[:, None] & ((cols >= 0) & (cols < sw))[None, :]

    # ------------------------------------------------------------------ coordinates
    def pixel_to_plane(self, rows: torch.Tensor, cols: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Plane point ``(x, y)`` (scene units, z = 0) of the centre of photo pixel
        ``(rows, cols)`` (original photo grid; fractional indices allowed; shapes broadcast)."""
        (sy, sx), (top, left), (sh, sw) = self.scale, self.origin, self.size
        u = ((cols + 0.5) * sx - left) / sw  # 0 at the plane's left edge, 1 at its right
        v = ((rows + 0.5) * sy - top) / sh  # 0 at the top edge (+y), 1 at the bottom
        return (u - 0.5) * self.plane_size, -(v - 0.5) * self.plane_size

    def photo_plane_distance(self, point: tuple[float, float]) -> torch.Tensor:
        """``[H, W]`` float32 on the photo's grid: the distance (scene units) from each
        photo pixel's plane point to the plane point ``(x, y)``, e.g. the point under the
        flash (the highlight region of a photo, measured on the photo's own pixels)."""
        h, w = self.photo_size
        rows, cols = torch.meshgrid(
            torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
        )
        x, y = self.pixel_to_plane(rows, cols)
        return torch.hypot(x - float(point[0]), y - float(point[1]))

    def plane_to_pixel(self, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Inverse of :meth:`pixel_to_plane`: fractional photo ``(rows, cols)`` of a plane point."""
        (sy, sx), (top, left), (sh, sw) = self.scale, self.origin, self.size
        u = x / self.plane_size + 0.5
        v = 0.5 - y / self.plane_size
        return (v * sh + top) / sy - 0.5, (u * sw + left) / sx - 0.5

    # ------------------------------------------------------------------ mappings
    def apply(self, image: torch.Tensor) -> torch.Tensor:
        """Prepare another image of the photo's grid the same way (a mask, a second photo).

        Args:
            image: ``[..., C, H, W]`` on the photo's grid, any dtype (bool and integer
                images are resized by nearest neighbour, float ones bilinearly).
        Returns:
            ``[..., C, S, S]``.
        """
        if tuple(image.shape[-2:]) != self.photo_size:
            raise ValueError(f"image is {tuple(image.shape[-2:])}, the photo {self.photo_size} (H, W)")
        if self.scaled_size != self.photo_size:
            lead = image.shape[:-2]
            flat = image.reshape(-1, 1, *self.photo_size)
            if flat.is_floating_point():
                flat = F.interpolate(flat, size=self.scaled_size, mode="bilinear", antialias=True, align_corners=False)
            else:
                flat = F.interpolate(flat.float(), size=self.scaled_size, mode="nearest-exact").to(image.dtype)
            image = flat.reshape(*lead, *self.scaled_size)
        (top, left), (sh, sw), (h, w) = self.origin, self.size, self.scaled_size
        rows = _source_index(torch.arange(top, top + sh, device=image.device), h, self.pad_mode)
        cols = _source_index(torch.arange(left, left + sw, device=image.device), w, self.pad_mode)
        return image.index_select(-2, rows).index_select(-1, cols)

    def to_photo(self, x: torch.Tensor, *, fill: float = 0.0) -> torch.Tensor:
        """Map an output on the prepared plane back to the photo's pixel grid.

        Args:
            x: ``[..., C, h, w]`` float, covering the prepared image's plane (any
                resolution: the prepared one, or e.g. a 64 x 64 relighting output).
            fill: value of photo pixels the prepared image does not cover (``fit="crop"``).
        Returns:
            ``[..., C, H, W]`` on the photo's grid. Exact (the same values) when ``x`` has
            the prepared size and the photo was not resized; otherwise bilinear
            resampling at the photo's pixel centres (renormalise normal maps after:
            :meth:`material_to_photo` does).
        """
        if x.dim() < 3:
            raise ValueError(f"x must be [..., C, h, w], got {tuple(x.shape)}")
        (H, W), (top, left), (sh, sw) = self.photo_size, self.origin, self.size
        lead, (c, xh, xw) = x.shape[:-3], x.shape[-3:]
        if (xh, xw) == self.size and self.scaled_size == self.photo_size:
            out = x.new_full((*lead, c, H, W), fill)
            r0, r1 = max(0, top), min(H, top + sh)
            c0, c1 = max(0, left), min(W, left + sw)
            out[..., r0:r1, c0:c1] = x[..., r0 - top : r1 - top, c0 - left : c1 - left]
            return out
        if not x.is_floating_point():
            raise TypeError(f"resampling needs a float tensor, got {x.dtype}")
        (sy, sx) = self.scale
        u = ((torch.arange(W, device=x.device, dtype=x.dtype) + 0.5) * sx - left) / sw
        v = ((torch.arange(H, device=x.device, dtype=x.dtype) + 0.5) * sy - top) / sh
        grid = torch.stack(torch.broadcast_tensors(2 * u[None, :] - 1, 2 * v[:, None] - 1), dim=-1)
        flat = x.reshape(-1, c, xh, xw)
        out = F.grid_sample(
            flat, grid[None].expand(flat.shape[0], H, W, 2), mode="bilinear", padding_mode="border", align_corners=False
        )
        covered = self.photo_coverage(device=x.device)
        if not bool(covered.all()):
            out = torch.where(covered, out, out.new_tensor(fill))
        return out.reshape(*lead, c, H, W)

    def material_to_photo(self, material: Material) -> Material:
        """:meth:`to_photo` for every map of a material ``[..., C, S, S]``; normals are
        renormalised after resampling, and photo pixels without maps (crop) get a flat
        normal (0, 0, 1) and zeros elsewhere."""
        maps = {name: self.to_photo(t) for name, t in material.maps().items()}
        normal = F.normalize(maps["normal"], dim=-3)
        covered = self.photo_coverage(device=normal.device)
        up = torch.zeros_like(normal)
        up[..., 2, :, :] = 1.0
        maps["normal"] = torch.where(covered, normal, up)
        return Material(**maps)

    # ------------------------------------------------------------------ records
    def to_dict(self) -> dict:
        """JSON-serialisable record (lists for tuples); ``Frame.from_dict`` reads it back."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @staticmethod
    def from_dict(d: dict) -> Frame:
        return Frame(
            photo_size=tuple(d["photo_size"]),
            scaled_size=tuple(d["scaled_size"]),
            origin=tuple(d["origin"]),
            size=tuple(d["size"]),
            pad_mode=d.get("pad_mode", "reflect"),
            plane_size=float(d.get("plane_size", 4.0)),
        )


def prepare_photo(
    photo,
    *,
    multiple: int = 8,
    max_side: int | None = None,
    fit: str = "pad",
    pad_mode: str = "reflect",
    plane_size: float = 4.0,
) -> tuple[torch.Tensor, Frame]:
    """Make a photo square, a multiple of ``multiple`` and at most ``max_side`` pixels.

    Args:
        photo: a ``materials.io.photo.Photo`` or a tensor ``[C, H, W]`` (linear radiance).
        multiple: the side is a multiple of this (the estimator's
            ``arch.downsample_factor``, 8 for the U-Nets here).
        max_side: downscale first so the prepared side is at most this (None: never
            resize; the result then holds the photo's pixels unchanged).
        fit: ``"pad"`` (keep the whole photo, pad the short side) or ``"crop"`` (the
            largest centred square inside it).
        pad_mode: ``"reflect"`` or ``"edge"`` (``PAD_MODES``).
        plane_size: side of the square plane the result spans, scene units (recorded).

    Returns:
        ``(image, frame)``: ``image [C, S, S]`` (same dtype as the input), and the
        ``Frame`` to map outputs back.
    """
    image = getattr(photo, "image", photo)
    if not isinstance(image, torch.Tensor) or image.dim() != 3:
        raise ValueError(f"photo must be a Photo or a [C, H, W] tensor, got {getattr(image, 'shape', type(image))}")
    if multiple < 1:
        raise ValueError(f"multiple must be at least 1, got {multiple}")
    if fit not in FITS:
        raise ValueError(f"fit must be one of {FITS}, got {fit!r}")
    if pad_mode not in PAD_MODES:
        raise ValueError(f"pad_mode must be one of {PAD_MODES}, got {pad_mode!r}")
    if not plane_size > 0:
        raise ValueError(f"plane_size must be positive, got {plane_size}")
    H, W = image.shape[-2:]
    if min(H, W) < 1:
        raise ValueError(f"photo is empty: {H}x{W}")

    h, w = H, W
    if max_side is not None:
        limit = (max_side // multiple) * multiple  # so padding up to a multiple stays <= max_side
        if limit < multiple:
            raise ValueError(f"max_side {max_side} is below the multiple {multiple}")
        # pad: the long side must fit; crop: only the short side is kept, so it must fit.
        side = max(H, W) if fit == "pad" else min(H, W)
        if side > limit:
            s = limit / side
            h, w = max(1, round(H * s)), max(1, round(W * s))

    if fit == "pad":
        side = math.ceil(max(h, w) / multiple) * multiple
        origin = (-((side - h) // 2), -((side - w) // 2))
    else:
        side = (min(h, w) // multiple) * multiple
        if side < multiple:
            raise ValueError(f"photo {H}x{W} is smaller than one {multiple}-pixel block; cannot crop")
        origin = ((h - side) // 2, (w - side) // 2)
    frame = Frame(
        photo_size=(H, W),
        scaled_size=(h, w),
        origin=origin,
        size=(side, side),
        pad_mode=pad_mode,
        plane_size=float(plane_size),
    )
    return frame.apply(image), frame
