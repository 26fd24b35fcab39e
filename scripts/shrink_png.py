"""Re-save result PNGs smaller before committing them (README, "Results and weights in git").

    .venv/bin/python scripts/shrink_png.py PNG [PNG ...] [--bits N]

Drops an alpha channel that is fully opaque (matplotlib writes RGBA), optionally rounds
every channel to ``--bits`` significant bits, and writes the file again with PNG's
``optimize`` flag, in place. ``--bits 8`` (the default) is lossless. ``--bits 5`` rounds
to multiples of 8 (largest change 4 of 255 levels, invisible on the result pictures here;
4 bits bands visibly in dark gradients) and is what the committed pictures above the
size budget were re-saved with. A file is rewritten only if the result is smaller.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image


def shrink(image: Image.Image, bits: int = 8) -> Image.Image:
    """Opaque RGBA -> RGB; each 8-bit channel rounded to the nearest multiple of ``2 ** (8 - bits)``."""
    if image.mode == "RGBA" and image.getextrema()[3] == (255, 255):
        image = image.convert("RGB")
    if bits >= 8:
        return image
    if image.mode not in ("RGB", "RGBA", "L"):
        raise ValueError(f"cannot round bits of a {image.mode} image")
    step = 1 << (8 - bits)
    values = np.asarray(image).astype(np.int32)
    rounded = np.clip((values + step // 2) // step * step, 0, 255).astype(np.uint8)
    return Image.fromarray(rounded)  # mode from the shape: [H, W] L, [H, W, 3] RGB, [H, W, 4] RGBA


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", nargs="+", type=Path, help="PNG files, rewritten in place")
    parser.add_argument("--bits", type=int, default=8, choices=range(1, 9), help="bits kept per channel (default 8)")
    args = parser.parse_args(argv)
    for path in args.paths:
        before = path.stat().st_size
        with Image.open(path) as image:
            image.load()  # shrink may return the image itself, which is saved after the file closes
            small = shrink(image, args.bits)
        # Written beside the target and renamed, so an interrupted run leaves the original.
        fd, tmp = tempfile.mkstemp(suffix=".png", dir=path.parent)
        os.close(fd)
        try:
            small.save(tmp, format="PNG", optimize=True)
            after = Path(tmp).stat().st_size
            if after < before:
                os.replace(tmp, path)
        finally:
            Path(tmp).unlink(missing_ok=True)
        print(f"{path}: {before / 1024:.0f} KB -> {min(before, after) / 1024:.0f} KB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
