"""Light and camera sampling (SPEC section 3) and the fixed evaluation set.

Positions are in scene units of the ``dgrsise`` preset (plane of side 4 at z = 0).
"""

from __future__ import annotations

import torch

__all__ = [
    "EVAL_CAMERA",
    "EVAL_LIGHTS",
    "TRAIN_CAMERA_HEIGHT",
    "TRAIN_LIGHT_XY",
    "TRAIN_LIGHT_HEIGHT",
    "sample_paper_lights",
    "eval_lights",
]

#: Training camera height range (paper: camera (0, 0, h), h ~ U[4, 8]).
TRAIN_CAMERA_HEIGHT = (4.0, 8.0)
#: Training light x, y range (paper: U[-4, 4]) and height range (paper: U[4, 8]).
TRAIN_LIGHT_XY = (-4.0, 4.0)
TRAIN_LIGHT_HEIGHT = (4.0, 8.0)

#: Evaluation camera (SPEC section 3): above the plane centre at height 4.
EVAL_CAMERA = (0.0, 0.0, 4.0)
#: The 7 fixed evaluation lights (the paper does not publish its own). Chosen to cover
#: the four quadrants at the camera's height (mirror highlights at p_xy / 2, inside the
#: plane), two higher lights off-axis, and one nearly overhead high light, so an
#: evaluation sees highlights at the centre, mid-plane and near the edges.
EVAL_LIGHTS = (
    (-2.0, 2.0, 4.0),
    (2.0, 2.0, 4.0),
    (2.0, -2.0, 4.0),
    (-2.0, -2.0, 4.0),
    (0.0, 3.0, 6.0),
    (3.0, 0.0, 5.0),
    (-1.0, 0.5, 7.0),
)


def _uniform(lo: float, hi: float, shape, generator: torch.Generator) -> torch.Tensor:
    return lo + (hi - lo) * torch.rand(shape, generator=generator, dtype=torch.float64)


def sample_paper_lights(views: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """One training group's positions (SPEC section 3), float32.

    Returns (light_pos ``[views, 3]``, camera_pos ``[views, 3]``): the camera is at (0, 0, h)
    for every view, h ~ U[4, 8]; view 0 is lit from the camera (the flash "input");
    views 1.. by lights with x, y ~ U[-4, 4], z ~ U[4, 8].
    """
    if views < 1:
        raise ValueError(f"views must be at least 1, got {views}")
    h = _uniform(*TRAIN_CAMERA_HEIGHT, (1,), generator)
    camera = torch.zeros(views, 3, dtype=torch.float64)
    camera[:, 2] = h
    light = torch.empty(views, 3, dtype=torch.float64)
    light[0] = camera[0]
    light[1:, :2] = _uniform(*TRAIN_LIGHT_XY, (views - 1, 2), generator)
    light[1:, 2] = _uniform(*TRAIN_LIGHT_HEIGHT, (views - 1,), generator)
    return light.float(), camera.float()


def eval_lights(*, include_input: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """The evaluation positions: (light_pos, camera_pos), each ``[V, 3]`` float32, with view 0
    the collocated input when ``include_input`` (V = 8), else the 7 targets (V = 7)."""
    targets = torch.tensor(EVAL_LIGHTS, dtype=torch.float32)
    light = torch.cat([torch.tensor([EVAL_CAMERA]), targets]) if include_input else targets
    camera = torch.tensor(EVAL_CAMERA).expand(light.shape[0], 3).clone()
    return light, camera
