"""Step 6, refinement at the photo's full resolution (``refine_full_resolution``): the
per-view targets and their masked, clip-aware log-L1 (``_Target``), the maps'
unconstrained parameters, the views rendered per call, and the memory estimate
(``refine_memory_bytes``).
"""

from __future__ import annotations

import math
from collections.abc import Collection
from typing import NamedTuple

import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

import kernels
from estimator.model import NORMAL_MIN_Z
from estimator.optim import MapAdam
from estimator.refine import DEFAULT_TOL, DEFAULT_WINDOW, LOGIT_EPS, converged
from kernels.loss import LOG_EPS
from matcap.capture.config import (
    DEFAULT_REFINE_STEPS,
    DEFAULT_RELIT_WEIGHT,
    DEFAULT_SHARED_STEP_MAPS,
    MAP_NAMES,
    REFINE_LR,
)
from matcap.capture.priors import FlashRings, flash_independence, plane_to_grid, tilt_energy
from matcap.capture.scene import area_downsample
from matcap.capture.vignetting import fit_vignetting, vignetting_basis, vignetting_gain
from materials.types import Material


class _Target:
    """One view's target, prepared once for the loss of every step (``loss``): the mean
    ``kernels.log_l1_loss`` over the pixels where ``mask`` ([h, w] bool) is True.

    ``ceiling``: the level at which ``y`` was clipped (a scalar or a tensor broadcasting to
    ``y``), or None. A pixel of ``y`` at its ceiling only says "at least this bright" (the
    flash highlight of an 8-bit photo, a relighter's output capped at 1), so there the
    render is compared as ``min(x, ceiling)``: a brighter render costs nothing.

    ``robust``: None, or the scale ``tau`` of a robust version of the same loss,
    ``tau * log(1 + r / tau)`` per element with ``r`` its log-L1 residual: equal to ``r``
    where ``r << tau`` and growing only logarithmically beyond, so pixels a view gets
    badly wrong (a relighter's dark disc where the flash was, a misplaced highlight)
    stop pulling the maps once the fit disagrees with them (a Cauchy / Lorentzian
    M-estimator on the L1 residual).
    """

    def __init__(
        self,
        y: torch.Tensor,
        mask: torch.Tensor,
        ceiling: torch.Tensor | float | None = None,
        robust: float | None = None,
    ):
        if robust is not None and not robust > 0:
            raise ValueError(f"robust scale must be positive, got {robust}")
        self.robust = robust
        self.mask = None if bool(mask.all()) else mask.to(y.dtype)
        self.scale = mask.numel() / int(mask.sum())  # mean over the masked pixels only
        self.y = y if self.mask is None else y * self.mask
        self.clipped, self.ceiling = None, None
        if ceiling is not None:
            ceiling = torch.as_tensor(ceiling, dtype=y.dtype)
            clipped = y >= ceiling - CLIP_TOL
            if bool(clipped.any()):
                self.clipped, self.ceiling = clipped, ceiling

    def loss(self, x: torch.Tensor) -> torch.Tensor:
        if self.clipped is not None:
            x = torch.where(self.clipped, torch.minimum(x, self.ceiling), x)
        if self.mask is not None:
            x = x * self.mask
        if self.robust is None:
            return kernels.log_l1_loss(x, self.y) * self.scale
        # torch, not the Warp loss: the robust weight needs the per-element residual (the
        # relit views are small: 64-256 px).
        r = (torch.log(x + LOG_EPS) - torch.log(self.y + LOG_EPS)).abs()
        return (self.robust * torch.log1p(r / self.robust)).mean() * self.scale


def _masked_log_l1(
    x: torch.Tensor, y: torch.Tensor, mask: torch.Tensor, ceiling: torch.Tensor | float | None = None
) -> torch.Tensor:
    """``_Target(y, mask, ceiling).loss(x)``."""
    return _Target(y, mask, ceiling).loss(x)


#: A target within this of its ceiling counts as clipped. Decoded 8-bit photos and the
#: relighters' capped outputs sit exactly at it; the next 8-bit code is 0.009 below 1.
CLIP_TOL = 1e-6


