"""Tiny shared fixtures for the estimator tests (32 x 32 images, base channels 8)."""

from __future__ import annotations

import pytest
import torch

import kernels
from estimator import SVBRDFEstimator
from estimator.config import TINY_TEST_CONFIG

SIZE = 32


@pytest.fixture(autouse=True)
def one_thread():
    """The machine has 2 cores shared with other work: two torch threads spin-wait
    against each other (a tiny step went from 0.04 s to 0.3-1 s when measured)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def tiny_model() -> SVBRDFEstimator:
    torch.manual_seed(0)
    return SVBRDFEstimator(**TINY_TEST_CONFIG.to_dict()).eval()


def _random_views(batch: int, views: int, size: int = SIZE, seed: int = 0):
    """Positive 'linear radiance' images with plausible light/camera positions."""
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(batch, views, 3, size, size, generator=g) * 2
    light = torch.empty(batch, views, 3)
    light[..., :2] = torch.rand(batch, views, 2, generator=g) * 8 - 4
    light[..., 2] = 4 + 4 * torch.rand(batch, views, generator=g)
    camera = torch.tensor([0.0, 0.0, 5.0]).expand(batch, views, 3).clone()
    light[:, 0] = camera[:, 0]
    return images, light, camera


def _synthetic_capture(batch: int = 1, views: int = 4, size: int = SIZE, seed: int = 0):
    """A smooth synthetic material rendered under ``views`` lights: (maps, images, light, camera)."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, size), torch.linspace(-1, 1, size), indexing="ij")
    diffuse = (0.3 + 0.25 * torch.stack([torch.sin(3 * xx), torch.cos(2 * yy), torch.sin(xx + yy)]))[None]
    normal = torch.stack([0.2 * torch.sin(4 * xx), 0.2 * torch.cos(3 * yy), torch.ones_like(xx)])[None]
    normal = torch.nn.functional.normalize(normal, dim=1)
    roughness = (0.4 + 0.2 * torch.cos(2 * xx))[None, None]
    specular = torch.full((1, 3, size, size), 0.06)
    maps = tuple(t.expand(batch, *t.shape[1:]).contiguous() for t in (diffuse, normal, roughness, specular))
    light = torch.empty(batch, views, 3)
    light[..., :2] = torch.rand(batch, views, 2, generator=g) * 6 - 3
    light[..., 2] = 4 + 2 * torch.rand(batch, views, generator=g)
    camera = torch.tensor([0.0, 0.0, 4.0]).expand(batch, views, 3).clone()
    light[:, 0] = camera[:, 0]
    images = kernels.render(*maps, light, camera)
    return maps, images, light, camera


@pytest.fixture
def random_views():
    """``random_views(batch, views, size=32, seed=0) -> (images, light, camera)``."""
    return _random_views


@pytest.fixture
def synthetic_capture():
    """``synthetic_capture(batch=1, views=4, size=32, seed=0) -> (maps, images, light, camera)``."""
    return _synthetic_capture
