"""``matcap.capture.CapturePipeline`` and ``relight capture``: the steps end to end with a
tiny random estimator and the analytic relighters (fast), one run with the shipped
diffusion relighter, the round trip through the written capture folder, mapping back to
the photo's pixels, EXIF orientation, ``--relit 0`` against the steps called by hand,
bad input, and the glTF export re-read."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import OpenEXR
import pytest
import torch
from PIL import ExifTags, Image

import kernels
from estimator.config import TINY_TEST_CONFIG
from estimator.model import SVBRDFEstimator
from matcap.capture import (
    DEFAULT_FLATNESS,
    DEFAULT_SHARED_STEP_MAPS,
    MAP_NAMES,
    MAX_SIDE,
    PROVENANCE_JSON,
    WORKING_SIZE,
    CaptureConfig,
    CapturePipeline,
    area_downsample,
    builtin_photo,
    falloff_factor,
    flash_disc,
    refine_full_resolution,
    refine_memory_bytes,
)
from matcap.capture.priors import plane_to_grid
from matcap.cli import main
from materials.frame import prepare_photo
from materials.io import read_capture, read_exr, read_glb, write_png
from materials.io.gltf import SPECULAR_EXTENSION
from materials.lights import EVAL_LIGHTS
from materials.types import Material
from relight.interface import Relighter, get_relighter

#: 8-bit capture PNGs: half a code step in display space, y = x^(1/2.2), is at most
#: 2.2 * 0.5 / 255 = 0.0043 in linear radiance for values in [0, 1] (dx/dy = 2.2 y^1.2 <= 2.2).
PNG_LINEAR_TOL = 2.2 * 0.5 / 255 + 1e-6
#: float32 round-off of the same computation done twice in a different order (the
#: pipeline vs the steps by hand): renders and sums of ~1e4 terms, relative ~1e-6.
SAME_MATH_TOL = 1e-5
#: ``tilt_energy`` of bumps (slopes up to 0.4) with an 8 px period at 128 px: a whole
#: Gaussian (sigma 4 cells of 2 px) would scale such a sine by exp(-2 pi^2 sigma^2 / P^2)
#: ~ 3e-9, but its taps stop at 3 sigma, and the cut-off mass (0.0027) bounds what passes:
#: (0.4 * 0.0027)^2 ~ 1.2e-6, a 0.06 degree tilt, far below the 0.04 of a constant slope 0.2.
FLAT_BUMPS_TOL = (0.4 * 0.0027) ** 2


@pytest.fixture(scope="module")
def tiny_estimator():
    torch.manual_seed(0)
    return SVBRDFEstimator(**TINY_TEST_CONFIG.to_dict()).eval()


@pytest.fixture(scope="module")
def estimator_folder(tmp_path_factory, tiny_estimator):
    folder = tmp_path_factory.mktemp("est") / "tiny"
    tiny_estimator.save_pretrained(folder)
    return folder


def smooth_photo(h: int, w: int, seed: int = 0) -> torch.Tensor:
    """``[3, h, w]`` linear radiance in (0.05, 0.6): smooth random colour blobs."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(1, 3, 4, 4, generator=g)
    return 0.05 + 0.55 * torch.nn.functional.interpolate(coarse, size=(h, w), mode="bilinear")[0]


def pipeline(estimator, relighter="lambertian", **config) -> CapturePipeline:
    config.setdefault("refine_steps", 3)
    return CapturePipeline(get_relighter(relighter) if relighter else None, estimator, config=CaptureConfig(**config))


# ---------------------------------------------------------------------- the steps
def test_pipeline_end_to_end_on_a_non_square_photo(tiny_estimator, tmp_path):
    photo = smooth_photo(100, 70)
    out = pipeline(tiny_estimator)(photo)
    k = len(EVAL_LIGHTS)
    # Maps, re-renders and their channels on the photo's grid; the relit views and the
    # estimator on the whole padded 128 px square (below the default relit and estimate
    # sizes, 256).
    assert out.material.shape == (100, 70) and out.material.diffuse.shape == (3, 100, 70)
    assert out.renders.shape == (1 + k, 3, 100, 70) and bool(torch.isfinite(out.renders).all())
    assert out.relit.shape == (k, 3, 2 * WORKING_SIZE, 2 * WORKING_SIZE) and out.estimate.shape == (128, 128)
    assert out.capture.num_views == 1 + k and out.capture.shape == (128, 128)
    assert torch.equal(out.capture.light_pos[0], out.capture.camera_pos[0])  # view 0: the flash
    assert out.frame.size == (128, 128) and out.frame.photo_size == (100, 70)
    assert out.confidence is None  # one sample
    assert len(out.refine_history) == 3
    out.material.validate()
    prov = out.provenance
    assert list(prov["timings_s"]) == [
        "1 check inputs",
        "2 prepare photo",
        "3 relight",
        "4 capture",
        "5 estimate",
        "6 refine",
        "7 maps to photo",
        "8 re-render",
    ]
    assert prov["frame"]["photo_size"] == [100, 70] and prov["photo"]["size"] == [100, 70]
    assert prov["settings"]["relit"] == k and prov["versions"]["dgrsise"]
    assert len(prov["weights"]["estimator"]["config_sha256"]) == 64
    json.dumps(prov)  # serialisable
    # The folder: everything there, atomically, and marked.
    out.save(tmp_path / "o")
    names = {p.name for p in (tmp_path / "o").iterdir()}
    assert names == {"material", "renders", "relit", "capture", "preview.png", PROVENANCE_JSON}
    assert read_exr(tmp_path / "o" / "material" / "diffuse.exr").shape == (100, 70, 3)
    assert len(list((tmp_path / "o" / "renders").glob("view_*.exr"))) == 1 + k


