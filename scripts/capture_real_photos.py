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
#: ``materials.highlight.HIGHLIGHT_RADIUS``; the ring is close enough to see the same
#: texture, far enough to be outside a flash highlight of roughness <~0.4.
DISC, RING = 0.5, (0.75, 1.25)


def highlight_ratio(diffuse: torch.Tensor, frame, camera: torch.Tensor) -> float:
    """Mean luminance of ``diffuse [3, H, W]`` (photo grid) in the disc over the ring."""
    r = frame.photo_plane_distance((camera[0], camera[1]))
    lum = (diffuse * torch.tensor([0.2126, 0.7152, 0.0722])[:, None, None]).sum(0)
    return float(lum[r <= DISC].mean() / lum[(r >= RING[0]) & (r <= RING[1])].mean())


#: Ring width of ``flash_profile``, plane units (plane side 4): the refinement prior's
#: (``matcap.capture.priors.RADIAL_RINGS`` rings per side).
PROFILE_RING = 0.125
#: Added before the log in ``flash_profile`` (``matcap.capture.priors.RADIAL_LOG_EPS``).
PROFILE_EPS = 0.01


def flash_profile(x: torch.Tensor, frame, camera: torch.Tensor) -> float:
    """How much ``x [C, H, W]`` (a map on the photo grid, linear) depends on the distance
    from the point under the flash: the RMS over pixels of its rings' mean
    ``log(x + PROFILE_EPS)`` about the mean of all pixels, rings ``PROFILE_RING`` wide
    (hard bins, channels averaged first). 0 for a map whose rings all average the same;
    a disc or a ring centred on the flash (a baked highlight, the specular / roughness
    trade of a single flash view) raises it. In natural-log units (0.1: ~10%).

    Measured here with hard bins on the photo grid, independently of the soft-binned
    prior (``matcap.capture.priors.FlashRings``) the refinement may use."""
    ring = (frame.photo_plane_distance((camera[0], camera[1])) / PROFILE_RING).long().flatten()
    v = torch.log(x.double() + PROFILE_EPS).mean(0).flatten()
    n = torch.zeros(int(ring.max()) + 1, dtype=torch.float64).index_add(0, ring, torch.ones_like(v))
    sums = torch.zeros_like(n).index_add(0, ring, v)
    means = sums[n > 0] / n[n > 0]
    return math.sqrt(float((n[n > 0] * (means - v.mean()).square()).sum() / v.numel()))


#: Centre disc and outer region of ``edge_drop``, plane units (plane side 4, half-side 2):
#: the disc is ``DISC``; beyond ``EDGE`` lie the outer quarter of the half-side and the corners.
EDGE = 1.5


def edge_drop(diffuse: torch.Tensor, frame, camera: torch.Tensor) -> float:
    """How much darker ``diffuse [3, H, W]`` (photo grid, linear) is far from the point
    under the flash than near it: mean ``log(luminance + PROFILE_EPS)`` of the pixels
    beyond ``EDGE`` minus that of the disc ``DISC`` (natural-log units; 0 for a map with
    no brightness falloff, negative where the map has absorbed a flash beam's or a lens's
    falloff). Unlike ``flash_profile`` it is signed and looks only at the two ends."""
    h, w = diffuse.shape[-2:]
    rows, cols = torch.meshgrid(
        torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
    )
    x, y = frame.pixel_to_plane(rows, cols)
    r = torch.hypot(x - camera[0], y - camera[1])
    lum = (diffuse.double() * torch.tensor([0.2126, 0.7152, 0.0722], dtype=torch.float64)[:, None, None]).sum(0)
    log_lum = torch.log(lum + PROFILE_EPS)
    return float(log_lum[r >= EDGE].mean() - log_lum[r <= DISC].mean())


def low_tilt_deg(normal: torch.Tensor) -> float:
    """RMS angle, degrees, of the low-pass normal of ``normal [3, H, W]`` (unit, tangent
    space): ``atan(sqrt(tilt_energy))`` of its slopes (``matcap.capture.priors``), the
    four-quadrant tilt a refinement uses to move a flash highlight. ~0 for a flat sample."""
    from matcap.capture.priors import tilt_energy

    n = normal.float()[None]
    slope = n[:, :2] / n[:, 2:3].clamp_min(1e-3)
    side = slope.shape[-1] - slope.shape[-1] % 64 or slope.shape[-1]
    return math.degrees(math.atan(math.sqrt(float(tilt_energy(slope[..., :side, :side])))))


