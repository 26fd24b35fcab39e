import pytest
import torch

from relight.diffusion import RelightDiffusion

#: A real but tiny architecture: every code path of the tiny preset, at 16x16, with the
#: switches a new training run turns on (``TINY_TRAINING_DEFAULTS``; base: the photo).
TINY = dict(
    resolution=16,
    block_out_channels=(8, 16),
    cross_attention_dim=16,
    attention_head_dim=4,
    num_light_tokens=2,
    condition_widths=(4, 4, 4, 4, 8, 8),
    photo_concat=True,
    residual=True,
    data_scale=3.0,
)


@pytest.fixture
def tiny_args():
    """The constructor arguments of ``tiny_model``."""
    return dict(TINY)


@pytest.fixture
def tiny_model():
    torch.manual_seed(0)
    return RelightDiffusion(**TINY)


@pytest.fixture
def group_batch():
    return make_group_batch


def make_group_batch(b=1, v=4, size=16, seed=0):
    gen = torch.Generator().manual_seed(seed)
    images = torch.rand(b, v, 3, size, size, generator=gen)
    light_pos = torch.rand(b, v, 3, generator=gen) * 4 - 2
    light_pos[..., 2] = 4 + torch.rand(b, v, generator=gen)
    camera_pos = torch.tensor([0.0, 0.0, 4.0]).expand(b, v, 3).clone()
    light_pos[:, 0] = camera_pos[:, 0]
    return {"images": images, "light_pos": light_pos, "camera_pos": camera_pos}