def test_refinement_decreases_the_loss_and_masks_the_padding(tiny_estimator):
    photo = smooth_photo(64, 40)
    image, frame = prepare_photo(photo, multiple=64)
    mask = frame.valid_mask()
    camera = torch.tensor([0.0, 0.0, 4.0])
    init = tiny_estimator(area_downsample(image, 64)[None, None], camera[None, None], camera[None, None])
    garbage = image.clone()
    garbage[:, ~mask] = 1e3  # whatever the padding holds must not matter
    runs = [
        refine_full_resolution(init, target, mask, torch.zeros(0, 3, 64, 64), mask, camera[None], camera, steps=10)
        for target in (image, garbage)
    ]
    assert runs[0].history[-1] < runs[0].history[0]
    assert runs[0].history == pytest.approx(runs[1].history, rel=SAME_MATH_TOL)


def test_relit_views_are_compared_at_their_resolution(tiny_estimator):
    # A relit view the maps reproduce exactly (the render area-downsampled) has zero loss:
    # the comparison is at the relit size, after rendering at full resolution.
    photo = smooth_photo(128, 128)
    camera = torch.tensor([0.0, 0.0, 4.83])
    init = tiny_estimator(area_downsample(photo, 64)[None, None], camera[None, None], camera[None, None])
    init = init.__class__(*(torch.nn.functional.interpolate(t, size=(128, 128)) for t in init.map_tensors()))
    light = torch.tensor([[2.0, 2.0, 4.0]])
    rendered = kernels.render(*init.map_tensors(), light[None], camera)[0]
    relit = area_downsample(rendered, 64)
    mask = torch.ones(128, 128, dtype=torch.bool)
    small_mask = torch.ones(64, 64, dtype=torch.bool)
    lights = torch.cat([camera[None], light])
    result = refine_full_resolution(
        init, photo, mask, relit, small_mask, lights, camera, photo_weight=0.0, relit_weight=1.0, steps=1
    )
    assert result.history[0] < 1e-6


def _flat_material(side: int, diffuse: float = 0.4, roughness: float = 0.5) -> Material:
    return Material(
        torch.full((1, 3, side, side), diffuse),
        torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, side, side).clone(),
        torch.full((1, 1, side, side), roughness),
        torch.full((1, 3, side, side), 0.04),
    )


#: Crease test: the change of the normals' x slope across the 3 columns at the flash
#: point, over the slope's largest magnitude. A sign field (per-pixel Adam's steps) jumps
#: by twice its amplitude there (1.77 measured); a field that follows the smooth radial
#: gradient of this glare changes by less than its amplitude (0.83 measured).
CREASE_RATIO_MAX = 1.2


def test_shared_normal_steps_leave_no_crease_through_the_flash():
    # A flat material and a photo with a broad glare at the flash point the renderer has
    # no term for: the fit keeps pulling the normals radially. Per-pixel Adam turns that
    # pull into sign(x) steps, a vertical crease through the flash point (real photos,
    # README "Capture a material"); a shared step size keeps the field smooth.
    side = 64
    camera = torch.tensor([0.0, 0.0, 4.0])
    truth = _flat_material(side, diffuse=0.3, roughness=0.3)
    photo = kernels.render(*truth.map_tensors(), camera[None, None], camera)[0, 0]
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, side), torch.linspace(-1, 1, side), indexing="ij")
    photo = photo * (1 + 0.8 * torch.exp(-(xx**2 + yy**2) / 0.1))
    mask = torch.ones(side, side, dtype=torch.bool)

    def crease_ratio(shared: tuple[str, ...]) -> float:
        refined = refine_full_resolution(
            truth, photo, mask, torch.zeros(0, 3, side, side), mask, camera[None], camera, steps=60,
            shared_step_maps=shared,
        ).material  # fmt: skip
        slope_x = refined.normal[0, 0]
        c = side // 2
        return float((slope_x[:, c + 1] - slope_x[:, c - 2]).abs().max() / slope_x.abs().max())

    assert crease_ratio(DEFAULT_SHARED_STEP_MAPS) < CREASE_RATIO_MAX
    assert crease_ratio(()) > CREASE_RATIO_MAX  # the measure sees the crease it guards against
    with pytest.raises(ValueError, match="shared_step_maps must be names"):
        crease_ratio(("albedo",))


