"""Multi-image SVBRDF estimator (SPEC section 5; after Luo et al. 2024, paper section 6.2).

Data flow for a batch of B materials seen in V views (any V >= 1), shapes symbolic:

1. Inputs: ``images [B, V, 3, H, W]`` linear radiance; ``light_pos``, ``camera_pos [B, V, 3]``.
   Each view is encoded as ``(log(x + 0.01) + INPUT_SHIFT) * INPUT_SCALE`` (the log of the
   rendering loss, Deschaintre et al. 2018: flash highlights span four decades, the log
   keeps dark texture and the highlight on one scale) concatenated with its 9-channel
   l/v/h map (``kernels.lvh_maps``), so the encoder knows where each view was lit from.
2. Shared per-view encoder: levels of strided 3x3 convs (GroupNorm, SiLU) on the
   ``B * V`` views (default 16-32-64-128-192 channels over 5 levels, ``SVBRDFEstimator``'s arguments).
3. Cross-view correlation at every level, a DeepSets block: each view's features get a
   residual ``conv1x1([f_v, mean_v f, max_v f])``, so every view sees what the others
   see before the next level; then the views are pooled (``conv1x1([mean_v f, max_v f])``)
   into one skip feature per level. Mean and max are symmetric, so the output does not
   depend on the view order and any V works (V = 1: mean = max = the view). The reference
   uses a learned graph over per-view channels; see ``DESIGN.md`` for why not here.
4. Bottleneck ("latent") ``[B, C_L, H / 2^(L-1), W / 2^(L-1)]`` plus a global-context
   term (spatial mean -> linear, broadcast). Test-time refinement adds ``latent_offset``
   here (``estimator.refine``).
5. Shared U-Net decoder back to full resolution, then one small adapter head per map:
   diffuse (3, sigmoid), normal (3: x, y = tanh, z = sigmoid in [NORMAL_MIN_Z, 1], then
   normalised, so z > 0), roughness (1, sigmoid), specular (3, sigmoid).
6. Shading branch (``shading_channels`` > 0): a narrow full-resolution per-view path on
   the log image, its ratio to the views' mean (albedo cancels: what is left is shading)
   and the l/v/h map, with its own cross-view correlation and pooling. A zero-initialised
   head reads it with the decoder features and adds to the normal head's x, y logits:
   the trunk is trained to see through the lighting (for the diffuse map), the branch to
   read it (``DESIGN.md``, "Shading branch").
7. Generated-view flag (``generated_flag``): a view may be marked as made by a relighter
   rather than photographed (``generated [B, V]`` bool). A learned vector per encoder
   level, zero at initialisation, is added to the marked views' features before the
   cross-view correlation, so one model can learn how far to trust generated views
   without trusting real ones less (``DESIGN.md``, "Generated views").

Output: a batched ``materials.types.Material`` (maps ``[B, C, H, W]``, linear, float32).

Memory layout: activations are kept channels-last (NHWC strides, same shapes). On the CPU
oneDNN runs these narrow convs (12-48 channels) 2-4x faster in NHWC, and the view mean /
max are running sums over views (contiguous adds) rather than a reduction over a strided
dimension; whole 1024 px, 8 views: 31 s -> 21 s (``estimator/DESIGN.md``, "Resolution").
Without autograd (inference) SiLU runs in place, which saves one full-resolution
allocation per block, and GroupNorm is a per-channel affine from per-channel moments
(``_group_affine``), so the cross-view mix never builds its 3C-channel input: 1024 px,
8 views, 19.5 s -> 10.6 s (``estimator/DESIGN.md``, "Resolution").
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence

import torch
import torch.nn as nn
import torch.nn.functional as F
from diffusers.configuration_utils import ConfigMixin, register_to_config
from diffusers.models.modeling_utils import ModelMixin

import kernels
from kernels.checks import FLOATING_DTYPES, check_finite, check_same, check_shape
from materials.types import Material
from weights import StrictLoadingMixin

__all__ = ["SVBRDFEstimator", "check_views", "INPUT_SHIFT", "INPUT_SCALE", "NORMAL_MIN_Z"]

#: Input encoding ``(log(x + LOG_EPS) + INPUT_SHIFT) * INPUT_SCALE``: log(0.01) = -4.6 for
#: black, about -1 for mid-grey diffuse, up to ~8 in mirror highlights; the shift and scale
#: put the common range near [-2, 2] before the first conv (GroupNorm follows it).
INPUT_SHIFT = 1.0
INPUT_SCALE = 0.5
#: Smallest normal z before normalisation: with |x|, |y| <= 1 this allows tilts up to
#: atan(sqrt(2) / 0.05) ~ 88 degrees while keeping z strictly positive (SPEC: normals face out).
NORMAL_MIN_Z = 0.05
#: The view log-ratios ``log x_v - mean_v log x`` are ~0.05 for a few degrees of relief
#: under a side light; x4 brings them to the ~0.2 scale of the other inputs before the
#: first conv (GroupNorm follows it).
RATIO_SCALE = 4.0
#: Initial bias of the normal head's z logit: sigmoid(2) ~ 0.88 with x, y ~ 0, i.e. the
#: untrained model starts from flat normals rather than random tilts.
NORMAL_Z_BIAS = 2.0


def _groups(channels: int, wanted: int) -> int:
    return math.gcd(channels, wanted)


def _silu(x: torch.Tensor) -> torch.Tensor:
    """SiLU, in place when no graph is recorded (its backward needs the input)."""
    return F.silu(x, inplace=not torch.is_grad_enabled())


def _moments_path(x: torch.Tensor) -> bool:
    """Whether GroupNorm runs from per-channel moments (``_group_affine``): without a graph,
    in float32 / float64 (under bf16 autocast the moments would be rounded to bf16 and
    their difference, the variance, lost: torch's GroupNorm accumulates in float32)."""
    return not torch.is_grad_enabled() and x.dtype in (torch.float32, torch.float64)


def _view_mean_max(x: torch.Tensor, views: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and max over views: ``[B * V, C, h, w]`` -> two ``[B, C, h, w]``, in ``x``'s
    memory layout. A running sum and maximum over the V slices: each step reads two
    contiguous tensors, where ``mean(1)`` of the ``[B, V, ...]`` view of a channels-last
    tensor walks a strided dimension (5-25x slower on the CPU)."""
    xv = x.unflatten(0, (-1, views))
    if views > 1 and not torch.is_grad_enabled():
        # In place into two fresh buffers: no allocation (and page faults) per view.
        total, top = xv[:, 0] + xv[:, 1], torch.maximum(xv[:, 0], xv[:, 1])
        for i in range(2, views):
            total.add_(xv[:, i])
            torch.maximum(top, xv[:, i], out=top)
        return total.div_(views), top
    total, top = xv[:, 0], xv[:, 0]
    for i in range(1, views):
        total = total + xv[:, i]
        top = torch.maximum(top, xv[:, i])
    return total / views, top


def _cat_channels_last(parts: Sequence[torch.Tensor]) -> torch.Tensor:
    """``torch.cat(parts, dim=1)`` written straight into one channels-last buffer (each
    part ``[N, C_i, h, w]``, any layout, stride-0 repeats included; differentiable).

    ``torch.cat`` returns NCHW unless every part is channels-last, and converting that back
    is a second full-resolution copy (at 1024 px, 8 views, 48 channels: 1.6 GB)."""
    out = _channels_last_buffer(parts)
    at = 0
    for t in parts:
        out[:, at : at + t.shape[1]] = t
        at += t.shape[1]
    return out


def _channels_last_buffer(parts: Sequence[torch.Tensor]) -> torch.Tensor:
    """An uninitialised channels-last ``[N, sum C_i, h, w]`` for ``parts`` ``[N, C_i, h, w]``."""
    n, _, h, w = parts[0].shape
    width = sum(t.shape[1] for t in parts)
    strides = (width * h * w, 1, w * width, width)
    return torch.empty_strided((n, width, h, w), strides, dtype=parts[0].dtype, device=parts[0].device)


def _repeat_views(shared: torch.Tensor, views: int) -> torch.Tensor:
    """``[B, C, h, w]`` -> ``[B * V, C, h, w]``, each material's row repeated for its views."""
    return shared[:, None].expand(-1, views, -1, -1, -1).flatten(0, 1)


class ConvBlock(nn.Module):
    """3x3 conv (optionally stride 2) -> GroupNorm -> SiLU."""

    def __init__(self, cin: int, cout: int, groups: int, stride: int = 1):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, 3, stride=stride, padding=1)
        self.norm = nn.GroupNorm(_groups(cout, groups), cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.conv(x)
        if not _moments_path(y):
            return _silu(self.norm(y))
        # Without a graph: the GroupNorm as an affine from per-channel moments, in place
        # on the conv's output (torch's CPU GroupNorm was 3-6x slower at full resolution).
        scale, shift = _group_affine(self.norm, *_channel_moments(y))
        return F.silu(y.mul_(scale[..., None, None]).add_(shift[..., None, None]), inplace=True)


class CrossViewMix(nn.Module):
    """DeepSets correlation across views: ``f_v + conv1x1(SiLU(GN([f_v, mean f, max f])))``.

    Permutation-equivariant over views; ``x`` is ``[B * V, C, h, w]``.
    """

    def __init__(self, channels: int, groups: int):
        super().__init__()
        self.norm = nn.GroupNorm(_groups(3 * channels, groups), 3 * channels)
        self.proj = nn.Conv2d(3 * channels, channels, 1)

    def forward(self, x: torch.Tensor, views: int) -> torch.Tensor:
        if _moments_path(x):
            return self._forward_no_grad(x, views)
        mean, top = _view_mean_max(x, views)
        joint = _cat_channels_last([x, _repeat_views(mean, views), _repeat_views(top, views)])
        return x + self.proj(_silu(self.norm(joint)))

    def _forward_no_grad(self, x: torch.Tensor, views: int) -> torch.Tensor:
        """``forward`` without building ``[f_v, mean, max]``: the same numbers up to
        summation order, 3-5x less memory traffic at full resolution (``DESIGN.md``,
        "Resolution").

        GroupNorm's statistics of the joint tensor are those of its channels, and the
        channels of the view mean and max are the same for every view of a material. So
        the statistics come from per-channel moments (the 1 / V-sized mean and max at
        material batch size), the normalisation is one per-channel affine, and the 1x1
        projection splits by input channel: the views' own channels (and any mean / max
        channel whose group also holds view channels, so its affine differs per view) at
        ``B * V``, the rest once per material at ``B``, broadcast over its views.
        """
        n, c, h, w = x.shape
        b = n // views
        mean, top = _view_mean_max(x, views)
        shared = torch.cat([mean, top], dim=1)  # [B, 2C, h, w]
        m1x, m2x = _channel_moments(x)
        m1s, m2s = _channel_moments(shared)
        m1 = torch.cat([m1x, m1s.repeat_interleave(views, 0)], 1)  # [B * V, 3C]
        m2 = torch.cat([m2x, m2s.repeat_interleave(views, 0)], 1)
        scale, shift = _group_affine(self.norm, m1, m2)  # [B * V, 3C]
        weight = self.proj.weight[:, :, 0, 0]  # [C_out, 3C]

        def project(parts: list[torch.Tensor], cols: slice, rows: slice, bias=None) -> torch.Tensor:
            """SiLU(scale * [parts] + shift) of joint channels ``cols`` into one
            channels-last buffer, then their columns of the 1x1 projection (one conv: a
            2-channel one alone is slow in oneDNN); ``rows`` picks the affine's samples."""
            sc, sh = scale[rows, cols], shift[rows, cols]
            y = _channels_last_buffer(parts)
            at = 0
            for t in parts:
                k = slice(at, at + t.shape[1])
                torch.addcmul(sh[:, k, None, None], t, sc[:, k, None, None], out=y[:, k])
                at += t.shape[1]
            return F.conv2d(F.silu(y, inplace=True), weight[:, cols, None, None].contiguous(), bias)

        # Joint channels from c on whose group starts before c share an affine that
        # differs per view; the rest are the same for all views of a material.
        split = c + (-c % (3 * c // self.norm.num_groups))
        own = [x] + ([_repeat_views(shared[:, : split - c], views)] if split > c else [])
        out = project(own, slice(0, split), slice(None), self.proj.bias)
        if split < 3 * c:
            # Once per material, with its first view's affine (all its views agree).
            common = project([shared[:, split - c :]], slice(split, 3 * c), slice(None, None, views))
            out.unflatten(0, (b, views)).add_(common[:, None])
        return out.add_(x)


def _group_affine(norm: nn.GroupNorm, m1: torch.Tensor, m2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``norm`` as a per-channel affine ``x * scale + shift`` from the per-channel moments
    ``m1``, ``m2`` ``[N, C]`` (``_channel_moments``): GroupNorm's group mean and biased
    variance are the means of its channels' moments. Returns two ``[N, C]``."""
    n, c = m1.shape
    groups = norm.num_groups
    g1 = m1.view(n, groups, -1).mean(-1)
    var = (m2.view(n, groups, -1).mean(-1) - g1 * g1).clamp_min(0)
    per = c // groups
    scale = norm.weight[None] * torch.rsqrt(var + norm.eps).repeat_interleave(per, 1)
    return scale, norm.bias[None] - g1.repeat_interleave(per, 1) * scale


def _channel_moments(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-channel mean and mean square over the pixels: ``[N, C, h, w]`` -> two ``[N, C]``.

    On a channels-last tensor ``[N, h * w, C]`` is a free view; the mean square is the
    diagonal of its Gram matrix (one BLAS pass over the pixels, no squared copy)."""
    n, c, h, w = x.shape
    flat = x.permute(0, 2, 3, 1).reshape(n, h * w, c)
    m1 = flat.mean(1)
    m2 = torch.bmm(flat.transpose(1, 2), flat).diagonal(dim1=1, dim2=2) / (h * w)
    return m1, m2


class ViewPool(nn.Module):
    """Symmetric pooling over views: ``conv1x1([mean_v f, max_v f])`` -> ``[B, C, h, w]``."""

    def __init__(self, channels: int):
        super().__init__()
        self.proj = nn.Conv2d(2 * channels, channels, 1)

    def forward(self, x: torch.Tensor, views: int) -> torch.Tensor:
        return self.proj(torch.cat(_view_mean_max(x, views), dim=1))


class GlobalContext(nn.Module):
    """Adds a broadcast ``linear(spatial mean)``: lets every pixel see image-wide cues
    (e.g. an overall specular level), like the global track of Deschaintre et al. 2018."""

    def __init__(self, channels: int):
        super().__init__()
        self.linear = nn.Linear(channels, channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.linear(F.silu(x.mean((2, 3))))[..., None, None]


class ShadingBranch(nn.Module):
    """Full-resolution per-view shading features, pooled over views (module docstring, 6).

    ``[B * V, 3 + 3 + 9, H, W]`` (encoded log image, ``RATIO_SCALE`` x its log-ratio to the
    mean over views, l/v/h) -> two 3x3 blocks -> ``CrossViewMix`` -> one 3x3 block ->
    ``ViewPool`` -> ``[B, C_s, H, W]``. With V = 1 the ratio is zero: one view leaves only
    the image and its lighting geometry.
    """

    def __init__(self, channels: int, groups: int):
        super().__init__()
        self.encode = nn.Sequential(ConvBlock(3 + 3 + 9, channels, groups), ConvBlock(channels, channels, groups))
        self.mix = CrossViewMix(channels, groups)
        self.post = ConvBlock(channels, channels, groups)
        self.pool = ViewPool(channels)

    def forward(self, encoded: torch.Tensor, log_image: torch.Tensor, lvh: torch.Tensor) -> torch.Tensor:
        """``encoded``, ``log_image``: ``[B, V, 3, H, W]``; ``lvh``: ``[B, V, 9, H, W]``."""
        views = log_image.shape[1]
        ratio = (log_image - log_image.mean(1, keepdim=True)) * RATIO_SCALE
        x = self.encode(_cat_channels_last([encoded.flatten(0, 1), ratio.flatten(0, 1), lvh.flatten(0, 1)]))
        return self.pool(self.post(self.mix(x, views)), views)


class AdapterHead(nn.Module):
    """Per-map head: 3x3 conv -> GroupNorm -> SiLU -> 1x1 conv to the map's raw channels."""

    def __init__(self, cin: int, width: int, cout: int, groups: int):
        super().__init__()
        self.block = ConvBlock(cin, width, groups)
        self.out = nn.Conv2d(width, cout, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out(self.block(x))


def check_views(images, light_pos, camera_pos, *, multiple: int = 1) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Validate a multi-view batch; return (images, light_pos, camera_pos) with positions
    ``[B, V, 3]``.

    Args:
        images: ``[B, V, 3, H, W]`` linear radiance, any floating dtype, finite.
        light_pos, camera_pos: ``[B, V, 3]`` or ``[V, 3]`` (shared by the batch), finite.
        multiple: H and W must be multiples of it.
    Raises:
        TypeError: a non-tensor or non-float argument.
        ValueError: naming the argument, for a wrong shape (e.g. V differing from the
            images'), NaN or inf, another device.
    """
    dims = check_shape(images, "B V 3 H W", name="images", dtypes=FLOATING_DTYPES)
    b, h, w = dims["B"], dims["H"], dims["W"]
    if images.numel() == 0:
        raise ValueError(f"images must be non-empty, got shape {tuple(images.shape)}")
    if h % multiple or w % multiple:
        raise ValueError(f"images H and W must be multiples of {multiple}, got {h} x {w}")
    out = []
    for name, t in (("light_pos", light_pos), ("camera_pos", camera_pos)):
        check_shape(t, ("V 3", "B V 3"), name=name, dims=dims, dtypes=FLOATING_DTYPES)
        check_same("images", images, dtype=False, **{name: t})
        out.append(t[None].expand(b, *t.shape) if t.dim() == 2 else t)
    check_finite(images=images, light_pos=out[0], camera_pos=out[1])
    return images, out[0], out[1]


class SVBRDFEstimator(StrictLoadingMixin, ModelMixin, ConfigMixin):
    """N-view SVBRDF estimator: ``(images, light_pos, camera_pos) -> Material`` (module docstring).

    The arguments are the architecture (``estimator/DESIGN.md``), saved in a checkpoint's
    ``config.json``; ``from_pretrained`` is diffusers' and refuses a missing or unexpected
    key (``weights.StrictLoadingMixin``). An argument added after checkpoints were saved
    defaults to what those checkpoints were (``shading_channels=0``), so an older
    ``config.json`` without it loads as trained; a new training run passes
    ``estimator.config.TRAINING_DEFAULTS`` (``EstimatorConfig()`` holds them).

    Args:
        base_channels: channels of the full-resolution encoder level; level ``i`` has
            ``base_channels * channel_mults[i]``.
        channel_mults: one multiplier per encoder level; level 0 is full resolution and
            each further level halves H and W with a stride-2 conv. The default, 16-32-64-
            128-192 over 5 levels (1.9 M parameters, 7.7 MB of safetensors), was measured
            on the 2-core CPU: a 32-64-128-256 encoder over 4 levels costs 2-3x more per
            step at 64 x 64 for V = 8, almost all of it in the full-resolution per-view
            convs, while the cheap deep levels are where the parameters are.
        blocks_per_level: 3x3 conv blocks (GroupNorm, SiLU) after each level's entry conv.
        adapter_width: hidden channels of each per-map adapter head.
        norm_groups: GroupNorm groups (reduced to a divisor of the channel count).
        plane_size: side of the material plane used for the l/v/h maps (``dgrsise``: 4).
        shading_channels: width of the full-resolution shading branch that feeds the normal
            map (``estimator/DESIGN.md``, "Shading branch"); 0 leaves it out (the
            architecture before 2026-12-02, and of checkpoints saved without the field).
            The shipped model and new training runs use 16.
        generated_flag: learn one vector per encoder level added to the features of views
            marked generated (``forward``'s ``generated``); zero-initialised, so a model
            grown from one without it starts unchanged. False: ``generated`` is ignored
            (the architecture of checkpoints saved without the field).
    Raises:
        ValueError: naming the argument, for non-positive sizes, empty or non-positive
            ``channel_mults``, a negative ``shading_channels`` or one with a single level.

    Example:
        >>> import torch
        >>> from estimator import SVBRDFEstimator
        >>> model = SVBRDFEstimator(base_channels=8, channel_mults=(1, 2, 4), adapter_width=8, norm_groups=4)
        >>> images = torch.rand(2, 3, 3, 32, 32)        # B=2 materials, V=3 views, linear
        >>> light_pos = torch.tensor([[0., 0, 4], [2, 2, 5], [-2, 1, 6]]).expand(2, 3, 3)
        >>> camera_pos = torch.tensor([0., 0, 4]).expand(2, 3, 3)
        >>> model(images, light_pos, camera_pos).diffuse.shape
        torch.Size([2, 3, 32, 32])
    """

    @register_to_config
    def __init__(
        self,
        base_channels: int = 16,
        channel_mults: tuple[int, ...] = (1, 2, 4, 8, 12),
        blocks_per_level: int = 1,
        adapter_width: int = 32,
        norm_groups: int = 8,
        plane_size: float = 4.0,
        shading_channels: int = 0,
        generated_flag: bool = False,
    ):
        super().__init__()
        if base_channels < 1 or adapter_width < 1 or norm_groups < 1:
            raise ValueError(
                f"base_channels, adapter_width and norm_groups must be positive, got {base_channels}, "
                f"{adapter_width}, {norm_groups}"
            )
        if len(channel_mults) < 1 or any(int(m) < 1 for m in channel_mults):
            raise ValueError(f"channel_mults must be a non-empty tuple of positive ints, got {channel_mults}")
        if shading_channels < 0:
            raise ValueError(f"shading_channels must be >= 0, got {shading_channels}")
        if shading_channels and len(channel_mults) < 2:
            # The branch rides on the level-0 skip, which with one level is the latent.
            raise ValueError("shading_channels needs at least two levels (channel_mults)")
        if blocks_per_level < 0:
            raise ValueError(f"blocks_per_level must be >= 0, got {blocks_per_level}")
        if plane_size <= 0:
            raise ValueError(f"plane_size must be positive, got {plane_size}")
        widths = [base_channels * int(m) for m in channel_mults]
        g = norm_groups

        self.encoder = nn.ModuleList()
        self.mix = nn.ModuleList()
        self.pool = nn.ModuleList()
        cin = 3 + 9
        for i, c in enumerate(widths):
            layers = [ConvBlock(cin, c, g, stride=1 if i == 0 else 2)]
            layers += [ConvBlock(c, c, g) for _ in range(blocks_per_level)]
            self.encoder.append(nn.Sequential(*layers))
            self.mix.append(CrossViewMix(c, g))
            self.pool.append(ViewPool(c))
            cin = c
        self.context = GlobalContext(widths[-1])
        self.generated_embed = (
            nn.ParameterList([nn.Parameter(torch.zeros(c)) for c in widths]) if generated_flag else None
        )

        self.decoder = nn.ModuleList()
        for i in reversed(range(len(widths) - 1)):
            layers = [ConvBlock(widths[i + 1] + widths[i], widths[i], g)]
            layers += [ConvBlock(widths[i], widths[i], g) for _ in range(blocks_per_level)]
            self.decoder.append(nn.Sequential(*layers))

        self.heads = nn.ModuleDict(
            {
                "diffuse": AdapterHead(widths[0], adapter_width, 3, g),
                "normal": AdapterHead(widths[0], adapter_width, 3, g),
                "roughness": AdapterHead(widths[0], adapter_width, 1, g),
                "specular": AdapterHead(widths[0], adapter_width, 3, g),
            }
        )
        with torch.no_grad():
            self.heads["normal"].out.bias[2].fill_(NORMAL_Z_BIAS)
        self.shading = ShadingBranch(shading_channels, g) if shading_channels else None
        # Reads decoder + shading features, adds to the normal x, y logits; zero output at
        # initialisation, so a model grown from one without the branch starts unchanged.
        self.shading_head = AdapterHead(widths[0] + shading_channels, adapter_width, 2, g) if shading_channels else None
        if self.shading_head is not None:
            nn.init.zeros_(self.shading_head.out.weight)
            nn.init.zeros_(self.shading_head.out.bias)

    # ------------------------------------------------------------------ stages
    def encode(
        self,
        images: torch.Tensor,
        light_pos: torch.Tensor,
        camera_pos: torch.Tensor,
        generated: torch.Tensor | None = None,
    ) -> list[torch.Tensor]:
        """Per-view encoding, cross-view correlation and pooling.

        Args:
            images: ``[B, V, 3, H, W]`` linear radiance (negative values clamped to 0).
            light_pos, camera_pos: ``[B, V, 3]`` or ``[V, 3]`` positions (``dgrsise`` scene units).
            generated: ``[B, V]`` or ``[V]`` bool, True for views a relighter made (None:
                none); used only by a model built with ``generated_flag``.
        Returns:
            The pooled pyramid, one ``[B, C_i, H / 2^i, W / 2^i]`` per level; the last is
            the bottleneck latent (global context already added). With the shading branch,
            level 0 carries its ``C_s`` channels after the ``C_0`` skip channels
            (``decode`` passes them on to the heads).
        """
        images, light_pos, camera_pos = check_views(images, light_pos, camera_pos, multiple=self.downsample_factor)
        b, v, _, h, w = images.shape
        dtype = self.dtype
        lvh = kernels.lvh_maps(
            light_pos.detach().to(dtype).contiguous(),
            camera_pos.detach().to(dtype).contiguous(),
            (h, w),
            plane_size=self.config.plane_size,
        )
        log_image = torch.log(images.to(dtype).clamp_min(0) + kernels.LOG_EPS)
        encoded = (log_image + INPUT_SHIFT) * INPUT_SCALE
        lvh = lvh.to(encoded.device)
        x = _cat_channels_last([encoded.flatten(0, 1), lvh.flatten(0, 1)])
        flags = self._generated_flags(generated, b, v, x)
        pyramid = []
        for i, (enc, mix, pool) in enumerate(zip(self.encoder, self.mix, self.pool)):
            x = enc(x)
            if flags is not None:
                assert self.generated_embed is not None
                x = x + flags * self.generated_embed[i].to(x.dtype)[None, :, None, None]
            x = mix(x, v)
            pyramid.append(pool(x, v))
        pyramid[-1] = self.context(pyramid[-1])
        if self.shading is not None:
            pyramid[0] = torch.cat([pyramid[0], self.shading(encoded, log_image, lvh)], dim=1)
        return pyramid

    def _generated_flags(
        self, generated: torch.Tensor | None, b: int, v: int, like: torch.Tensor
    ) -> torch.Tensor | None:
        """``[B * V, 1, 1, 1]`` 0/1 of the views marked generated, in ``like``'s dtype and
        device; None when the model has no flag or no view is marked."""
        if generated is None or self.generated_embed is None:
            return None
        if not isinstance(generated, torch.Tensor) or generated.dtype != torch.bool:
            raise TypeError(
                f"generated must be a bool tensor, got {type(generated).__name__} {getattr(generated, 'dtype', '')}"
            )
        if generated.shape not in ((v,), (b, v)):
            raise ValueError(f"generated must be [V] or [B, V] = [{v}] or [{b}, {v}], got {list(generated.shape)}")
        if not bool(generated.any()):
            return None
        return generated.expand(b, v).reshape(b * v, 1, 1, 1).to(device=like.device, dtype=like.dtype)

    def decode(self, pyramid: Sequence[torch.Tensor], latent_offset: torch.Tensor | None = None) -> torch.Tensor:
        """Shared decoder: pyramid (+ ``latent_offset`` on the bottleneck, same shape as
        ``pyramid[-1]``) -> full-resolution features ``[B, C_0 (+ C_s), H, W]`` (the decoder's,
        then the shading branch's when there is one)."""
        x = pyramid[-1]
        skip0, c0 = pyramid[0], self._decoder_channels
        if self.shading is not None:
            pyramid = [skip0[:, :c0], *pyramid[1:]]
        if latent_offset is not None:
            if latent_offset.shape != x.shape:
                raise ValueError(f"latent_offset must have shape {tuple(x.shape)}, got {tuple(latent_offset.shape)}")
            x = x + latent_offset
        for block, skip in zip(self.decoder, reversed(pyramid[:-1])):
            x = F.interpolate(x, size=skip.shape[-2:], mode="nearest")
            x = block(torch.cat([x, skip], dim=1))
        return torch.cat([x, skip0[:, c0:]], dim=1) if self.shading is not None else x

    def predict_maps(self, features: torch.Tensor) -> Material:
        """Adapter heads: ``decode``'s features ``[B, C_0 (+ C_s), H, W]`` -> Material (maps
        in [0, 1], unit normals with z > 0)."""
        both, features = features, features[:, : self._decoder_channels]
        diffuse = torch.sigmoid(self.heads["diffuse"](features))
        raw = self.heads["normal"](features)
        if self.shading_head is not None:
            raw = torch.cat([raw[:, :2] + self.shading_head(both), raw[:, 2:]], dim=1)
        z = NORMAL_MIN_Z + (1 - NORMAL_MIN_Z) * torch.sigmoid(raw[:, 2:3])
        normal = F.normalize(torch.cat([torch.tanh(raw[:, :2]), z], dim=1), dim=1)
        roughness = torch.sigmoid(self.heads["roughness"](features))
        specular = torch.sigmoid(self.heads["specular"](features))
        return Material(diffuse, normal, roughness, specular)

    def forward(
        self,
        images: torch.Tensor,
        light_pos: torch.Tensor,
        camera_pos: torch.Tensor,
        *,
        latent_offset: torch.Tensor | None = None,
        generated: torch.Tensor | None = None,
    ) -> Material:
        """Estimate SVBRDF maps from V views (see ``encode`` for the argument shapes and
        ``generated``).

        Returns a Material with maps ``[B, C, H, W]``: diffuse, specular (linear RGB in
        [0, 1]), normal (unit, z > 0), roughness (in [0, 1]).
        """
        return self.predict_maps(self.decode(self.encode(images, light_pos, camera_pos, generated), latent_offset))

    @property
    def _decoder_channels(self) -> int:
        """C_0: the decoder's full-resolution channels (the shading branch's follow them)."""
        return self.config.base_channels * self.config.channel_mults[0]

    @property
    def downsample_factor(self) -> int:
        """H and W must be multiples of this (2 ** (levels - 1))."""
        return 2 ** (len(self.config.channel_mults) - 1)

    @property
    def arch(self):
        """The architecture as an ``estimator.config.EstimatorConfig`` (comparable, hashable)."""
        # Imported here: estimator.config reads this class's signature, so it imports this module.
        from estimator.config import EstimatorConfig

        return EstimatorConfig.from_saved(self.config)

    # ------------------------------------------------------------------ parameter groups
    def adapter_parameters(self) -> Iterator[nn.Parameter]:
        """Parameters of the per-map adapter heads, the shading head included (what
        refinement fine-tunes)."""
        yield from self.heads.parameters()
        if self.shading_head is not None:
            yield from self.shading_head.parameters()

    def latent_shape(self, batch: int, size: tuple[int, int]) -> tuple[int, int, int, int]:
        """Shape of the bottleneck latent for ``batch`` images of ``size`` (H, W)."""
        f = self.downsample_factor
        return (batch, self.config.base_channels * self.config.channel_mults[-1], size[0] // f, size[1] // f)
