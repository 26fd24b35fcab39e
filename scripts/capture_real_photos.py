"""Run real flash photos through the capture pipeline and make the README's picture.

For each photo: ``CapturePipeline`` with its defaults (7 relit views) and with the photo
alone (``relit=0``), both saved under ``--work`` (the folders ``relight capture`` writes).
The picture has one row per photo (``--figure``, the first ones): the photo, two relit
views, the diffuse map from the photo alone, the diffuse, normal, roughness and
specular maps from photo + relit views, and a re-render under a light off to the side.

The flash-highlight check, ``highlight_ratio``: the diffuse map's mean luminance in the
disc of radius 0.5 (plane units, side 4) around the point under the camera, divided by
its mean in the ring from 0.75 to 1.25 around it. The flash highlight sits in the disc;
a diffuse map that has the highlight baked in is brighter there (ratio above 1), a map
free of it is as bright as the ring (ratio near 1; texture moves it either way).

    python scripts/capture_real_photos.py ../shared/data/real-dev/photos/*/*.png \\
        --work runs/capture_real --figure 2 --out results/capture_real_photos/capture_real_photos.png

Prints a table and writes ``capture_real_photos.json`` next to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "results" / "capture_real_photos" / "capture_real_photos.png"
#: Tile side of the picture, pixels.
TILE = 128
#: Disc and ring of ``highlight_ratio``, plane units (plane side 4): the disc is
#: ``estimator.evaluate.HIGHLIGHT_RADIUS``; the ring is close enough to see the same
#: texture, far enough to be outside a flash highlight of roughness <~0.4.
DISC, RING = 0.5, (0.75, 1.25)


def highlight_ratio(diffuse: torch.Tensor, frame, camera: torch.Tensor) -> float:
    """Mean luminance of ``diffuse [3, H, W]`` (photo grid) in the disc over the ring."""
    h, w = diffuse.shape[-2:]
    rows, cols = torch.meshgrid(
        torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
    )
    x, y = frame.pixel_to_plane(rows, cols)
    r = torch.hypot(x - camera[0], y - camera[1])
    lum = (diffuse * torch.tensor([0.2126, 0.7152, 0.0722])[:, None, None]).sum(0)
    return float(lum[r <= DISC].mean() / lum[(r >= RING[0]) & (r <= RING[1])].mean())


def low_tilt_deg(normal: torch.Tensor) -> float:
    """RMS angle, degrees, of the low-pass normal of ``normal [3, H, W]`` (unit, tangent
    space): ``atan(sqrt(tilt_energy))`` of its slopes (``matcap.capture.refine``), the
    four-quadrant tilt a refinement uses to move a flash highlight. ~0 for a flat sample."""
    from matcap.capture.refine import tilt_energy

    n = normal.float()[None]
    slope = n[:, :2] / n[:, 2:3].clamp_min(1e-3)
    side = slope.shape[-1] - slope.shape[-1] % 64 or slope.shape[-1]
    return math.degrees(math.atan(math.sqrt(float(tilt_energy(slope[..., :side, :side])))))


def crease_deg(normal: torch.Tensor, frame, camera: torch.Tensor) -> tuple[float, float]:
    """The refinement's creases through the flash point, as angles (degrees).

    ``normal [3, H, W]`` (photo grid). Per column ``c``, the change of the x slope
    ``n_x / n_z`` across the 3 columns around ``c``, averaged along the column (signed, so
    texture cancels and a crease, one sign along its whole length, stays). The same is
    done per row with the y slope. Returns the mean of the two at the point under the
    camera, and the median of the same over every other column and row (the texture's
    level): a crease stands far above the second number.
    """
    n = normal.float()
    slope = n[:2] / n[2:3].clamp_min(1e-3)
    h, w = slope.shape[-2:]
    rows, cols = torch.meshgrid(
        torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
    )
    x, y = frame.pixel_to_plane(rows, cols)
    col = int((x[h // 2] - camera[0]).abs().argmin())
    row = int((y[:, w // 2] - camera[1]).abs().argmin())
    across_cols = (slope[0, :, 3:] - slope[0, :, :-3]).mean(0).abs()  # at columns 1.5 ... w - 1.5
    across_rows = (slope[1, 3:, :] - slope[1, :-3, :]).mean(1).abs()
    at = (float(across_cols[col - 2]) + float(across_rows[row - 2])) / 2
    rest = torch.cat([across_cols[: col - 4], across_cols[col:], across_rows[: row - 4], across_rows[row:]])
    return math.degrees(math.atan(at)), math.degrees(math.atan(float(rest.median())))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("photos", nargs="+", type=Path)
    parser.add_argument("--work", type=Path, required=True, help="folder for the capture outputs")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="the picture (PNG)")
    parser.add_argument("--figure", type=int, default=2, help="photos (rows) in the picture")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--estimator", type=Path, default=None, help="estimator folder (default: the pipeline's)")
    parser.add_argument(
        "--flatness", type=float, default=None, help="refinement flatness weight (default: the pipeline's)"
    )
    parser.add_argument(
        "--shared-step-maps",
        default=None,
        help="maps whose refinement step is shared by their pixels, comma-separated or none (default: the pipeline's)",
    )
    args = parser.parse_args(argv)

    import kernels
    from kernels.tonemap import srgb_encode
    from matcap.args import parse_map_names
    from matcap.capture import CapturePipeline
    from matcap.outputs import contact_sheet
    from materials.io import read_photo, write_png
    from materials.io.encoding import chw_to_hwc, encode_normal

    torch.set_num_threads(args.threads)
    pipeline = CapturePipeline.from_pretrained(estimator=args.estimator)
    if args.flatness is not None:
        pipeline.config = replace(pipeline.config, flatness=args.flatness)
    if args.shared_step_maps is not None:
        pipeline.config = replace(
            pipeline.config, shared_step_maps=parse_map_names(args.shared_step_maps, "--shared-step-maps")
        )
    rows, records = [], []
    side_light = torch.tensor([[3.0, 1.0, 4.0]])

    def tile(x: torch.Tensor) -> torch.Tensor:
        x = x.float()
        if x.shape[0] == 1:
            x = x.expand(3, -1, -1)
        return torch.nn.functional.interpolate(x[None], size=(TILE, TILE), mode="area")[0].clamp(0, 1)

    for path in args.photos:
        photo = read_photo(path)
        start = time.perf_counter()
        with_relit = pipeline(photo)
        seconds = time.perf_counter() - start
        alone = pipeline(photo, config=replace(pipeline.config, relit=0))
        name = path.stem
        with_relit.save(args.work / name, overwrite=True)
        alone.save(args.work / f"{name}_alone", overwrite=True)
        camera = with_relit.scene.camera_pos
        record = {
            "photo": f"{path.parent.name}/{path.name}",
            "size": list(photo.size),
            "seconds": round(seconds, 1),
            "highlight_ratio_alone": round(highlight_ratio(alone.material.diffuse, alone.frame, camera), 3),
            "highlight_ratio_relit": round(highlight_ratio(with_relit.material.diffuse, with_relit.frame, camera), 3),
            "highlight_ratio_photo": round(highlight_ratio(photo.image, with_relit.frame, camera), 3),
            "tilt_deg_alone": round(low_tilt_deg(alone.material.normal), 2),
            "tilt_deg_relit": round(low_tilt_deg(with_relit.material.normal), 2),
            **{
                f"crease_deg_{run}{part}": round(v, 2)
                for run, out in (("alone", alone), ("relit", with_relit))
                for part, v in zip(("", "_elsewhere"), crease_deg(out.material.normal, out.frame, camera))
            },
            "flatness": pipeline.config.flatness,
            "shared_step_maps": list(pipeline.config.shared_step_maps),
        }
        records.append(record)
        print(json.dumps(record), file=sys.stderr, flush=True)
        if len(rows) < args.figure:
            m = with_relit.material
            render = kernels.render(
                *(t[None] for t in m.map_tensors()), side_light[None], camera, **with_relit.scene.render_kwargs
            )
            rows.append(
                torch.stack(
                    [
                        tile(kernels.tonemap(photo.image)),
                        tile(kernels.tonemap(with_relit.relit[0])),
                        tile(kernels.tonemap(with_relit.relit[5])),
                        tile(srgb_encode(alone.material.diffuse)),
                        tile(srgb_encode(m.diffuse)),
                        tile(encode_normal(m.normal)),
                        tile(m.roughness),
                        tile(srgb_encode(m.specular)),
                        tile(kernels.tonemap(render[0, 0])),
                    ]
                )
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_png(args.out, chw_to_hwc(contact_sheet(torch.cat(rows), columns=rows[0].shape[0])))
    (args.out.parent / "capture_real_photos.json").write_text(json.dumps(records, indent=2) + "\n")
    print(
        "| photo | size | s (7 relit) | diffuse disc/ring, photo alone | with 7 relit | photo itself "
        "| crease deg, alone | with 7 relit | elsewhere |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in records:
        print(
            f"| {r['photo']} | {r['size'][1]}x{r['size'][0]} | {r['seconds']} | {r['highlight_ratio_alone']} | "
            f"{r['highlight_ratio_relit']} | {r['highlight_ratio_photo']} | {r['crease_deg_alone']} | "
            f"{r['crease_deg_relit']} | {r['crease_deg_relit_elsewhere']} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