def crease_deg(normal: torch.Tensor, frame, camera: torch.Tensor) -> tuple[float, float]:
    """The refinement's creases through the flash point, as angles (degrees).

    ``normal [3, H, W]`` (photo grid). Per window of 4 columns, the change of the x slope
    ``n_x / n_z`` from its first column to its last, averaged along the window's rows
    (signed, so texture cancels and a crease, one sign along its whole length, stays).
    The same is done per window of 4 rows with the y slope. Returns the mean of the two
    for the windows centred on the point under the camera, and the median over the
    windows that do not overlap those (the texture's level): a crease stands far above
    the second number. NaN where the point is less than 2 pixels from the border.
    """
    n = normal.float()
    slope = n[:2] / n[2:3].clamp_min(1e-3)
    row, col = (float(v) for v in frame.plane_to_pixel(camera[0], camera[1]))
    # Window j spans columns j .. j + 3, centred at j + 1.5.
    across_cols = (slope[0, :, 3:] - slope[0, :, :-3]).mean(0).abs()
    across_rows = (slope[1, 3:, :] - slope[1, :-3, :]).mean(1).abs()
    j, i = round(col - 1.5), round(row - 1.5)
    if not (0 <= j < len(across_cols) and 0 <= i < len(across_rows)):
        return math.nan, math.nan
    at = (float(across_cols[j]) + float(across_rows[i])) / 2
    rest = torch.cat(
        [across_cols[: max(j - 3, 0)], across_cols[j + 4 :], across_rows[: max(i - 3, 0)], across_rows[i + 4 :]]
    )
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
        "--radial", type=float, default=None, help="refinement flash-independence weight (default: the pipeline's)"
    )
    parser.add_argument(
        "--radial-maps",
        default=None,
        help="maps the flash-independence prior looks at, comma-separated (default: the pipeline's)",
    )
    parser.add_argument(
        "--vignetting",
        choices=("off", "photo", "all"),
        default=None,
        help="which views the refinement's fitted radial gain multiplies (default: the pipeline's)",
    )
    parser.add_argument(
        "--shared-step-maps",
        default=None,
        help="maps whose refinement step is shared by their pixels, comma-separated or none (default: the pipeline's)",
    )
    parser.add_argument(
        "--relit-maps",
        default=None,
        help="maps the relit views' refinement loss may change, comma-separated (default: the pipeline's)",
    )
    parser.add_argument(
        "--relit-highlight",
        type=float,
        default=None,
        help="half-angle of the flash disc left out of the relit views' loss, degrees (default: the pipeline's)",
    )
    parser.add_argument(
        "--flash-point",
        choices=("centre", "auto"),
        default=None,
        help="camera over the photo's centre or over its located flash highlight (default: the pipeline's)",
    )
    parser.add_argument(
        "--measure-about",
        choices=("camera", "located"),
        default="camera",
        help="centre of the flash checks: the pipeline's camera, or the flash highlight located in the photo "
        "(matcap.capture.flash.locate_flash; the same point for every run, to compare runs with different cameras)",
    )
    parser.add_argument(
        "--measure-only",
        action="store_true",
        help="no capture and no picture: measure the folders an earlier run left in --work again",
    )
    args = parser.parse_args(argv)
    if args.measure_only:
        records = [remeasure(path, args.work, args.measure_about) for path in args.photos]
        _write_records(records, args.out)
        return 0

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
    if args.radial is not None:
        pipeline.config = replace(pipeline.config, radial=args.radial)
    if args.radial_maps is not None:
        pipeline.config = replace(pipeline.config, radial_maps=parse_map_names(args.radial_maps, "--radial-maps"))
    if args.vignetting is not None:
        pipeline.config = replace(pipeline.config, vignetting=args.vignetting)
    if args.shared_step_maps is not None:
        pipeline.config = replace(
            pipeline.config, shared_step_maps=parse_map_names(args.shared_step_maps, "--shared-step-maps")
        )
    if args.relit_maps is not None:
        pipeline.config = replace(
            pipeline.config, relit_maps=parse_map_names(args.relit_maps, "--relit-maps", allow_none=False)
        )
    if args.relit_highlight is not None:
        pipeline.config = replace(pipeline.config, relit_highlight=args.relit_highlight)
    if args.flash_point is not None:
        pipeline.config = replace(pipeline.config, flash_point=args.flash_point)
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
        runs = {"alone": (alone.material, alone.frame), "relit": (with_relit.material, with_relit.frame)}
        record = {
            "photo": f"{path.parent.name}/{path.name}",
            "size": list(photo.size),
            "seconds": round(seconds, 1),
            **measure(photo.image, runs, measure_point(photo.image, with_relit.frame, camera, args.measure_about)),
            "camera": [round(v, 3) for v in camera.tolist()],
            "measured_about": args.measure_about,
            "flatness": pipeline.config.flatness,
            "radial": pipeline.config.radial,
            "radial_maps": list(pipeline.config.radial_maps),
            "vignetting": pipeline.config.vignetting,
            "vignetting_fit": with_relit.provenance["refinement"]["vignetting"],
            "shared_step_maps": list(pipeline.config.shared_step_maps),
            "relit_maps": list(pipeline.config.relit_maps),
            "relit_highlight": pipeline.config.relit_highlight,
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
    _write_records(records, args.out)
    return 0


def measure(photo: torch.Tensor, runs: dict, camera: torch.Tensor) -> dict:
    """The checks of one photo: ``photo [3, H, W]`` linear; ``runs`` maps "alone" and
    "relit" to ``(Material with maps [C, H, W] on the photo grid, Frame)``."""
    record = {
        "highlight_ratio_alone": round(highlight_ratio(runs["alone"][0].diffuse, runs["alone"][1], camera), 3),
        "highlight_ratio_relit": round(highlight_ratio(runs["relit"][0].diffuse, runs["relit"][1], camera), 3),
        "highlight_ratio_photo": round(highlight_ratio(photo, runs["relit"][1], camera), 3),
        "tilt_deg_alone": round(low_tilt_deg(runs["alone"][0].normal), 2),
        "tilt_deg_relit": round(low_tilt_deg(runs["relit"][0].normal), 2),
    }
    for run, (material, frame) in runs.items():
        for name in ("diffuse", "roughness", "specular"):
            record[f"profile_{name}_{run}"] = round(flash_profile(getattr(material, name), frame, camera), 3)
        record[f"edge_drop_diffuse_{run}"] = round(edge_drop(material.diffuse, frame, camera), 3)
        at, elsewhere = crease_deg(material.normal, frame, camera)
        record[f"crease_deg_{run}"], record[f"crease_deg_{run}_elsewhere"] = round(at, 2), round(elsewhere, 2)
    return record


def measure_point(photo: torch.Tensor, frame, camera: torch.Tensor, about: str) -> torch.Tensor:
    """``[3]``: the centre of the checks, the pipeline's ``camera`` or (``about`` =
    "located") the plane point of ``locate_flash(photo)`` at the camera's height."""
    if about == "camera":
        return camera
    from matcap.capture.flash import locate_flash

    x, y = locate_flash(photo).plane_point(frame)
    return torch.tensor([x, y, float(camera[2])])


def remeasure(path: Path, work: Path, about: str = "camera") -> dict:
    """``measure`` on the folders an earlier run wrote for ``path`` under ``work``."""
    from materials.frame import Frame
    from materials.io import read_exr, read_photo
    from materials.types import Material

    def chw(file: Path) -> torch.Tensor:
        return torch.from_numpy(read_exr(file)).permute(2, 0, 1).float()

    runs, prov = {}, {}
    for run, folder in (("alone", work / f"{path.stem}_alone"), ("relit", work / path.stem)):
        prov[run] = json.loads((folder / "provenance.json").read_text())
        maps = {
            name: chw(folder / "material" / f"{name}.exr") for name in ("diffuse", "normal", "roughness", "specular")
        }
        runs[run] = (Material(**maps), Frame.from_dict(prov[run]["frame"]))
    settings = prov["relit"]["settings"]
    photo, camera = read_photo(path), torch.tensor(prov["relit"]["scene"]["camera_pos"])
    return {
        "photo": f"{path.parent.name}/{path.name}",
        "size": list(photo.size),
        "seconds": None,  # not timed again
        **measure(photo.image, runs, measure_point(photo.image, runs["relit"][1], camera, about)),
        "camera": prov["relit"]["scene"]["camera_pos"],
        "measured_about": about,
        "flatness": settings["flatness"],
        "radial": settings.get("radial", 0.0),
        "radial_maps": settings.get("radial_maps", []),
        "vignetting": settings.get("vignetting", "off"),
        "vignetting_fit": prov["relit"]["refinement"].get("vignetting"),
        "shared_step_maps": settings.get("shared_step_maps", []),
    }


def _write_records(records: list[dict], out: Path) -> None:
    """``capture_real_photos.json`` next to ``out``, and a table on stdout."""
    out.parent.mkdir(parents=True, exist_ok=True)
    (out.parent / "capture_real_photos.json").write_text(json.dumps(records, indent=2) + "\n")
    print(
        "| photo | size | s (7 relit) | diffuse disc/ring, photo alone | with 7 relit | photo itself "
        "| crease deg, alone | with 7 relit | elsewhere, with 7 relit |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in records:
        print(
            f"| {r['photo']} | {r['size'][1]}x{r['size'][0]} | {r['seconds']} | {r['highlight_ratio_alone']} | "
            f"{r['highlight_ratio_relit']} | {r['highlight_ratio_photo']} | {r['crease_deg_alone']} | "
            f"{r['crease_deg_relit']} | {r['crease_deg_relit_elsewhere']} |"
        )


if __name__ == "__main__":
    sys.exit(main())
