"""Pure-torch twins of every public kernel function, with the same names and semantics.

They define what the Warp kernels compute (tests compare forward values and gradients
against them) and are the baseline in the benchmarks. Plain eager torch, autograd by
torch; written for clarity, not speed or memory.
"""

from __future__ import annotations

import math

import torch

from kernels.brdf import FRESNEL_A, FRESNEL_B, NORMALIZE_EPS
from kernels.geometry import highlight_offsets
from kernels.presets import RenderPreset, get_preset

__all__ = [
    "render",
    "lvh_maps",
    "plane_points",
    "cook_torrance",
    "translate",
    "highlight_offsets",
    "log_l1_loss",
    "mse_loss",
    "rendering_loss",
    "LOG_EPS",
    "UNIT_ROUNDOFF",
    "render_rtol",
]

from kernels.loss import LOG_EPS

#: Unit roundoff u (half an ulp of 1: the largest relative error of one correctly rounded
#: operation) of the dtypes the kernels are built for.
UNIT_ROUNDOFF = {torch.float32: 2.0**-24, torch.float64: 2.0**-53}
#: Constants of the forward error model of ``render_rtol`` (derivation in its docstring):
#: RENDER_ERR_C1 / alpha counts the ulps that the GGX peak and the visibility term amplify,
#: RENDER_ERR_C0 the ulps of everything else on the path.
RENDER_ERR_C0 = 100.0
RENDER_ERR_C1 = 50.0


def render_rtol(dtype: torch.dtype, roughness_min: float) -> float:
    """Bound on ``max |render - exact| / max |exact|`` for ``render`` (``kernels.render``
    or this module's twin) evaluated in ``dtype`` on maps whose roughness, after the
    preset's floor clamp, is >= ``roughness_min``; "exact" is the same formula evaluated
    in exact arithmetic on the same inputs (in practice: in float64, whose own error is
    this bound with u = 2^-53, ~1e-9 of the float32 one).

    Returns ``u (RENDER_ERR_C0 + RENDER_ERR_C1 / alpha_min)``, alpha_min = roughness_min^2,
    u = ``UNIT_ROUNDOFF[dtype]``. Derivation (worst case per operation, first order in u):

    - directions: l and v (a difference of positions, three squares summed, a square
      root, a division) are each within ~4u of their exact direction, h = normalize(l + v)
      within ~8u, n within ~4u: the angle theta between n and h is within 12u.
    - GGX D = alpha^2 / (pi d^2), d = alpha^2 cos^2 + sin^2: d ln d / d theta =
      2 t (1 - alpha^2) / (alpha^2 + t^2) (t = tan theta) is at most 1 / alpha (at
      t = alpha), so |d ln D / d theta| <= 2 / alpha: 24u / alpha relative in D.
    - evaluating d (``kernels.brdf``'s docstring): each component of n x h within ~3u, so
      |n x h|^2 = s^2 within 2 sqrt(3) 3u s ~ 10.4 s u, against d >= 2 alpha s: 5.2u / alpha
      relative in d, 10.4u / alpha in D = 1 / d^2.
    - visibility: (n.l) / A, A = (n.l)(1 - k) + k, has derivative k / A^2 <= 2 / alpha in
      n.l, which is within ~4u: 8u / alpha on a factor at most ~1; 1 / B likewise in n.v:
      16u / alpha together. Sum of the four: ~50u / alpha = RENDER_ERR_C1 / alpha.
    - everything else relative to the value: the Fresnel weight 2^x, x in [-12.5, 0],
      x within |dx / d(v.h)| 4u + 3u |x| <= 18.1 * 4u + 37.5u ~ 110u, i.e. ln 2 * 110u ~
      76u relative; ~20 more products, quotients and sums on the path, ~1u each: 100u in
      all (RENDER_ERR_C0).

    Each term is relative to the element's value or to a factor at most ~1 of it, hence
    the bound against the largest value. Worst cases rarely align: measured float32
    errors against float64 are 10-80x below it (kernels/DESIGN.md). Examples (float32):
    1.4e-4 at roughness 0.15, 3.1e-4 at the 0.0993 floor.
    """
    alpha = roughness_min * roughness_min
    return UNIT_ROUNDOFF[dtype] * (RENDER_ERR_C0 + RENDER_ERR_C1 / alpha)


