"""``estimator.optim.MapAdam``: per-element groups are torch's Adam; shared groups step in
proportion to the gradient (no sign field, the cause of the refinement's creases)."""

from __future__ import annotations

import pytest
import torch

from estimator.optim import MapAdam

#: MapAdam against torch.optim.Adam (single-tensor path) or the update written out here:
#: the same float64 formula, its operations grouped slightly differently (torch squares
#: the gradient inside ``addcmul_``); a few units of roundoff (2.2e-16) per step at most.
SAME_OPS_RTOL = 1e-13


def _quadratic_grads(p: torch.Tensor, target: torch.Tensor) -> None:
    p.grad = None
    ((p - target) ** 2 * torch.linspace(0.1, 3.0, p.numel(), dtype=p.dtype).view_as(p)).sum().backward()


def test_per_element_group_is_torch_adam():
    g = torch.Generator().manual_seed(0)
    start = torch.randn(1, 3, 8, 8, generator=g, dtype=torch.float64)
    target = torch.randn(1, 3, 8, 8, generator=g, dtype=torch.float64)
    ours = start.clone().requires_grad_(True)
    theirs = start.clone().requires_grad_(True)
    opt_ours = MapAdam([ours], lr=0.05, shared=False)
    opt_theirs = torch.optim.Adam([theirs], lr=0.05, foreach=False)
    for _ in range(10):
        _quadratic_grads(ours, target)
        _quadratic_grads(theirs, target)
        opt_ours.step()
        opt_theirs.step()
    assert not torch.equal(ours, start)
    torch.testing.assert_close(ours, theirs, rtol=SAME_OPS_RTOL, atol=0)


def test_shared_step_is_proportional_to_the_gradient():
    """A smooth ramp of gradient (x across the map, a radial field's x component): stock
    Adam's first step is lr * sign(x), a step function with a jump at x = 0 (the crease);
    the shared step is -lr * g / rms(g) per channel, the ramp itself."""
    lr = 0.01
    x = torch.linspace(-1, 1, 16, dtype=torch.float64)
    grad = torch.stack([x.expand(16, 16), 3 * x[:, None].expand(16, 16)])[None]  # [1, 2, 16, 16]
    steps = {}
    for shared in (False, True):
        p = torch.zeros(1, 2, 16, 16, dtype=torch.float64, requires_grad=True)
        opt = MapAdam([p], lr=lr, shared=shared)
        p.grad = grad.clone()
        opt.step()
        steps[shared] = p.detach()
    rms = grad.square().mean(dim=(-2, -1), keepdim=True).sqrt()
    torch.testing.assert_close(steps[True], -lr * grad / (rms + 1e-8), rtol=SAME_OPS_RTOL, atol=0)
    # Stock Adam: every pixel steps by lr, in the sign of its gradient (up to eps).
    torch.testing.assert_close(steps[False].abs(), torch.full_like(grad, lr), rtol=1e-6, atol=0)
    # The jump between the two middle columns: the whole 2 lr for stock Adam, one ramp
    # increment (2 / 15 of the ramp's unit) scaled by lr / rms for the shared step.
    jump = {s: float((steps[s][0, 0, :, 8] - steps[s][0, 0, :, 7]).abs().max()) for s in steps}
    assert jump[False] == pytest.approx(2 * lr, rel=1e-6)
    assert jump[True] < 0.25 * lr


def test_share_channels_keeps_the_gradient_direction():
    # The y slope's gradient three times the x slope's: per-channel moments give both
    # channels the same RMS step (the direction turns towards 45 degrees); one moment for
    # both keeps the 1 : 3 ratio, i.e. the gradient's direction.
    x = torch.linspace(-1, 1, 8, dtype=torch.float64).expand(8, 8)
    grad = torch.stack([x, 3 * x])[None]
    ratio = {}
    for joint in (False, True):
        p = torch.zeros(1, 2, 8, 8, dtype=torch.float64, requires_grad=True)
        opt = MapAdam([p], lr=0.01, share_channels=joint)
        p.grad = grad.clone()
        opt.step()
        assert opt.state[p]["exp_avg_sq"].shape == ((1, 1, 1, 1) if joint else (1, 2, 1, 1))
        ratio[joint] = float(p.detach()[0, 1].abs().max() / p.detach()[0, 0].abs().max())
    # rel 1e-6: Adam's eps (1e-8) against RMS gradients of 0.6 and 1.8 tilts the ratio by ~1e-8.
    assert ratio[False] == pytest.approx(1.0, rel=1e-6)
    assert ratio[True] == pytest.approx(3.0, rel=1e-6)