def _to_parameters(material: Material) -> list[torch.Tensor]:
    """Unconstrained per-pixel parameters of ``[1, C, S, S]`` maps, as in
    ``estimator.refine.refine_maps``: logits of diffuse, roughness, specular (clamped to
    ``[LOGIT_EPS, 1 - LOGIT_EPS]`` first), normals as slopes ``(n_x, n_y) / n_z``."""
    n = F.normalize(material.normal.detach().float(), dim=1)
    nz = n[:, 2:3].clamp_min(NORMAL_MIN_Z)

    def logit(t):
        return torch.logit(t.detach().float().clamp(LOGIT_EPS, 1 - LOGIT_EPS))

    return [
        logit(material.diffuse).requires_grad_(True),
        (n[:, :2] / nz).requires_grad_(True),
        logit(material.roughness).requires_grad_(True),
        logit(material.specular).requires_grad_(True),
    ]


def _from_parameters(p: list[torch.Tensor]) -> Material:
    slope = p[1]
    normal = F.normalize(torch.cat([slope, torch.ones_like(slope[:, :1])], dim=1), dim=1)
    return Material(torch.sigmoid(p[0]), normal, torch.sigmoid(p[2]), torch.sigmoid(p[3]))


#: Views rendered in one call of the refinement: as many as fit in this many bytes of
#: per-view buffers (render, Fresnel weights, output gradient, loss temporaries: about
#: 12 float32 channels a pixel). One call for several views costs less than one per view
#: (256 px, 8 views: 0.13 s against 0.29 s forward + backward on this CPU); 2048 px gets
#: 2 views a call.
CHUNK_BYTES = 512 * 1024 * 1024
_VIEW_CHANNELS = 12


