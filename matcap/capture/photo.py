"""Photos without a file: a ``[3, H, W]`` tensor wrapped as a ``Photo``
(``photo_from_tensor``) and the built-in flash photo the project renders itself
(``builtin_photo``).
"""

from __future__ import annotations

import torch

import kernels
from kernels.tonemap import tonemap
from matcap.capture.config import BUILTIN_SEED, BUILTIN_SIZE, DEFAULT_FALLOFF, FALLOFFS
from matcap.capture.scene import CaptureScene
from materials.camera import DEFAULT_FOV_DEG
from materials.io.photo import Photo


def photo_from_tensor(image: torch.Tensor, name: str = "<tensor>", *, fmt: str = "tensor") -> Photo:
    """Wrap ``[3, H, W]`` linear radiance as a ``Photo`` (for callers without a file)."""
    if not isinstance(image, torch.Tensor) or image.dim() != 3 or image.shape[0] != 3:
        raise ValueError(f"photo must be a Photo or a [3, H, W] tensor, got {getattr(image, 'shape', type(image))}")
    size = tuple(image.shape[-2:])
    return Photo(image=image.float(), path=name, format=fmt, bit_depth=None, file_size=size, channels=3)


def builtin_photo(name: str = "", *, size: int = BUILTIN_SIZE, falloff: str = DEFAULT_FALLOFF) -> Photo:
    """A flash photo the project makes itself: a procedural material rendered under the
    flash at the default camera (45 degrees over a square photo), tone-mapped and
    quantised to 8 bits like a PNG, decoded back to linear radiance.

    Args:
        name: ``""`` (seed ``BUILTIN_SEED``), a seed number, or a procedural family
            (``materials.procedural.FAMILIES``; its glossy finish).
        size: side of the square photo, pixels.
        falloff: whether the flash falls off with 1/d^2 (a real flash) or not.

    Returns:
        A ``Photo`` with ``format="builtin"`` and ``path="builtin:<name>"``.
    """
    from materials.camera import camera_from_fov
    from materials.procedural import FAMILIES, generate

    if falloff not in FALLOFFS:
        raise ValueError(f"falloff must be one of {', '.join(FALLOFFS)}, got {falloff!r}")
    if name == "":
        material, label = generate(BUILTIN_SEED, size=size), str(BUILTIN_SEED)
    elif name.isdigit():
        material, label = generate(int(name), size=size), name
    elif name in FAMILIES:
        material, label = generate(BUILTIN_SEED, size=size, family=name, glossy=True), name
    else:
        raise ValueError(f"builtin photo {name!r}: give a seed number or a family ({', '.join(FAMILIES)})")
    camera = camera_from_fov(DEFAULT_FOV_DEG)
    scene = CaptureScene(camera, "default", DEFAULT_FOV_DEG, torch.zeros(0, 3), falloff, 4.0)
    radiance = kernels.render(*(t[None] for t in material.map_tensors()), camera[None], camera, **scene.render_kwargs)
    codes = torch.round(tonemap(radiance[0, 0]) * 255.0) / 255.0
    return photo_from_tensor(kernels.inverse_tonemap(codes), f"builtin:{label}", fmt="builtin")
