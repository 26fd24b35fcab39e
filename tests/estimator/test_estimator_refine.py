"""Test-time refinement: lowers the rendering loss, Warp and pure-torch losses agree,
the caller's model is untouched, bad inputs are named."""

from __future__ import annotations

import pytest
import torch

import kernels
import kernels.reference
from estimator.refine import converged, refine, refine_maps

#: Warp vs pure-torch rendering loss along a few identical Adam steps: the forward
#: losses differ by float32 summation order (~1e-6 relative) and the gradients by the
#: same, which a few steps of Adam cannot amplify past 1e-3 (the brief's tolerance).
BACKEND_RTOL = 1e-3


def _loss(material, images, light, camera):
    return float(kernels.rendering_loss(*material.map_tensors(), images, light, camera))


def test_refine_lowers_rendering_loss(tiny_model, synthetic_capture):
    _, images, light, camera = synthetic_capture(batch=1, views=4)
    with torch.no_grad():
        start = _loss(tiny_model(images, light, camera), images, light, camera)
    result = refine(tiny_model, images, light, camera, steps=40, latent_steps=10, progress=False)
    assert len(result.history) <= 40 and result.latent_steps <= 10
    assert result.history[0] == pytest.approx(start, rel=1e-5)
    end = _loss(result.material, images, light, camera)
    assert end < 0.9 * start, (start, end)
    assert end <= min(result.history) + 1e-6  # the best parameters are the ones returned


def test_refine_does_not_mutate_the_model(tiny_model, synthetic_capture):
    _, images, light, camera = synthetic_capture(views=2)
    before = {k: v.clone() for k, v in tiny_model.state_dict().items()}
    flags = {k: p.requires_grad for k, p in tiny_model.named_parameters()}
    refine(tiny_model, images, light, camera, steps=6, latent_steps=3, progress=False)
    for k, v in tiny_model.state_dict().items():
        torch.testing.assert_close(v, before[k], atol=0, rtol=0, msg=k)
    assert flags == {k: p.requires_grad for k, p in tiny_model.named_parameters()}


@pytest.mark.parametrize("stage", ["latent", "heads"])
def test_warp_and_reference_losses_agree(tiny_model, synthetic_capture, stage):
    _, images, light, camera = synthetic_capture(views=3, seed=2)
    latent = 4 if stage == "latent" else 0
    kw = dict(steps=4, latent_steps=latent, window=100, progress=False)
    warp = refine(tiny_model, images, light, camera, render_loss_fn=kernels.rendering_loss, **kw)
    ref = refine(tiny_model, images, light, camera, render_loss_fn=kernels.reference.rendering_loss, **kw)
    assert len(warp.history) == len(ref.history) == 4
    for a, b in zip(warp.history, ref.history):
        assert a == pytest.approx(b, rel=BACKEND_RTOL)
    assert warp.history[-1] < warp.history[0]


def test_refine_maps_lowers_loss_and_backends_agree(synthetic_capture):
    maps, images, light, camera = synthetic_capture(views=4, seed=3)
    from materials.types import Material

    start = Material(
        torch.full_like(maps[0], 0.5),
        torch.nn.functional.normalize(maps[1] + 0.3, dim=1),
        torch.full_like(maps[2], 0.5),
        torch.full_like(maps[3], 0.1),
    )
    warp = refine_maps(start, images, light, camera, steps=30, lr=5e-2, progress=False)
    ref = refine_maps(
        start,
        images,
        light,
        camera,
        steps=5,
        lr=5e-2,
        window=100,
        progress=False,
        render_loss_fn=kernels.reference.rendering_loss,
    )
    for a, b in zip(warp.history[:5], ref.history):
        assert a == pytest.approx(b, rel=BACKEND_RTOL)
    assert _loss(warp.material, images, light, camera) < 0.7 * warp.history[0]
    warp.material.validate()


def test_converged_rule():
    assert not converged([1.0] * 5, window=5, tol=1e-4)
    assert converged([1.0] * 6, window=5, tol=1e-4)
    assert not converged([1.0, 0.9, 0.8, 0.7, 0.6, 0.5], window=5, tol=1e-4)


@pytest.mark.parametrize(
    "mutate, name",
    [
        (lambda i, l, c: (i[:, 0], l, c), "images"),
        (lambda i, l, c: (i, l[:, :1], c), "light"),
        (lambda i, l, c: (i, l, c[:, :1]), "camera"),
        (lambda i, l, c: (i * float("nan"), l, c), "images"),
    ],
)
def test_refine_bad_input(tiny_model, synthetic_capture, mutate, name):
    _, images, light, camera = synthetic_capture(views=2)
    with pytest.raises(ValueError, match=name):
        refine(tiny_model, *mutate(images, light, camera), steps=2, progress=False)