def test_relit_views_change_only_the_maps_routed_to_them():
    # Relit views of a darker, glossier material, the photo weighted 0: with the relit
    # views routed to roughness only, every other map stays exactly where it started
    # (steps=0 gives the start after the parameters' round trip) while roughness moves;
    # unrouted, the diffuse map moves too.
    side = 64
    camera = torch.tensor([0.0, 0.0, 4.83])
    lights = torch.tensor([[0.0, 0.0, 4.83], [2.0, -1.0, 4.0], [-2.0, 1.0, 5.0]])
    truth = _flat_material(side, diffuse=0.2, roughness=0.2)
    relit = kernels.render(*truth.map_tensors(), lights[1:][None], camera)[0]
    init = _flat_material(side)
    mask = torch.ones(side, side, dtype=torch.bool)

    def refine(steps: int, maps=("diffuse", "normal", "roughness", "specular")) -> Material:
        return refine_full_resolution(
            init, relit[0], mask, relit, mask, lights, camera, photo_weight=0.0, relit_weight=1.0,
            relit_maps=maps, steps=steps,
        ).material  # fmt: skip

    start, routed, free = refine(0), refine(5, ("roughness",)), refine(5)
    for name in ("diffuse", "normal", "specular"):
        assert torch.equal(getattr(routed, name), getattr(start, name)), name
    assert float((routed.roughness - start.roughness).abs().min()) > 0
    assert float((free.diffuse - start.diffuse).abs().min()) > 0

    # With the photo weighted too, the unrouted maps take the photo-only fit's first step
    # (Adam's first step does not depend on the loss's scale); the photo's render sees
    # every map (a photo render given the detached maps would leave them at the start).
    photo = kernels.render(*truth.map_tensors(), lights[:1][None], camera)[0, 0]

    def first_step(relit_weight: float, maps) -> Material:
        return refine_full_resolution(
            init, photo, mask, relit, mask, lights, camera, relit_weight=relit_weight, relit_maps=maps, steps=1
        ).material

    photo_only, with_relit = first_step(0.0, ("roughness",)), first_step(1.0, ("roughness",))
    # The diffuse map only: the normals' and specular's photo gradients are tiny on this
    # flat, rough material, where Adam's epsilon (1e-8) makes the first step depend on
    # the loss's scale after all (differences up to 1e-4 measured).
    assert torch.allclose(with_relit.diffuse, photo_only.diffuse, atol=SAME_MATH_TOL)
    assert not torch.equal(with_relit.diffuse, start.diffuse)
    with pytest.raises(ValueError, match="relit_maps must be a non-empty subset"):
        refine(1, ("albedo",))
    with pytest.raises(ValueError, match="relit_maps must be distinct names"):
        CaptureConfig(relit_maps=("roughness", "roughness"))
    with pytest.raises(ValueError, match="relit_maps cannot be empty"):
        CaptureConfig(relit_maps=())


def test_photo_maps_come_from_the_estimator_on_the_photo_alone(tiny_estimator):
    # photo_maps picks those maps from a second estimator pass on the photo alone; the
    # others stay the estimate from the photo and the relit views.
    photo = smooth_photo(64, 64, seed=5)
    alone = pipeline(tiny_estimator, None, relit=0, refine_steps=0)(photo).estimate
    both = pipeline(tiny_estimator, refine_steps=0, photo_maps=())(photo).estimate
    mixed = pipeline(tiny_estimator, refine_steps=0, photo_maps=("diffuse", "roughness"))(photo).estimate
    for name in ("diffuse", "roughness"):
        assert torch.equal(getattr(mixed, name), getattr(alone, name)), name
    for name in ("normal", "specular"):
        assert torch.equal(getattr(mixed, name), getattr(both, name)), name
    for name in ("diffuse", "normal", "roughness", "specular"):  # the relit views do change the estimate
        assert not torch.equal(getattr(alone, name), getattr(both, name)), name


def test_clipped_pixels_are_lower_bounds():
    # A target at its ceiling (an 8-bit photo's 1.0) only says "at least this bright": a
    # brighter render there costs nothing, a darker one costs as usual; unclipped pixels
    # are unaffected.
    from matcap.capture import _masked_log_l1

    target = torch.tensor([[[1.0, 0.5]]]).expand(3, 1, 2)
    mask = torch.ones(1, 2, dtype=torch.bool)
    brighter = torch.tensor([[[3.0, 0.5]]]).expand(3, 1, 2)
    darker = torch.tensor([[[0.5, 0.5]]]).expand(3, 1, 2)
    assert float(_masked_log_l1(brighter, target, mask, 1.0)) == 0.0
    assert float(_masked_log_l1(brighter, target, mask, None)) > 0.0
    assert float(_masked_log_l1(darker, target, mask, 1.0)) == pytest.approx(
        float(_masked_log_l1(darker, target, mask))
    )


def test_robust_relit_loss_is_log_l1_for_small_residuals_and_caps_outliers():
    # tau log(1 + r / tau): r where r << tau; an outlier pixel (a relighter's dark disc)
    # pulls with weight 1 / (1 + r / tau) instead of 1.
    from matcap.capture.refine import _Target

    gen = torch.Generator().manual_seed(0)
    y = torch.rand(3, 8, 8, generator=gen) * 0.5 + 0.2
    mask = torch.ones(8, 8, dtype=torch.bool)
    close = y * 1.001
    plain, robust = _Target(y, mask), _Target(y, mask, robust=0.1)
    assert float(robust.loss(close)) == pytest.approx(float(plain.loss(close)), rel=0.01)
    far = y.clone()
    far[:, 0, 0] = y[:, 0, 0] * 20  # log residual ~3: 30 tau
    x = far.clone().requires_grad_(True)
    robust.loss(x).backward()
    grad_outlier = x.grad[:, 0, 0].abs().mean()
    x2 = far.clone().requires_grad_(True)
    plain.loss(x2).backward()
    assert float(grad_outlier) < 0.05 * float(x2.grad[:, 0, 0].abs().mean())  # 1 / (1 + 30) and below
    with pytest.raises(ValueError, match="robust scale must be positive"):
        _Target(y, mask, robust=0.0)
    with pytest.raises(ValueError, match="relit_robust must be a positive number"):
        CaptureConfig(relit_robust=-1.0)