def _normalize(x: torch.Tensor, dim: int) -> torch.Tensor:
    return x / torch.sqrt((x * x).sum(dim, keepdim=True) + NORMALIZE_EPS)


def _positions(pos: torch.Tensor, batch: int, num: int | None = None) -> torch.Tensor:
    if pos.dim() == 1:
        pos = pos[None, None]
    elif pos.dim() == 2:
        pos = pos[None]
    return pos.expand(batch, pos.shape[1] if num is None else num, 3)


def plane_points(h: int, w: int, plane_size: float, *, dtype=torch.float32, device="cpu") -> torch.Tensor:
    """``[3, H, W]`` plane positions of the pixel centres (SPEC section 2; row 0 is +y)."""
    j = (torch.arange(w, dtype=dtype, device=device) + 0.5) / w - 0.5
    i = (torch.arange(h, dtype=dtype, device=device) + 0.5) / h - 0.5
    x = (j * plane_size)[None, :].expand(h, w)
    y = (-i * plane_size)[:, None].expand(h, w)
    return torch.stack([x, y, torch.zeros_like(x)])


def cook_torrance(n, l, v, rho_d, f0, rough, rough_floor: float) -> torch.Tensor:
    """BRDF times cosine (see ``kernels.brdf``); vectors on dim -3, broadcasting."""
    h = _normalize(l + v, -3)
    n_dot_l = (n * l).sum(-3, keepdim=True).clamp_min(0)
    n_dot_v = (n * v).sum(-3, keepdim=True).clamp_min(0)
    n_dot_h_raw = (n * h).sum(-3, keepdim=True)
    n_dot_h = n_dot_h_raw.clamp_min(0)
    v_dot_h = (v * h).sum(-3, keepdim=True).clamp_min(0)
    r = rough.clamp_min(rough_floor)
    alpha = r * r
    k = alpha * 0.5
    a2 = alpha * alpha
    # (n.h)^2 (a2 - 1) + 1 as a2 (n.h)^2 + |n x h|^2: no cancellation near the highlight
    # (kernels.brdf's docstring); 1 where n.h <= 0, the clamped form's value there.
    nxh = torch.linalg.cross(*torch.broadcast_tensors(n, h), dim=-3)
    sin2 = torch.where(n_dot_h_raw > 0, (nxh * nxh).sum(-3, keepdim=True), 1.0)
    d = a2 / (math.pi * (a2 * n_dot_h * n_dot_h + sin2) ** 2)
    fr = f0 + (1 - f0) * torch.exp2((FRESNEL_A * v_dot_h + FRESNEL_B) * v_dot_h)
    vis = 0.25 / ((n_dot_l * (1 - k) + k) * (n_dot_v * (1 - k) + k))
    return (rho_d * (1 - f0) / math.pi + fr * d * vis) * n_dot_l