def test_shared_update_over_several_steps_matches_the_formula():
    # Changing gradients over 5 steps: the bias corrections at t > 1 and the moving averages.
    g = torch.Generator().manual_seed(1)
    lr, (b1, b2), eps = 0.02, (0.9, 0.999), 1e-8
    p = torch.zeros(1, 2, 6, 6, dtype=torch.float64, requires_grad=True)
    opt = MapAdam([p], lr=lr, shared=True)
    expect = torch.zeros(1, 2, 6, 6, dtype=torch.float64)
    m = torch.zeros_like(expect)
    v = torch.zeros(1, 2, 1, 1, dtype=torch.float64)
    for t in range(1, 6):
        grad = torch.randn(1, 2, 6, 6, generator=g, dtype=torch.float64) * t
        p.grad = grad.clone()
        opt.step()
        m = b1 * m + (1 - b1) * grad
        v = b2 * v + (1 - b2) * grad.square().mean(dim=(-2, -1), keepdim=True)
        expect = expect - lr * (m / (1 - b1**t)) / ((v / (1 - b2**t)).sqrt() + eps)
    torch.testing.assert_close(p.detach(), expect, rtol=SAME_OPS_RTOL, atol=1e-15)


def test_mask_keeps_padding_from_diluting_the_shared_step():
    # A 4 x 4 map padded to 4 x 8 with pixels no loss reaches (zero gradient): with the
    # mask, the real pixels step exactly as without the padding; without it, the mean
    # square halves and they step sqrt(2) times too far.
    g = torch.Generator().manual_seed(2)
    grad = torch.randn(1, 1, 4, 4, generator=g, dtype=torch.float64)
    padded = torch.cat([grad, torch.zeros_like(grad)], dim=-1)
    mask = torch.cat([torch.ones(4, 4, dtype=torch.bool), torch.zeros(4, 4, dtype=torch.bool)], dim=-1)

    def first_step(gradient, **kw):
        p = torch.zeros_like(gradient, requires_grad=True)
        opt = MapAdam([p], lr=0.1, **kw)
        p.grad = gradient.clone()
        opt.step()
        return p.detach()

    alone = first_step(grad)
    torch.testing.assert_close(first_step(padded, mask=mask)[..., :4], alone, rtol=SAME_OPS_RTOL, atol=0)
    torch.testing.assert_close(first_step(padded)[..., :4], alone * 2**0.5, rtol=1e-6, atol=0)


def test_max_step_caps_a_pixel_that_holds_the_whole_gradient():
    grad = torch.zeros(1, 1, 64, 64)
    grad[0, 0, 10, 10] = 1.0
    for cap, expect in ((None, 64.0), (10.0, 10.0)):  # sqrt(H * W) rates uncapped
        p = torch.zeros(1, 1, 64, 64, requires_grad=True)
        opt = MapAdam([p], lr=0.01, max_step=cap)
        p.grad = grad.clone()
        opt.step()
        assert float(p.detach().abs().max()) == pytest.approx(0.01 * expect, rel=1e-4)


def test_shared_groups_and_per_element_groups_mix():
    a = torch.zeros(1, 1, 4, 4, requires_grad=True)
    b = torch.zeros(1, 1, 4, 4, requires_grad=True)
    opt = MapAdam([{"params": [a], "shared": True}, {"params": [b], "shared": False}], lr=0.1)
    grad = torch.arange(16.0).view(1, 1, 4, 4) + 1
    a.grad, b.grad = grad.clone(), grad.clone()
    opt.step()
    assert opt.state[a]["exp_avg_sq"].shape == (1, 1, 1, 1)
    assert opt.state[b]["exp_avg_sq"].shape == (1, 1, 4, 4)
    assert float(a.detach().abs().max() - a.detach().abs().min()) > 0.05  # follows the gradient
    torch.testing.assert_close(b.detach(), torch.full_like(b, -0.1), rtol=1e-5, atol=0)  # sign steps


@pytest.mark.parametrize(
    "bad, message",
    [
        (dict(lr=0.0), "lr must be positive"),
        (dict(betas=(1.0, 0.999)), "betas"),
        (dict(eps=-1.0), "eps"),
        (dict(max_step=0.0), "max_step"),
        (dict(mask=torch.ones(3, 3, dtype=torch.bool)), "mask must be"),
        (dict(mask=torch.zeros(2, 2, dtype=torch.bool)), "no pixel"),
        (dict(shared=False, mask=torch.ones(2, 2, dtype=torch.bool)), "shared groups only"),
    ],
)
def test_bad_settings_are_refused(bad, message):
    with pytest.raises(ValueError, match=message):
        MapAdam([torch.zeros(1, 1, 2, 2, requires_grad=True)], **bad)


def test_shared_group_needs_maps():
    with pytest.raises(ValueError, match="maps"):
        MapAdam([torch.zeros(4, requires_grad=True)], shared=True)
    opt = MapAdam([torch.zeros(1, 1, 2, 2, requires_grad=True)])
    with pytest.raises(ValueError, match="maps"):  # groups added later are checked too
        opt.add_param_group({"params": [torch.zeros(4, requires_grad=True)]})