def test_tilt_energy_sees_low_frequency_tilt_not_bumps():
    # A flat sample however bumpy: slopes of a periodic height field average to ~0 over
    # each cell, so the prior costs ~nothing; a constant tilt s costs s^2 (the blur keeps
    # a constant); a tilt in the masked-out padding costs nothing.
    from matcap.capture.priors import FLATNESS_GRID, tilt_energy

    side = 2 * FLATNESS_GRID
    k = 2 * math.pi / 8  # bumps of an 8 px period: 16 whole periods across
    u = (torch.arange(side, dtype=torch.float64) + 0.5) * k
    # Slopes of the height 0.5 sin(u_x) sin(u_y), analytic: [1, 2, S, S], up to ~0.4.
    bumps = (
        0.5
        * k
        * torch.stack([torch.cos(u)[None, :] * torch.sin(u)[:, None], torch.sin(u)[None, :] * torch.cos(u)[:, None]])
    )
    bumps = bumps[None]
    assert float(bumps.abs().max()) > 0.3
    assert float(tilt_energy(bumps)) < FLAT_BUMPS_TOL
    tilt = torch.full((1, 2, side, side), 0.2, dtype=torch.float64)
    assert float(tilt_energy(tilt)) == pytest.approx(0.2**2, rel=1e-9)
    mask = torch.zeros(side, side, dtype=torch.bool)
    mask[:, : side // 2] = True
    half = tilt.clone()
    half[..., : side // 2] = 0.0
    assert float(tilt_energy(half, mask)) == 0.0
    # Smooth: its gradient is finite everywhere and points against the tilt.
    x = tilt.clone().requires_grad_(True)
    tilt_energy(x).backward()
    assert bool(torch.isfinite(x.grad).all()) and bool((x.grad > 0).all())


def test_flatness_prior_removes_a_low_frequency_tilt(tiny_estimator):
    # Start from maps whose normals tilt in four quadrants (what the refinement does to
    # real photos) and refine against a photo of the flat material: with the prior the
    # tilt left after the same steps is far smaller, and the loss it reports includes it.
    from matcap.capture.refine import tilt_energy

    side = 128
    camera = torch.tensor([0.0, 0.0, 4.83])
    flat = Material(
        torch.full((1, 3, side, side), 0.4),
        torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, side, side).clone(),
        torch.full((1, 1, side, side), 0.5),
        torch.full((1, 3, side, side), 0.04),
    )
    photo = kernels.render(*flat.map_tensors(), camera[None, None], camera)[0, 0]
    sign = torch.where(torch.arange(side) < side // 2, -1.0, 1.0)
    slope = torch.stack([sign[None, :].expand(side, side), sign[:, None].expand(side, side)]) * 0.2
    tilted = torch.nn.functional.normalize(torch.cat([slope, torch.ones(1, side, side)])[None], dim=1)
    init = Material(flat.diffuse, tilted, flat.roughness, flat.specular)
    mask = torch.ones(side, side, dtype=torch.bool)
    empty = torch.zeros(0, 3, 64, 64)

    def left_tilt(flatness: float) -> float:
        result = refine_full_resolution(
            init, photo, mask, empty, mask, camera[None], camera, flatness=flatness, steps=20
        )
        n = result.material.normal
        return float(tilt_energy(n[:, :2] / n[:, 2:3]))

    assert left_tilt(DEFAULT_FLATNESS) < 0.25 * left_tilt(0.0)
    with pytest.raises(ValueError, match="flatness must be a finite number >= 0"):
        CaptureConfig(flatness=float("nan"))


def test_relit_zero_equals_the_estimator_and_refinement_by_hand(tiny_estimator):
    photo = smooth_photo(96, 80, seed=3)
    config = CaptureConfig(relit=0, refine_steps=4, falloff="none")
    out = CapturePipeline(None, tiny_estimator, config=config)(photo)
    # By hand: pad to a multiple of 64, the camera at 45 degrees over the photo's centre,
    # the estimator on the whole 128 px padded photo (under the estimate size), refinement
    # against the photo, back to its grid.
    image, frame = prepare_photo(photo, multiple=64)
    assert config.estimate_side(frame.size[0]) == 128
    h = (frame.photo_long_side / 2) / math.tan(math.radians(45.0) / 2)
    x, y = frame.pixel_to_plane(torch.tensor(95 / 2), torch.tensor(79 / 2))
    camera = torch.tensor([float(x), float(y), h])
    with torch.no_grad():
        estimate = tiny_estimator(image[None, None], camera[None, None], camera[None, None])
    init = estimate.__class__(
        *(torch.nn.functional.interpolate(t, size=frame.size, mode="bilinear") for t in estimate.map_tensors())
    )
    init = init.__class__(
        init.diffuse, torch.nn.functional.normalize(init.normal, dim=1), init.roughness, init.specular
    )
    empty = torch.zeros(0, 3, 64, 64)
    mask = frame.valid_mask()
    result = refine_full_resolution(
        init,
        image,
        mask,
        empty,
        mask,
        camera[None],
        camera,
        photo_ceiling=1.0,
        flatness=config.flatness,
        radial=config.radial,
        radial_maps=config.radial_maps,
        steps=4,
    )
    by_hand = frame.material_to_photo(result.material[0])
    assert out.refine_history == pytest.approx(result.history, rel=SAME_MATH_TOL)
    for name, t in by_hand.maps().items():
        assert torch.allclose(getattr(out.material, name), t, atol=SAME_MATH_TOL), name


def test_maps_land_on_the_photo_pixels_they_came_from(tiny_estimator):
    # One bright quadrant (top-right) in a non-square photo: after refinement against the
    # photo alone, the diffuse map is brightest in that quadrant of the photo's grid.
    photo = torch.full((3, 80, 120), 0.05)
    photo[:, :40, 60:] = 0.5
    out = pipeline(tiny_estimator, None, relit=0, refine_steps=60, refine_lr=0.1, falloff="none")(photo)
    d = out.material.diffuse.mean(0)
    quadrants = [d[:40, :60], d[:40, 60:], d[40:, :60], d[40:, 60:]]
    means = [float(q.mean()) for q in quadrants]
    # Clearly brightest (here about 2x; the dark quadrants differ by specular and normals).
    assert means.index(max(means)) == 1 and means[1] > 1.5 * max(means[0], means[2], means[3])


def test_samples_give_a_confidence_map_with_the_shipped_diffusion_relighter(tiny_estimator):
    photo = builtin_photo(size=64)
    config = CaptureConfig(relit=2, samples=2, refine_steps=1)
    relighter = get_relighter("diffusion")
    out = CapturePipeline(relighter, tiny_estimator, config=config)(photo)
    assert out.relit.shape == (2, 3, 64, 64) and bool(torch.isfinite(out.relit).all())
    assert out.confidence.shape == (1, 64, 64) and float(out.confidence.max()) > 0
    assert out.provenance["weights"]["relighter"]["steps"] == 1
    assert out.provenance["weights"]["relighter"]["config_sha256"]


def test_relit_views_at_a_larger_size_are_refined_against_there(tiny_estimator):
    # relit_size 128 on a 128 px photo: the relighter relights the photo at 128, the
    # estimator (estimate size 64) sees the views area-downsampled, the refinement at 128.
    photo = smooth_photo(128, 128)
    out = pipeline(tiny_estimator, relit=2, relit_size=128, estimate_size=64, falloff="none")(photo)
    assert out.relit.shape == (2, 3, 128, 128) and out.capture.shape == (64, 64)
    lamb = get_relighter("lambertian")
    camera = out.scene.camera_pos
    direct = lamb.relight(photo[None], out.scene.relit_light_pos[None], camera[None])[0]
    torch.testing.assert_close(out.relit, direct)  # relit from the full-size photo
    torch.testing.assert_close(out.capture.images[1:], area_downsample(direct, 64))
    # Relit views smaller than the estimate size are upsampled bilinearly to it.
    up = pipeline(tiny_estimator, relit=2, relit_size=None, estimate_size=128, falloff="none")(photo)
    assert up.relit.shape == (2, 3, 64, 64) and up.capture.shape == (128, 128)
    torch.testing.assert_close(up.capture.images[0], photo)  # the photo itself, no falloff
    torch.testing.assert_close(
        up.capture.images[1:], torch.nn.functional.interpolate(up.relit, size=(128, 128), mode="bilinear")
    )
    # a size that does not divide the padded side falls back to one that does
    assert CaptureConfig(relit_size=256).relit_side(320) == 64
    with pytest.raises(ValueError, match="multiple of the working size"):
        CaptureConfig(relit_size=100)


def test_flash_disc_is_the_cone_under_the_flash():
    # Camera off the centre at height 4 over a plane of side 4 at 128 px (1/32 unit a
    # pixel): the disc has the radius h tan(angle), its centre under the camera.
    camera = torch.tensor([0.5, -0.25, 4.0])
    disc = flash_disc(camera, 128, 4.0, 10.0)
    radius_px = 4.0 * math.tan(math.radians(10.0)) * 32
    # Pixel-count of a digitised disc: off by at most its perimeter's pixels.
    assert abs(int(disc.sum()) - math.pi * radius_px**2) <= 2 * math.pi * radius_px
    rows, cols = torch.nonzero(disc, as_tuple=True)
    row0, col0 = plane_to_grid(0.5, -0.25, 128, 4.0)
    assert abs(float(rows.double().mean()) - row0) < 0.5 and abs(float(cols.double().mean()) - col0) < 0.5
    # Twice as high, the same angle covers twice the radius.
    high = flash_disc(torch.tensor([0.5, -0.25, 8.0]), 128, 4.0, 10.0)
    assert int(high.sum()) == pytest.approx(4 * int(disc.sum()), rel=0.05)
    assert not flash_disc(camera, 128, 4.0, 0.0).any()
    with pytest.raises(ValueError, match="half angle"):
        flash_disc(camera, 128, 4.0, 90.0)


class _FixedViews(Relighter):
    """Relit views given in advance (``[K, 3, S, S]``), whatever the photo."""

    name = "fixed"

    def __init__(self, views: torch.Tensor):
        self.views = views

    def _relight(self, photo, light_pos, camera_pos, *, generator=None):
        return self.views[None, : light_pos.shape[1]].clone()


def test_relit_views_do_not_pull_the_maps_inside_the_flash_highlight(tiny_estimator):
    # The relit views' pixels within relit_highlight degrees under the flash, and those
    # over the photo's clipped pixels, are out of their loss: changing them there leaves
    # the refined maps exactly as they were; changing a pixel elsewhere does not.
    photo = smooth_photo(64, 64)
    photo[:, 2:6, 2:6] = 1.0  # a clipped patch far from the flash point
    base = photo.clamp(max=0.6)[None] * torch.tensor([0.8, 1.2]).view(2, 1, 1, 1)  # two views, all below 1
    cfg = {"relit": 2, "relit_size": None, "falloff": "none", "relit_weight": 1.0, "refine_steps": 3}
    cfg["photo_maps"] = MAP_NAMES  # the estimator's maps do not see the relit views: only the refinement does
    cfg["camera"] = (0.0, 0.0, 4.0)  # the disc: 4 tan 7 deg = 0.49 units, 7.9 px at 16 px a unit

    def run(views, angle):
        config = CaptureConfig(relit_highlight=angle, **cfg)
        return CapturePipeline(_FixedViews(views), tiny_estimator, config=config)(photo).material

    inside, clipped, outside = base.clone(), base.clone(), base.clone()
    inside[:, :, 29:35, 29:35] *= 1.5  # within 4.3 px of the flash point (31.5, 31.5)
    clipped[:, :, 3:5, 3:5] *= 0.2
    outside[:, :, 50:54, 10:14] *= 1.5
    reference = run(base, 7.0)
    for changed in (inside, clipped):
        for a, b in zip(run(changed, 7.0).map_tensors(), reference.map_tensors()):
            torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert not torch.equal(run(outside, 7.0).diffuse, reference.diffuse)
    # With relit_highlight 0 every pixel counts again.
    assert not torch.equal(run(inside, 0.0).diffuse, run(base, 0.0).diffuse)
    with pytest.raises(ValueError, match="relit_highlight"):
        CaptureConfig(relit_highlight=-1.0)


def test_the_shipped_diffusion_relighter_relights_in_tiles_above_its_size(tiny_estimator):
    out = CapturePipeline(
        get_relighter("diffusion"), tiny_estimator, config=CaptureConfig(relit=1, relit_size=128, refine_steps=1)
    )(builtin_photo(size=128))
    assert out.relit.shape == (1, 3, 128, 128) and bool(torch.isfinite(out.relit).all())


def test_a_deterministic_relighter_refuses_samples(tiny_estimator):
    with pytest.raises(ValueError, match="deterministic"):
        pipeline(tiny_estimator, samples=2)(smooth_photo(64, 64))


# ---------------------------------------------------------------------- units, falloff
def test_falloff_conventions_agree_with_the_renderer():
    # A render with 1/d^2 at intensity pi h^2 equals the no-falloff render times the
    # falloff factor, for the flash and for another light: the two conversions the
    # pipeline makes (photo / factor, relit * factor) are exact for a renderer's scene.
    from materials.procedural import generate

    maps = [t[None] for t in generate(5, size=32).map_tensors()]
    camera = torch.tensor([0.0, 0.0, 4.83])
    lights = torch.tensor([[0.0, 0.0, 4.83], [2.0, -1.0, 4.0]])
    plain = kernels.render(*maps, lights[None], camera)[0]
    falloff = kernels.render(*maps, lights[None], camera, inverse_square=True, intensity=math.pi * 4.83**2)[0]
    factor = falloff_factor(lights, 4.83, 32, 4.0)
    assert torch.allclose(falloff, plain * factor, rtol=1e-4, atol=1e-6)
    assert float(factor[0, 0, 15:17, 15:17].max()) == pytest.approx(1.0, abs=2e-3)  # ~1 under the flash


def test_builtin_photo_is_an_8_bit_flash_render():
    photo = builtin_photo("wood", size=64)
    assert photo.size == (64, 64) and photo.format == "builtin" and photo.path == "builtin:wood"
    codes = kernels.tonemap(photo.image) * 255
    assert torch.allclose(codes, codes.round(), atol=1e-3)
    with pytest.raises(ValueError, match="family"):
        builtin_photo("nosuch")


# ---------------------------------------------------------------------- sizes
def test_size_guard_refuses_large_photos_and_downscales_on_request(tiny_estimator):
    big = torch.full((3, 2100, 64), 0.2)
    with pytest.raises(ValueError, match="--max-side 2048"):
        pipeline(tiny_estimator, relit=0)(big)
    out = pipeline(tiny_estimator, relit=0, max_side=256, refine_steps=1)(big)
    assert out.material.shape == (2100, 64) and out.frame.size == (256, 256)
    # The memory estimate at the limit stays under 2 GB and grows with the side.
    assert refine_memory_bytes(MAX_SIDE, 8) < 2e9
    assert refine_memory_bytes(512, 8) < refine_memory_bytes(1024, 8) < refine_memory_bytes(2048, 8)


@pytest.mark.slow
def test_a_512_pixel_photo_end_to_end(tiny_estimator):
    out = pipeline(tiny_estimator, refine_steps=2)(builtin_photo(size=512))
    assert out.material.shape == (512, 512) and out.frame.size == (512, 512)
    assert out.refine_history[-1] < out.refine_history[0]


# ---------------------------------------------------------------------- command line
def capture_argv(photo, out, estimator_folder, *extra):
    return ["capture", str(photo), "--out", str(out), "--estimator", str(estimator_folder), "--refine", "2", *extra]


def test_cli_capture_then_estimate_round_trip(tmp_path, estimator_folder, capsys):
    out = tmp_path / "cap"
    args = capture_argv("builtin:tiles", out, estimator_folder, "--relighter", "lambertian", "--relit", "3")
    args += [
        "--falloff",
        "none",
        "--estimate-size",
        "64",
        "--relit-size",
        "64",
        "--shared-step-maps",
        "normal,roughness",
    ]
    assert main([*args, "--radial", "0.5", "--radial-maps", "roughness,specular"]) == 0
    assert "capture" in capsys.readouterr().err  # the progress bar
    prov = json.loads((out / PROVENANCE_JSON).read_text())
    settings = prov["settings"]  # the flags reach the pipeline
    assert settings["shared_step_maps"] == ["normal", "roughness"]
    assert (settings["radial"], settings["radial_maps"]) == (0.5, ["roughness", "specular"])
    capture = read_capture(out / "capture")
    assert capture.num_views == 4 and capture.shape == (64, 64)
    assert torch.allclose(capture.light_pos[1:], torch.tensor(EVAL_LIGHTS[:3]))
    assert capture.camera_pos[0].tolist() == pytest.approx(prov["scene"]["camera_pos"])
    # The written views are the relit ones, to 8-bit precision.
    relit = torch.stack(
        [torch.from_numpy(read_exr(out / "relit" / f"relit_{k:02d}.exr")).permute(2, 0, 1) for k in range(3)]
    )
    assert float((capture.images[1:] - relit.clamp(0, 1)).abs().max()) <= PNG_LINEAR_TOL
    # `relight estimate` reruns the estimator on it.
    est = tmp_path / "est"
    assert main(["estimate", str(out / "capture"), "--out", str(est), "--model", str(estimator_folder)]) == 0
    assert read_exr(est / "material" / "diffuse.exr").shape == (64, 64, 3)


def test_cli_glb_re_read(tmp_path, estimator_folder):
    out = tmp_path / "cap"
    assert main(capture_argv("builtin", out, estimator_folder, "--relit", "0")) == 0
    glb = read_glb(out / "material" / "material.glb")
    material = glb.gltf["materials"][0]
    assert SPECULAR_EXTENSION in glb.gltf["extensionsUsed"] and SPECULAR_EXTENSION in material["extensions"]
    pbr = material["pbrMetallicRoughness"]
    assert "baseColorTexture" in pbr and "metallicRoughnessTexture" in pbr and "normalTexture" in material
    import io

    base = Image.open(io.BytesIO(glb.texture_image(pbr["baseColorTexture"])))
    assert base.size == (256, 256) and base.mode == "RGB"


def test_cli_exif_orientation_end_to_end(tmp_path, estimator_folder):
    # Stored 96 wide x 64 high with orientation 6 (turn 90 degrees clockwise): the photo is
    # 64 wide x 96 high, and its stored top-left bright corner ends up top-right.
    stored = np.full((64, 96, 3), 20, np.uint8)
    stored[:32, :32] = 230
    exif = Image.Exif()
    exif[ExifTags.Base.Orientation] = 6
    Image.fromarray(stored).save(tmp_path / "p.jpg", quality=95, exif=exif)
    out = tmp_path / "cap"
    args = capture_argv(tmp_path / "p.jpg", out, estimator_folder, "--relit", "0", "--falloff", "none")
    assert main([*args, "--refine", "60"]) == 0  # the last --refine wins
    diffuse = read_exr(out / "material" / "diffuse.exr").mean(-1)
    assert diffuse.shape == (96, 64)
    corners = [diffuse[:32, :32], diffuse[:32, 32:], diffuse[-32:, :32], diffuse[-32:, 32:]]
    means = [float(c.mean()) for c in corners]
    assert means.index(max(means)) == 1  # top-right
    assert json.loads((out / PROVENANCE_JSON).read_text())["photo"]["orientation"] == 6


def test_cli_non_square_png_works(tmp_path, estimator_folder):
    write_png(tmp_path / "p.png", np.full((64, 150, 3), 0.4, np.float32))
    assert (
        main(capture_argv(tmp_path / "p.png", tmp_path / "o", estimator_folder, "--relit", "1", "--relighter", "input"))
        == 0
    )
    assert read_exr(tmp_path / "o" / "material" / "normal.exr").shape == (64, 150, 3)


def _bad_inputs(tmp_path) -> dict:
    (tmp_path / "corrupt.jpg").write_bytes(b"\xff\xd8\xff\xe0" + b"\x00" * 50)
    Image.fromarray(np.zeros((1, 1, 3), np.uint8)).save(tmp_path / "one.png")
    # write_exr refuses NaN: the file is written with OpenEXR directly.
    planes = {c: np.full((64, 64), np.nan if c == "G" else 0.5, np.float32) for c in "RGB"}
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, planes) as exr:
        exr.write(str(tmp_path / "nan.exr"))
    return {
        "corrupt JPEG": (tmp_path / "corrupt.jpg", "cannot decode the JPEG"),
        "1x1": (tmp_path / "one.png", "at least 64 pixels"),
        "NaN EXR": (tmp_path / "nan.exr", "NaN"),
        "missing": (tmp_path / "nothing.png", "does not exist"),
        "unknown builtin": ("builtin:nosuch", "family"),
    }


@pytest.mark.parametrize("case", ["corrupt JPEG", "1x1", "NaN EXR", "missing", "unknown builtin"])
def test_cli_bad_photo_is_one_error_line_and_nothing_written(tmp_path, estimator_folder, capsys, case):
    photo, message = _bad_inputs(tmp_path)[case]
    out = tmp_path / "o"
    assert main(capture_argv(photo, out, estimator_folder)) == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and message in err and "Traceback" not in err
    assert not out.exists() and not list(tmp_path.glob(".o.*"))


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--relit", "9"], "--relit must be 0..7"),
        (["--refine", "-1"], "--refine must be >= 0"),
        (["--fov", "190"], "--fov must lie strictly between"),
        (["--max-side", "5000"], "--max-side must be 64..2048"),
        (["--camera", "0,0,-1"], "below the material plane"),
        (["--relighter", "nosuch"], "unknown relighter 'nosuch'"),
        (["--relighter", "lambertian", "--samples", "2"], "applies to sampling methods"),
        (["--relit-size", "100"], "--relit-size must be a multiple of 64"),
        (["--flatness", "-1"], "--flatness must be a number >= 0"),
        (["--relit-highlight", "95"], "--relit-highlight must lie in [0, 90) degrees"),
        (["--radial", "-0.5"], "--radial must be a number >= 0"),
        (["--radial-maps", "gloss"], "--radial-maps takes distinct names"),
        (["--relit-maps", "albedo"], "--relit-maps takes distinct names of diffuse, normal"),
        (["--photo-maps", "normal,normal"], "--photo-maps takes distinct names"),
        (["--shared-step-maps", "slope"], "--shared-step-maps takes distinct names"),
        (["--relit-maps", "none"], "--relit-maps takes distinct names of diffuse, normal, roughness, specular, got"),
    ],
)
def test_cli_bad_settings(tmp_path, estimator_folder, capsys, extra, message):
    out = tmp_path / "o"
    assert main([*capture_argv("builtin", out, estimator_folder), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and not out.exists()


def test_cli_read_only_output_folder(tmp_path, estimator_folder, capsys):
    if os.geteuid() == 0:
        pytest.skip("root writes into read-only folders; the permission case needs another user")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        assert main(capture_argv("builtin", locked / "o", estimator_folder)) == 2
        assert "cannot write in" in capsys.readouterr().err
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o755)


def test_cli_existing_output_is_checked_before_any_work(tmp_path, estimator_folder, capsys, monkeypatch):
    out = tmp_path / "o"
    out.mkdir()
    (out / "keep.txt").write_text("x")

    def no_work(*args, **kwargs):
        raise AssertionError("computed before checking --out")

    monkeypatch.setattr(CapturePipeline, "__call__", no_work)
    assert main(capture_argv("builtin", out, estimator_folder)) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


def test_cli_interrupt_leaves_nothing_half_written(tmp_path, estimator_folder, monkeypatch):
    import materials.io

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(materials.io, "write_capture", interrupted)
    out = tmp_path / "o"
    assert main(capture_argv("builtin", out, estimator_folder, "--relit", "0")) == 130
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_help_numbers_match_the_code(capsys):
    from matcap.capture import (
        DEFAULT_FLASH_POINT,
        DEFAULT_FLATNESS,
        DEFAULT_PHOTO_MAPS,
        DEFAULT_RADIAL,
        DEFAULT_RADIAL_MAPS,
        DEFAULT_REFINE_STEPS,
        DEFAULT_RELIGHT_STEPS,
        DEFAULT_RELIT_HIGHLIGHT,
        DEFAULT_RELIT_MAPS,
        DEFAULT_RELIT_WEIGHT,
        DEFAULT_SHARED_STEP_MAPS,
    )

    with pytest.raises(SystemExit):
        main(["capture", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"(default {DEFAULT_RELIGHT_STEPS}, its best setting)" in text
    assert f"refinement steps (default {DEFAULT_REFINE_STEPS})" in text
    assert f"the photo's is 1 (default {DEFAULT_RELIT_WEIGHT:g}:" in text
    assert f"low-frequency normal tilt (default {DEFAULT_FLATNESS:g};" in text
    assert f"the photo's clipped pixels (default {DEFAULT_RELIT_HIGHLIGHT:g}: off;" in text
    assert f"centred on the flash (default {DEFAULT_RADIAL:g};" in text
    assert f"separated (default {','.join(DEFAULT_RADIAL_MAPS)})" in text
    assert f"fitted to the photo alone (default {','.join(DEFAULT_RELIT_MAPS)}:" in text
    assert f"the relit views (default {','.join(DEFAULT_PHOTO_MAPS) or 'none'})" in text
    assert f"Adam per pixel (default {','.join(DEFAULT_SHARED_STEP_MAPS) or 'none'}:" in text
    assert f"at most {MAX_SIDE}" in text and f"relit views, 0-{len(EVAL_LIGHTS)}" in text
    assert f"in the photo ({DEFAULT_FLASH_POINT}, the default:" in text


def test_cli_directx_normals_and_tileable_maps(tmp_path, estimator_folder):
    out = tmp_path / "cap"
    args = capture_argv("builtin", out, estimator_folder, "--relit", "0", "--normals", "directx", "--tileable")
    assert main(args) == 0
    gl = read_exr(out / "material" / "normal.exr")
    # The refined maps are written once in each convention: DirectX flips green only.
    assert (out / "material_tileable" / "normal.exr").exists()
    opengl = tmp_path / "gl"
    assert main(capture_argv("builtin", opengl, estimator_folder, "--relit", "0")) == 0
    ref = read_exr(opengl / "material" / "normal.exr")
    np.testing.assert_allclose(gl[..., 1], -ref[..., 1], atol=1e-6)
    np.testing.assert_allclose(gl[..., [0, 2]], ref[..., [0, 2]], atol=1e-6)
    seams = json.loads((out / "material_tileable" / "export.json").read_text())["provenance"]["seam_error"]
    assert set(seams) == {"diffuse", "normal", "roughness", "specular"}
    assert all(s["after"] <= max(s["before"], 2.0) for s in seams.values()), seams