def render(
    diffuse,
    normal,
    roughness,
    specular,
    light_pos,
    camera_pos,
    *,
    preset: str | RenderPreset = "dgrsise",
    return_lvh: bool = False,
    **overrides,
):
    """Reference for ``kernels.render``: ``[B, K, 3, H, W]`` linear radiance."""
    p = get_preset(preset).with_overrides(**overrides)
    b, _, h, w = diffuse.shape
    light = _positions(light_pos, b)
    camera = _positions(camera_pos, b, light.shape[1])
    x = plane_points(h, w, p.plane_size, dtype=diffuse.dtype, device=diffuse.device)  # [3, H, W]
    to_light = light[..., None, None] - x  # [B, K, 3, H, W]
    dist2 = (to_light * to_light).sum(2, keepdim=True) + NORMALIZE_EPS
    l = to_light / torch.sqrt(dist2)
    v = _normalize(camera[..., None, None] - x, 2)
    n = _normalize(normal, 1)[:, None]
    f = cook_torrance(n, l, v, diffuse[:, None], specular[:, None], roughness[:, None], p.roughness_floor)
    radiance = f * torch.tensor(p.intensity, dtype=diffuse.dtype, device=diffuse.device)[:, None, None]
    if p.inverse_square:
        radiance = radiance / dist2
    if return_lvh:
        return radiance, lvh_maps(light, camera, (h, w), preset=p)
    return radiance


def lvh_maps(light_pos, camera_pos, size, *, preset="dgrsise", plane_size=None) -> torch.Tensor:
    """Reference for ``kernels.lvh_maps``: ``[B, K, 9, H, W]`` unit l, v, h."""
    p = get_preset(preset).with_overrides(plane_size=plane_size)
    batch = light_pos.shape[0] if light_pos.dim() == 3 else 1
    light = _positions(light_pos, batch).detach()
    camera = _positions(camera_pos, batch, light.shape[1]).detach()
    h, w = size
    x = plane_points(h, w, p.plane_size, dtype=light.dtype, device=light.device)
    l = _normalize(light[..., None, None] - x, 2)
    v = _normalize(camera[..., None, None] - x, 2)
    return torch.cat([l, v, _normalize(l + v, 2)], dim=2)


def translate(features: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """Reference for ``kernels.translate``: ``out(i, j) = features(i - dy, j - dx)``,
    bilinear, coordinates clamped to the map (edge values repeat)."""
    b, c, h, w = features.shape
    dtype, device = features.dtype, features.device
    jj = torch.arange(w, dtype=dtype, device=device)[None, None, :]
    ii = torch.arange(h, dtype=dtype, device=device)[None, :, None]
    sx = (jj - offsets[:, 0, None, None]).clamp(0, w - 1).expand(b, h, w)
    sy = (ii - offsets[:, 1, None, None]).clamp(0, h - 1).expand(b, h, w)
    x0 = sx.detach().floor().long().clamp(max=w - 1)
    y0 = sy.detach().floor().long().clamp(max=h - 1)
    x1, y1 = (x0 + 1).clamp(max=w - 1), (y0 + 1).clamp(max=h - 1)
    fx, fy = (sx - x0.to(dtype))[:, None], (sy - y0.to(dtype))[:, None]
    flat = features.reshape(b, c, h * w)

    def gather(y, x):
        return flat.gather(2, (y * w + x).reshape(b, 1, h * w).expand(b, c, h * w)).reshape(b, c, h, w)

    top = (1 - fx) * gather(y0, x0) + fx * gather(y0, x1)
    bottom = (1 - fx) * gather(y1, x0) + fx * gather(y1, x1)
    return (1 - fy) * top + fy * bottom


def log_l1_loss(x: torch.Tensor, y: torch.Tensor, eps: float = LOG_EPS) -> torch.Tensor:
    """Reference for ``kernels.log_l1_loss``."""
    return (torch.log(x + eps) - torch.log(y.detach() + eps)).abs().mean()


def mse_loss(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Reference for ``kernels.mse_loss``."""
    return ((x - y.detach()) ** 2).mean()


def rendering_loss(
    diffuse,
    normal,
    roughness,
    specular,
    target,
    light_pos,
    camera_pos,
    *,
    preset="dgrsise",
    eps: float = LOG_EPS,
    **overrides,
) -> torch.Tensor:
    """Reference for ``kernels.rendering_loss``: render, then log-L1 against target."""
    images = render(diffuse, normal, roughness, specular, light_pos, camera_pos, preset=preset, **overrides)
    return log_l1_loss(images, target, eps)
