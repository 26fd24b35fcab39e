"""Step 3, relighting: a relighter's native size (``native_resolution``) and one photo
relit to K lights, with the spread across samples (``relight_views``).
"""

from __future__ import annotations

import torch
from tqdm.auto import tqdm


def native_resolution(relighter) -> int | None:
    """The only image size a relighter accepts (the diffusion model's), or None."""
    model = getattr(getattr(relighter, "pipeline", None), "model", None)
    resolution = getattr(getattr(model, "config", None), "resolution", None)
    return int(resolution) if resolution is not None else None


def relight_views(
    relighter,
    photo: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    samples: int = 1,
    generator: torch.Generator | None = None,
    progress: bool = False,
    desc: str = "relight",
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Relight one photo to K lights, one light (and sample) per call, so a slow model
    shows progress; the generator carries on from call to call.

    Args:
        photo: ``[3, h, w]`` linear radiance at the relighter's size.
        light_pos: ``[K, 3]``; camera_pos: ``[3]``.
        samples: samples per light (>= 2 only for stochastic relighters).

    Returns:
        ``(relit [K, 3, h, w], std [K, 3, h, w] or None)``: the mean over samples and the
        per-pixel standard deviation across them (None for one sample).
    """
    total = len(light_pos) * samples
    outs = []
    with tqdm(total=total, desc=desc, unit="image", leave=False, disable=not progress) as bar:
        for _ in range(samples):
            row = []
            for k in range(len(light_pos)):
                out = relighter.relight(
                    photo=photo[None],
                    light_pos=light_pos[None, k : k + 1],
                    camera_pos=camera_pos[None],
                    generator=generator,
                )
                row.append(out[0, 0].float())
                bar.update(1)
            outs.append(torch.stack(row))
    stack = torch.stack(outs)  # [samples, K, 3, h, w]
    return stack.mean(0), (stack.std(0, unbiased=False) if samples >= 2 else None)
