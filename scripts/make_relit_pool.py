"""Make a relit pool (``materials.relit_pool``): views 1.. of training groups relit by a
relighter from their flash photo, for fine-tuning the estimator on relighter outputs.

    python scripts/make_relit_pool.py --out $CKPT/relit_pool.safetensors --count 600

Items ``start .. start + count - 1`` of ``RenderedGroups(TRAIN_SEEDS, GroupConfig(size,
views, 2 * size, seed))``; the relighter sees view 0 (linear flash photo) and each item's
own lights and camera. The file is rewritten every ``--save-every`` items and a rerun with
the same arguments continues after the items it holds (a killed run loses little).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch
from tqdm import tqdm


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="pool file (.safetensors)")
    parser.add_argument("--count", type=int, default=600)
    parser.add_argument("--start", type=int, default=0, help="first item index of the stream")
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0, help="the stream's GroupConfig seed and the sampling seed")
    parser.add_argument("--relighter", default="diffusion")
    parser.add_argument("--steps", type=int, default=1, help="sampling steps of a sampling relighter")
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--save-every", type=int, default=64)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)

    from matcap.args import set_sampling
    from materials.dataset import TRAIN_SEEDS, GroupConfig, RenderedGroups
    from materials.relit_pool import read_relit_pool, write_relit_pool
    from relight.interface import get_relighter

    torch.set_num_threads(args.threads)
    config = GroupConfig(size=args.size, views=args.views, source_size=2 * args.size, seed=args.seed)
    groups = RenderedGroups(TRAIN_SEEDS, config)
    relighter = get_relighter(args.relighter)
    if getattr(relighter, "stochastic", False):
        set_sampling(relighter, args.relighter, args.steps)
    source = {
        "relighter": args.relighter,
        "steps": args.steps,
        "seed": args.seed,
        "script": "scripts/make_relit_pool.py",
    }
    index, relit = torch.arange(args.start, args.start + args.count), []
    if args.out.exists():
        done_index, done, old_config, old_source = read_relit_pool(args.out)
        if old_config != config or old_source != source or not torch.equal(done_index, index[: len(done_index)]):
            parser.error(f"{args.out} holds another pool; remove it or change --out")
        relit = list(done.float().unbind(0))
        print(f"continuing after {len(relit)} items of {args.out}", file=sys.stderr)
    start = time.perf_counter()
    with tqdm(total=args.count, initial=len(relit), desc="relit pool", unit="item") as bar:
        while len(relit) < args.count:
            chunk = index[len(relit) : len(relit) + args.batch].tolist()
            items = [groups[i] for i in chunk]
            photo = torch.stack([it["images"][0] for it in items])
            light_pos = torch.stack([it["light_pos"][1:] for it in items])
            camera_pos = torch.stack([it["camera_pos"][0] for it in items])
            g = torch.Generator().manual_seed(args.seed * 1_000_003 + chunk[0])
            with torch.no_grad():
                relit += list(relighter.relight(photo, light_pos, camera_pos, generator=g).unbind(0))
            bar.update(len(chunk))
            if len(relit) % args.save_every < args.batch or len(relit) == args.count:
                write_relit_pool(args.out, index[: len(relit)], torch.stack(relit), config, source)
    print(f"wrote {args.out}: {args.count} items, {time.perf_counter() - start:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