def _view_chunks(views: list[int], side: int) -> list[list[int]]:
    per_view = 4 * _VIEW_CHANNELS * side * side
    n = max(1, CHUNK_BYTES // per_view)
    return [views[i : i + n] for i in range(0, len(views), n)]


#: Cap on a shared-step map's step per pixel, in units of the rate (``MapAdam``). The
#: largest normal-slope step of 100 was 5.7 rates on the real photo lgd/028, 5.2 on
#: lgd/038 and 6.9 on the built-in procedural photo, so the cap does not bind there; it
#: stops a pixel that holds most of a map's gradient (a glint, a mask edge) from stepping
#: by up to ``sqrt(H * W)`` rates at once.
MAX_SHARED_STEP = 10.0


class FullResolutionResult(NamedTuple):
    """``estimator.refine.RefineResult``'s fields, plus the fitted coefficients of the
    photo's radial gain (``matcap.capture.vignetting``; empty when not fitted)."""

    material: Material
    history: list[float]
    latent_steps: int
    vignetting: tuple[float, ...] = ()


def refine_memory_bytes(side: int, views: int) -> int:
    """Estimated peak bytes of ``refine_full_resolution`` at ``side x side`` (float32).

    Per pixel: the 10 map channels as parameters, their gradient, Adam's two moments and
    the best copy (5 x 10), the maps made from them and a detached copy with its gradient
    (3 x 10), the photo target and mask (4); plus, per view rendered in one call
    (``CHUNK_BYTES``), about 12 channels (render, Fresnel weights, masked products, their
    gradients). Compared with the peak RSS in ``benchmarks/bench_capture.py``.
    """
    per_view = 4 * _VIEW_CHANNELS * side * side
    in_flight = min(views, max(1, CHUNK_BYTES // per_view))
    return int(4 * side * side * (5 * 10 + 3 * 10 + 4) + in_flight * per_view)


def refine_full_resolution(
    material: Material,
    photo: torch.Tensor,
    photo_mask: torch.Tensor,
    relit: torch.Tensor,
    relit_mask: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    photo_weight: float = 1.0,
    relit_weight: float = DEFAULT_RELIT_WEIGHT,
    photo_ceiling: float | None = None,
    relit_ceiling: torch.Tensor | float | None = None,
    relit_robust: float | None = None,
    relit_maps: Collection[str] = MAP_NAMES,
    shared_step_maps: Collection[str] = DEFAULT_SHARED_STEP_MAPS,
    flatness: float = 0.0,
    radial: float = 0.0,
    radial_maps: Collection[str] = MAP_NAMES,
    vignetting: str = "off",
    steps: int = DEFAULT_REFINE_STEPS,
    lr: float = REFINE_LR,
    tol: float = DEFAULT_TOL,
    window: int = DEFAULT_WINDOW,
    render_kwargs: dict | None = None,
    progress: bool = False,
) -> FullResolutionResult:
    """Fit per-pixel maps at the photo's resolution to the photo and to lower-resolution
    relit views, through the Warp renderer.

    Loss: ``sum_v w_v L_v / sum_v w_v + flatness * tilt_energy + radial *
    flash_independence`` (``matcap.capture.priors``) with ``L_v`` the mean log-L1
    (``kernels.log_l1_loss``, Deschaintre et al. 2018) over the masked pixels: view 0 the
    maps rendered under the flash against ``photo`` at full resolution; view k >= 1
    rendered at full resolution under light k, area-downsampled to the relit size, against
    ``relit[k - 1]``. ``w_0 = photo_weight``, ``w_k = relit_weight``. The views are
    rendered and back-propagated one at a time (the maps' gradient accumulates), so the
    memory does not grow with K (``refine_memory_bytes``). Adam on the parameters of
    ``estimator.refine.refine_maps``, per pixel or with a step size shared by a map's
    pixels (``shared_step_maps``, ``estimator.optim.MapAdam``); early stop and best-of as
    in ``estimator.refine``.

    Args:
        material: initial maps ``[1, C, S, S]`` (e.g. the estimator's, upsampled).
        photo: ``[3, S, S]`` linear radiance; photo_mask: ``[S, S]`` bool (True: real pixel).
        relit: ``[K, 3, s, s]`` (K may be 0; S a multiple of s); relit_mask: ``[s, s]`` bool.
        light_pos: ``[1 + K, 3]`` (row 0 the flash); camera_pos: ``[3]``.
        photo_ceiling, relit_ceiling: where the photo / the relit views were clipped
            (``_masked_log_l1``): None (not clipped), a number, or for the relit views a
            tensor broadcasting to ``[K, 3, s, s]``.
        relit_robust: None (log-L1), or the scale of the robust loss of the relit views
            (``_Target``): generated views may be wrong in places, the photo is not.
        relit_maps: the maps the relit views' loss may change (``MAP_NAMES``, default
            all): the relit views' renders see the others as constants, so those are
            fitted to the photo alone.
        shared_step_maps: the maps (``MAP_NAMES``) whose Adam step size is shared by all
            their pixels, so that each pixel steps in proportion to its gradient; the
            others get per-pixel Adam (``torch.optim.Adam``'s update).
        flatness: weight of the flat-sample prior ``flatness * tilt_energy(slopes,
            photo_mask)`` added to the loss (0: none).
        radial: weight of the flash-independence prior ``radial *
            flash_independence(rings, maps)`` (0: none): the radial profile of
            ``radial_maps`` (``MAP_NAMES``) around the point under the flash (row 0 of
            ``light_pos``), over the real pixels.
        vignetting: fit a smooth darkening radial gain about the same point with the
            maps (``matcap.capture.vignetting``: a real flash's beam, a lens's
            vignetting), multiplying the render of the ``"photo"`` or of ``"all"`` views
            (``"off"``: none); it starts at ``fit_vignetting`` of the initial diffuse
            (whose smooth radial brightness is divided out), and its coefficients come
            back in the result.
        render_kwargs: ``kernels.render`` keywords (preset, falloff, intensity).

    Returns:
        ``FullResolutionResult(material [1, C, S, S], history, 0, vignetting)``.
    """
    render_kwargs = dict(render_kwargs or {"preset": "dgrsise"})
    k = relit.shape[0]
    side = photo.shape[-1]
    if material.diffuse.shape[0] != 1 or material.shape != (side, side) or photo.shape[-2] != side:
        raise ValueError(f"material {material.shape} and photo {tuple(photo.shape)} must be one [.., S, S] image")
    if light_pos.shape != (1 + k, 3):
        raise ValueError(f"light_pos must be [1 + K, 3] = [{1 + k}, 3], got {tuple(light_pos.shape)}")
    unknown = set(relit_maps) - set(MAP_NAMES)
    if unknown or not relit_maps:
        raise ValueError(f"relit_maps must be a non-empty subset of {', '.join(MAP_NAMES)}, got {sorted(relit_maps)}")
    unknown = set(shared_step_maps) - set(MAP_NAMES)
    if unknown:
        raise ValueError(f"shared_step_maps must be names of {', '.join(MAP_NAMES)}, got {sorted(shared_step_maps)}")
    unknown = set(radial_maps) - set(MAP_NAMES)
    if unknown:
        raise ValueError(f"radial_maps must be names of {', '.join(MAP_NAMES)}, got {sorted(radial_maps)}")
    for name, value in (("flatness", flatness), ("radial", radial)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {value}")
    # Which of the maps (in ``map_tensors`` order) the relit views' gradient reaches; None: all.
    routed = None if set(relit_maps) == set(MAP_NAMES) else tuple(name in relit_maps for name in MAP_NAMES)
    weights = [photo_weight] + [relit_weight] * k
    total = sum(weights)
    if not total > 0:
        raise ValueError("the view weights sum to 0")
    views = [v for v in range(1 + k) if weights[v] > 0]
    lights = light_pos.float()
    camera = camera_pos.float().reshape(1, 1, 3)
    relit_size = relit.shape[-1] if k else side

    # Per chunk of views rendered together: the photo's target (if view 0 is in it) and
    # one batched target for its relit views (they share one weight).
    plan = []
    for chunk in _view_chunks(views, side):
        rel = [v - 1 for v in chunk if v > 0]
        ceiling = relit_ceiling[rel] if isinstance(relit_ceiling, torch.Tensor) else relit_ceiling
        plan.append(
            (
                chunk,
                _Target(photo, photo_mask, photo_ceiling) if chunk[0] == 0 else None,
                _Target(relit[rel], relit_mask, ceiling, robust=relit_robust) if rel else None,
                len(rel) * relit_weight / total,
            )
        )

    def render(maps: tuple[torch.Tensor, ...], chunk: list[int]) -> torch.Tensor:
        return kernels.render(*maps, lights[chunk][None], camera, **render_kwargs)[0]  # [n, 3, S, S]

    def chunk_loss(maps: tuple[torch.Tensor, ...], step: tuple) -> torch.Tensor:
        chunk, photo_target, relit_target, relit_share = step
        n = int(photo_target is not None)  # the photo (view 0) leads its chunk
        if routed is None:  # one render call for the whole chunk (cheaper than two)
            images = render(maps, chunk)
            photo_images, relit_images = images[:n], images[n:]
        else:  # the relit views see the maps they may not change as constants
            fixed = tuple(m if free else m.detach() for m, free in zip(maps, routed))
            photo_images = render(maps, chunk[:n]) if n else None
            relit_images = render(fixed, chunk[n:]) if chunk[n:] else None
        loss = maps[0].new_zeros(())
        if photo_target is not None:
            photo_render = photo_images[0] if gain is None else photo_images[0] * vignetting_gain(gain, basis)
            loss = loss + photo_target.loss(photo_render) * (photo_weight / total)
        if relit_target is not None:
            if gain is not None and vignetting == "all":
                relit_images = relit_images * vignetting_gain(gain, basis)
            loss = loss + relit_target.loss(area_downsample(relit_images, relit_size)) * relit_share
        return loss

    plane = render_kwargs.get("plane_size") or kernels.get_preset(render_kwargs.get("preset", "dgrsise")).plane_size
    center = plane_to_grid(float(light_pos[0, 0]), float(light_pos[0, 1]), side, plane)
    gain, basis = None, None
    if vignetting not in ("off", "photo", "all"):
        raise ValueError(f"vignetting must be off, photo or all, got {vignetting!r}")
    if vignetting != "off" and photo_weight > 0:
        # Start from the initial diffuse's smooth radial brightness moved into the gain.
        basis = vignetting_basis(side, center)
        start = fit_vignetting(material.diffuse, basis, None if bool(photo_mask.all()) else photo_mask)
        diffuse = (material.diffuse / vignetting_gain(start, basis)).clamp(0, 1)
        material = Material(diffuse, material.normal, material.roughness, material.specular)
        gain = start.clone().requires_grad_(True)

    params = _to_parameters(material)
    # The real pixels, for the prior and the shared steps' mean (padding has no gradient
    # and would inflate the real pixels' steps): None when every pixel is real (a square
    # photo), which spares a full-resolution product per step.
    flat_mask = None if bool(photo_mask.all()) else photo_mask

    rings = FlashRings(side, center, flat_mask) if radial > 0 and radial_maps else None

    def prior_loss(maps: tuple[torch.Tensor, ...]) -> torch.Tensor | None:
        """The priors on ``maps`` (``_from_parameters(params).map_tensors()``, built once a
        step for the views' loss too: sigmoids and their backward at full resolution cost
        more than the rings)."""
        total = None
        if flatness > 0:
            total = flatness * tilt_energy(params[1], flat_mask)
        if rings is not None:
            named_maps = {"diffuse": maps[0], "normal": params[1], "roughness": maps[2], "specular": maps[3]}
            term = radial * flash_independence(rings, {n: named_maps[n] for n in MAP_NAMES if n in radial_maps})
            total = term if total is None else total + term
        return total

    named = list(zip(MAP_NAMES, params, strict=True))
    per_pixel = [p for name, p in named if name not in shared_step_maps]
    shared = [p for name, p in named if name in shared_step_maps]
    # fused: one kernel for the whole update (a per-tensor Python loop cost ~10% of a step
    # at 1024 px); MapAdam's loop only for the shared maps (the normals by default).
    opts: list[torch.optim.Optimizer] = []
    if per_pixel:
        opts.append(torch.optim.Adam(per_pixel, lr=lr, fused=True))
    if gain is not None:
        opts.append(torch.optim.Adam([gain], lr=lr))
    if shared:
        opts.append(MapAdam(shared, lr=lr, mask=flat_mask, max_step=MAX_SHARED_STEP))
    history: list[float] = []
    fitted = params if gain is None else [*params, gain]
    best, best_loss = [p.detach().clone() for p in fitted], float("inf")

    def loss_and_grad() -> float:
        maps = _from_parameters(params).map_tensors()
        leaves = tuple(t.detach().requires_grad_(True) for t in maps)
        value = 0.0
        for step in plan:
            loss = chunk_loss(leaves, step)
            loss.backward()  # one chunk's graph at a time; the leaves' .grad accumulates
            value += float(loss.detach())
        # A map no view's loss reached (routed away from the relit views, photo weight 0)
        # has no gradient to pass on.
        reached = [(m, t.grad) for m, t in zip(maps, leaves) if t.grad is not None]
        prior = prior_loss(maps)
        if prior is not None:  # one backward through the maps' construction for both
            reached.append((prior, torch.ones_like(prior)))
            value += float(prior.detach())
        torch.autograd.backward([m for m, _ in reached], [g for _, g in reached])
        return value

    with tqdm(total=steps, desc="refine (full resolution)", leave=False, disable=not progress) as bar:
        for _ in range(steps):
            for opt in opts:
                opt.zero_grad(set_to_none=True)
            value = loss_and_grad()
            if value < best_loss:  # the loss belongs to the parameters before this step
                best_loss, best = value, [p.detach().clone() for p in fitted]
            for opt in opts:
                opt.step()
            if gain is not None:
                with torch.no_grad():
                    gain.clamp_(max=0.0)  # a gain that only darkens (matcap.capture.vignetting)
            history.append(value)
            bar.update(1)
            bar.set_postfix(loss=f"{value:.5f}")
            if converged(history, window, tol):
                break
    with torch.no_grad():
        if steps:
            maps = _from_parameters(params).map_tensors()
            final = sum(float(chunk_loss(maps, step)) for step in plan)
            prior = prior_loss(maps)
            if prior is not None:
                final += float(prior)
            if final >= best_loss:
                for p, b in zip(fitted, best):
                    p.copy_(b)
        coefficients = () if gain is None else tuple(float(a) for a in gain)
        return FullResolutionResult(_from_parameters(params), history, 0, coefficients)
