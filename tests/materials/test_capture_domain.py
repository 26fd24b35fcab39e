"""Capture-domain randomisation (materials.capture_domain, materials.domain_groups):
crops keep l / v / h and images consistent with rendering the crop directly, each
photometric switch does what it says (statistics on a batch), falloff and auto-exposure,
determinism, the paper setup reproduces RenderedGroups, texture folders and symmetries."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from PIL import Image

import kernels
from kernels.tonemap import inverse_tonemap, srgb_encode, tonemap
from materials.capture_domain import (
    MODEL_PLANE_SIZE,
    PHONE_CAMERA_HEIGHT,
    CaptureDomain,
    Degradation,
    apply_degradation,
    crop_geometry,
    degrade,
    quantize_8bit,
    render_geometry,
    sample_degradation,
    sample_geometry,
)
from materials.dataset import TRAIN_SEEDS, GroupConfig, RenderedGroups
from materials.domain_groups import DomainGroups, crop_texture, dihedral, load_texture_folder, mix_materials
from materials.io.encoding import encode_normal
from materials.lights import sample_paper_lights
from materials.procedural import generate
from materials.types import Material

#: Crop vs full render in float64: the same expressions on positions that differ by a
#: few ulps after the shift and scale (1e-16 relative); GGX peaks amplify that by at most
#: ~1e4 on the test's roughness >= 0.2, far below 1e-9.
CROP_RTOL = 1e-9
#: Warp float32 render vs the render scaled afterwards: a few float32 ulps (1e-7
#: relative) on values up to ~1e3 in highlights; 1e-5 relative leaves margin.
RENDER_RTOL = 1e-5
#: 8-bit grid check: codes are integers; float rounding of x^(1/2.2) after x = (c/255)^2.2
#: moves 255 * y by ~1e-4 at most in float32.
CODE_ATOL = 1e-3
#: Sample statistics on 4096 noise values (per level): the variance estimate's relative
#: standard error is sqrt(2 / 4096) ~ 2.2 %; 15 % is ~7 standard errors.
VARIANCE_RTOL = 0.15

#: The white-balance gains are stored in float32: three logs of values rounded to 6e-8
#: relative sum to within ~2e-7 of their float64 sum of 0.
WB_LOG_ATOL = 1e-6

SIZE = 16
CFG = GroupConfig(size=SIZE, views=4, source_size=32)


def _material(size: int = SIZE, seed: int = 11, dtype=torch.float32) -> Material:
    m = generate(seed, size=size)
    # Roughness >= 0.2 keeps GGX peaks moderate for tight comparisons.
    return Material(m.diffuse, m.normal, m.roughness.clamp_min(0.2), m.specular).to(dtype)


def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _render(material: Material, light, camera, **kw):
    return kernels.render(*(t[None] for t in material.map_tensors()), light, camera, return_lvh=True, **kw)


# ---------------------------------------------------------------------- crops
@pytest.mark.parametrize("inverse_square", [False, True])
def test_crop_region_render_equals_cropped_full_render(inverse_square):
    full_px, top, left, n = 32, 8, 4, 16
    material = _material(full_px, dtype=torch.float64)
    light = torch.tensor([[0.3, -0.2, 4.5], [3.0, 1.0, 6.0], [-2.0, -3.0, 5.0]], dtype=torch.float64)
    camera = torch.tensor([[0.3, -0.2, 4.4], [0.0, 0.0, 5.0], [-0.5, 0.5, 3.0]], dtype=torch.float64)
    full, full_lvh = _render(material, light, camera, inverse_square=inverse_square)

    pixel = MODEL_PLANE_SIZE / full_px
    side = n * pixel
    center = (-MODEL_PLANE_SIZE / 2 + (left + n / 2) * pixel, MODEL_PLANE_SIZE / 2 - (top + n / 2) * pixel)
    l2, c2, factor = crop_geometry(light, camera, center, side, inverse_square=inverse_square)
    assert factor == (pytest.approx((MODEL_PLANE_SIZE / side) ** 2) if inverse_square else 1.0)
    crop, crop_lvh = _render(
        material.crop(top, left, n, n), l2, c2, inverse_square=inverse_square, intensity=math.pi * factor
    )
    window = (..., slice(top, top + n), slice(left, left + n))
    torch.testing.assert_close(crop_lvh, full_lvh[window], rtol=CROP_RTOL, atol=CROP_RTOL)
    torch.testing.assert_close(crop, full[window], rtol=CROP_RTOL, atol=0.0)


def test_sampled_crop_renders_a_window_of_the_full_frame():
    """A sampled geometry with a crop, undone with crop_geometry's inverse (the crop of a
    crop back to the full frame), places the window where ``geometry.crop`` says."""
    domain = CaptureDomain(p_crop=1.0, crop_scale=(0.5, 0.5), p_falloff=1.0)
    g = sample_geometry(3, domain, _gen(4))
    cx, cy, side = g.crop
    assert side == pytest.approx(2.0) and abs(cx) <= 1.0 and abs(cy) <= 1.0
    # Back to the full frame: inverse of p' = (p - c) * 4 / side.
    light = g.light.double() * side / MODEL_PLANE_SIZE + torch.tensor([cx, cy, 0.0], dtype=torch.float64)
    camera = g.camera.double() * side / MODEL_PLANE_SIZE + torch.tensor([cx, cy, 0.0], dtype=torch.float64)
    redo, _, factor = crop_geometry(light, camera, (cx, cy), side, inverse_square=True)
    torch.testing.assert_close(redo.float(), g.light, rtol=1e-5, atol=1e-5)
    metering = torch.cat([camera[0, :2], camera.new_zeros(1)])
    expected_gain = float(((light[0] - metering) ** 2).sum()) * factor
    assert float(g.gain[0]) == pytest.approx(expected_gain, rel=1e-5)


# ---------------------------------------------------------------------- geometry
def test_geometry_ranges_and_flash_next_to_the_lens():
    domain = CaptureDomain(p_crop=0.0)
    heights, collocated = [], 0
    for seed in range(200):
        g = sample_geometry(6, domain, _gen(seed))
        assert (g.light[:, 2] > 0).all() and (g.camera[:, 2] > 0).all()
        h = float(g.camera[0, 2])
        heights.append(h)
        assert domain.camera_height[0] - 1e-5 <= h <= domain.camera_height[1] + 1e-5
        assert (g.camera[0, :2].abs() <= domain.camera_offset * h + 1e-5).all()
        # The flash sits beside the lens, at its height, within the relative offset.
        offset = (g.light[0] - g.camera[0]).norm()
        assert float(g.light[0, 2]) == pytest.approx(h) and offset <= domain.flash_offset[1] * h + 1e-5
        if g.collocated:
            collocated += 1
            lens_flash = (g.light - g.camera).norm(dim=1)
            assert (lens_flash <= domain.flash_offset[1] * g.camera[:, 2] + 1e-5).all()
            tilt = torch.atan((g.camera[1:, :2] - g.camera[0, :2]).norm(dim=1) / g.camera[1:, 2])
            assert (torch.rad2deg(tilt) <= domain.collocated_tilt + 1e-3).all()
        else:
            assert (g.camera == g.camera[0]).all(), "paper-style groups keep the camera fixed"
    heights = torch.tensor(heights)
    # Log-uniform [2.5, 12]: the median is the geometric mean sqrt(30) = 5.48; with 200
    # draws the sample median's quantile is within ~0.1 of 0.5 -> heights 4.2-7.1.
    assert 4.2 < float(heights.median()) < 7.1
    assert heights.min() < 4.0 and heights.max() > 8.0, "heights go beyond the paper's [4, 8]"
    assert 60 < collocated < 140, "p_collocated = 0.5 of 200 groups"
    assert abs(PHONE_CAMERA_HEIGHT - 4.828) < 1e-3, "2 / tan(22.5 deg)"
    assert domain.camera_height[0] <= PHONE_CAMERA_HEIGHT <= domain.camera_height[1]


def test_paper_geometry_is_sample_paper_lights():
    g = sample_geometry(8, CaptureDomain.paper(), _gen(3))
    light, camera = sample_paper_lights(8, _gen(3))
    assert torch.equal(g.light, light) and torch.equal(g.camera, camera)
    assert not g.inverse_square and (g.gain == 1).all() and g.crop == (0.0, 0.0, MODEL_PLANE_SIZE)


def test_falloff_auto_exposure_matches_no_falloff_at_the_metering_point():
    """With 1/d^2 the intensity is set so the radiance under the camera equals the
    no-falloff preset's; elsewhere it falls off."""
    n = 33  # odd: the centre pixel sits exactly at (0, 0), the camera's ground point
    flat = Material(
        torch.full((3, n, n), 0.5),
        torch.tensor([0.0, 0.0, 1.0])[:, None, None].expand(3, n, n).clone(),
        torch.full((1, n, n), 0.6),
        torch.full((3, n, n), 0.04),
    )
    domain = CaptureDomain(camera_offset=0.0, p_crop=0.0, p_collocated=0.0, p_falloff=1.0)
    g = sample_geometry(2, domain, _gen(1))
    assert g.inverse_square and float(g.gain[0]) > 1
    lit = render_geometry(flat, g)
    plain = render_geometry(flat, replace(g, inverse_square=False, gain=torch.ones(2)))
    c = n // 2
    torch.testing.assert_close(lit[0, :, c, c], plain[0, :, c, c], rtol=RENDER_RTOL, atol=0.0)
    assert (lit[0, :, 0, 0] < plain[0, :, 0, 0]).all(), "the corner is farther from the flash"


def test_geometry_is_deterministic_and_switches_change_it():
    a = sample_geometry(8, CaptureDomain(), _gen(5))
    b = sample_geometry(8, CaptureDomain(), _gen(5))
    c = sample_geometry(8, CaptureDomain(), _gen(6))
    assert torch.equal(a.light, b.light) and torch.equal(a.gain, b.gain) and a.crop == b.crop
    assert not torch.equal(a.light, c.light)
    stats = [sample_geometry(4, CaptureDomain(p_falloff=0.0, p_crop=0.0), _gen(s)) for s in range(50)]
    assert all(not g.inverse_square and g.crop[2] == MODEL_PLANE_SIZE for g in stats)
    stats = [sample_geometry(4, CaptureDomain(p_falloff=1.0, p_crop=1.0), _gen(s)) for s in range(50)]
    assert all(g.inverse_square and g.crop[2] < MODEL_PLANE_SIZE for g in stats)


# ---------------------------------------------------------------------- photometric
def _images(views: int = 4, seed: int = 0) -> torch.Tensor:
    """Linear renders of a glossy material with a highlight far above white."""
    m = generate(seed, size=SIZE, glossy=True)
    light = torch.tensor([[0.0, 0.0, 4.0]] * views) + torch.linspace(0, 0.3, views)[:, None]
    return kernels.render(*(t[None] for t in m.map_tensors()), light, torch.tensor([0.0, 0.0, 4.0]))[0]


def _only(**effects) -> CaptureDomain:
    return CaptureDomain().without_photometric().switched(**effects)


def test_all_photometric_switches_off_is_the_identity():
    x = _images()
    out = degrade(x, CaptureDomain().without_photometric(), _gen(0))
    assert torch.equal(out, x)
    assert sample_degradation(4, CaptureDomain.paper(), _gen(0)).is_identity


def test_degradation_is_deterministic_by_seed():
    x = _images()
    a, b, c = (degrade(x, CaptureDomain(p_noise=1.0), _gen(s)) for s in (7, 7, 8))
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_switching_one_effect_leaves_the_others_draws():
    on = sample_degradation(4, CaptureDomain(p_noise=1.0, p_jpeg=1.0), _gen(2))
    off = sample_degradation(4, CaptureDomain(p_noise=0.0, p_jpeg=1.0), _gen(2))
    assert off.shot_noise == 0 and on.shot_noise > 0
    assert torch.equal(on.exposure, off.exposure) and on.jpeg_quality == off.jpeg_quality


def test_exposure_is_a_lognormal_gain_per_view():
    domain = _only(exposure=True)
    x = _images().double()
    logs = []
    for seed in range(300):
        out = degrade(x, domain, _gen(seed))
        ratio = out / x
        # One factor per view, the same for every pixel and channel.
        torch.testing.assert_close(ratio, ratio[:, :1, :1, :1].expand_as(ratio), rtol=1e-12, atol=0.0)
        logs.append(ratio[:, 0, 0, 0].log())
    logs = torch.stack(logs)  # [300, V]
    sigma = math.hypot(domain.exposure_sigma, domain.exposure_view_sigma)
    # 300 groups: the std estimate's standard error is ~sigma / sqrt(600) ~ 4 %.
    assert float(logs.std()) == pytest.approx(sigma, rel=0.2)
    assert abs(float(logs.mean())) < 4 * sigma / math.sqrt(300), "median exposure 1"
    within = (logs - logs.mean(1, keepdim=True)).std()
    assert float(within) == pytest.approx(domain.exposure_view_sigma, rel=0.25)


def test_white_balance_gains_have_unit_geometric_mean():
    domain = _only(white_balance=True)
    x = _images().double()
    gains = []
    for seed in range(200):
        out = degrade(x, domain, _gen(seed))
        g = (out / x)[0, :, 0, 0]
        assert float(g.log().sum()) == pytest.approx(0.0, abs=WB_LOG_ATOL)
        gains.append(g)
    spread = torch.stack(gains).log().std(0)
    # log gains are centred N(0, s^2) with one degree of freedom removed: s * sqrt(2/3).
    expected = domain.white_balance_sigma * math.sqrt(2 / 3)
    assert torch.allclose(spread, torch.full((3,), expected, dtype=spread.dtype), rtol=0.25)


def test_noise_variance_grows_with_signal():
    # Levels >= 3 noise std above 0, so the clamp at the black level does not bias the
    # variance: sqrt(1e-4 + 0.01 * 0.1) = 0.033 at 0.1.
    levels = torch.tensor([0.1, 0.8], dtype=torch.float64)
    x = levels[None, :, None, None, None].expand(1, 2, 3, 32, 64).reshape(2, 3, 32, 64).contiguous()
    deg = Degradation(torch.ones(2), torch.ones(3), shot_noise=0.01, read_noise=1e-4)
    out = apply_degradation(x, deg, _gen(0))
    var = (out - x).reshape(2, -1).var(dim=1)
    expected = deg.read_noise + deg.shot_noise * levels
    torch.testing.assert_close(var, expected, rtol=VARIANCE_RTOL, atol=0.0)
    assert var[1] > 5 * var[0]
    # Sampled noise: Brooks et al.'s ranges.
    d = CaptureDomain(p_noise=1.0)
    for seed in range(20):
        s = sample_degradation(2, d, _gen(seed))
        assert d.shot_noise[0] <= s.shot_noise <= d.shot_noise[1] and 0 < s.read_noise < s.shot_noise


def test_clipping_caps_highlights_and_keeps_the_rest():
    domain = replace(_only(clip=True), clip_level=0.75)  # exact in float32
    x = _images()
    assert x.max() > 10, "the flash highlight is far above white"
    out = degrade(x, domain, _gen(0))
    assert float(out.max()) == 0.75
    below = x <= 0.75
    assert torch.equal(out[below], x[below])


def test_quantisation_lands_on_the_8bit_tonemapped_grid():
    x = _images()
    out = degrade(x, _only(quantize=True), _gen(0))
    codes = tonemap(out) * 255
    assert float((codes - codes.round()).abs().max()) < CODE_ATOL
    torch.testing.assert_close(out, inverse_tonemap(quantize_8bit(x).float() / 255))
    assert float(out.max()) <= 1.0, "the tone map clips at 1"
    step = (tonemap(out) - tonemap(x)).abs()
    assert float(step.max()) <= 0.5 / 255 + 1e-6


def test_jpeg_compresses_the_8bit_image():
    x = _images()
    domain = replace(_only(jpeg=True), jpeg_quality=(60, 60))
    deg = sample_degradation(4, domain, _gen(0))
    assert deg.jpeg_quality == 60 and deg.quantize, "JPEG implies the 8-bit round trip"
    out = apply_degradation(x, deg, _gen(0))
    codes = tonemap(out) * 255
    assert float((codes - codes.round()).abs().max()) < CODE_ATOL
    plain = apply_degradation(x, replace(deg, jpeg_quality=None), _gen(0))
    err = (tonemap(out) - tonemap(plain)).abs()
    assert float(err.max()) > 1 / 255, "JPEG changed the image"
    # Quality 60 on a smooth 16 px render: small mean error in display units.
    assert float(err.mean()) < 0.05


# ---------------------------------------------------------------------- dataset
def test_paper_domain_reproduces_rendered_groups():
    a = RenderedGroups(TRAIN_SEEDS, CFG)[3]
    b = DomainGroups(TRAIN_SEEDS, CFG, CaptureDomain.paper())[3]
    for key in ("images", "light_pos", "camera_pos", "maps"):
        assert torch.equal(a[key], b[key]), key
    assert a["seed"] == b["seed"]


def test_domain_item_contract_and_clean_reproduction():
    data = DomainGroups(TRAIN_SEEDS, CFG, CaptureDomain(p_falloff=1.0, p_jpeg=1.0))
    item = data[5]
    assert item["images"].shape == item["clean"].shape == (4, 3, SIZE, SIZE)
    assert item["light_pos"].shape == item["camera_pos"].shape == item["intensity"].shape == (4, 3)
    material = Material.from_stacked(item["maps"]).validate()
    # ``clean`` is the maps rendered with the item's intensity and falloff.
    for v in range(4):
        again = kernels.render(
            *(t[None] for t in material.map_tensors()),
            item["light_pos"][v : v + 1],
            item["camera_pos"][v],
            intensity=tuple(item["intensity"][v].tolist()),
            inverse_square=bool(item["inverse_square"]),
        )[0, 0]
        torch.testing.assert_close(again, item["clean"][v], rtol=RENDER_RTOL, atol=1e-6)
    assert float(item["images"].max()) <= 1.0 and not torch.equal(item["images"], item["clean"])
    again = DomainGroups(TRAIN_SEEDS, CFG, CaptureDomain(p_falloff=1.0, p_jpeg=1.0))[5]
    assert torch.equal(again["images"], item["images"])


def test_textures_and_mixing_are_drawn():
    texture = _material(48, seed=21)
    data = DomainGroups(TRAIN_SEEDS, CFG, CaptureDomain.paper(), textures=[texture], p_texture=0.5, p_mix=0.5)
    sources = [data[i]["source"] for i in range(24)]
    assert {"texture0", "mix", "procedural"} <= set(sources)
    i = sources.index("texture0")
    assert data[i]["seed"] == -1
    # A texture item's diffuse values come from the texture (crop + resize only).
    d = Material.from_stacked(data[i]["maps"]).diffuse
    assert texture.diffuse.min() - 1e-3 <= d.min() and d.max() <= texture.diffuse.max() + 1e-3


def test_mix_materials_endpoints():
    a, b = _material(seed=1), _material(seed=2)
    assert torch.allclose(mix_materials(a, b, 0.0).stacked(), a.stacked(), atol=1e-6)
    assert torch.allclose(mix_materials(a, b, 1.0).stacked(), b.stacked(), atol=1e-6)
    mixed = mix_materials(a, b, 0.5).validate()
    torch.testing.assert_close(mixed.diffuse, (a.diffuse + b.diffuse) / 2)


@pytest.mark.parametrize("transpose,flip_x,flip_y", [(True, False, False), (False, True, False), (True, True, True)])
def test_dihedral_moves_normals_with_the_pixels(transpose, flip_x, flip_y):
    """Rendering the transformed maps under the transformed lights gives the transformed
    image: the normals were turned consistently with the pixel grid."""
    m = _material(dtype=torch.float64)
    light = torch.tensor([[1.0, 0.5, 3.0], [-2.0, 1.5, 4.0]], dtype=torch.float64)
    camera = torch.tensor([0.3, -0.4, 4.0], dtype=torch.float64)

    def move(p):
        p = p.clone()
        if transpose:
            p[..., :2] = torch.stack([-p[..., 1], -p[..., 0]], dim=-1)
        if flip_x:
            p[..., 0] = -p[..., 0]
        if flip_y:
            p[..., 1] = -p[..., 1]
        return p

    def move_image(img):
        if transpose:
            img = img.transpose(-1, -2)
        if flip_x:
            img = img.flip(-1)
        if flip_y:
            img = img.flip(-2)
        return img

    original, _ = _render(m, light, camera)
    moved, _ = _render(dihedral(m, transpose, flip_x, flip_y), move(light), move(camera))
    torch.testing.assert_close(moved, move_image(original), rtol=CROP_RTOL, atol=CROP_RTOL)


def _write_png(path, chw: torch.Tensor, alpha: int | None = None) -> None:
    hwc = (chw.clamp(0, 1) * 255).round().to(torch.uint8).permute(1, 2, 0).numpy()
    if hwc.shape[-1] == 1:
        hwc = hwc[..., 0]
    if alpha is not None:
        hwc = np.concatenate([hwc, np.full(hwc.shape[:2] + (1,), alpha, np.uint8)], axis=-1)
    Image.fromarray(hwc).save(path)


def test_load_texture_folder_decodes_the_matsynth_convention(tmp_path):
    m = _material(seed=5)
    _write_png(tmp_path / "diffuse.png", srgb_encode(m.diffuse), alpha=255)  # opaque RGBA is accepted
    _write_png(tmp_path / "normal.png", encode_normal(m.normal))
    _write_png(tmp_path / "roughness.png", m.roughness)
    _write_png(tmp_path / "specular.png", srgb_encode(m.specular))
    loaded = load_texture_folder(tmp_path)
    # 8-bit storage: half a code step, sRGB-decoded (slope <= 1 above the knee, 1/12.92 below).
    torch.testing.assert_close(loaded.diffuse, m.diffuse, atol=2.5 / 255, rtol=0)
    torch.testing.assert_close(loaded.roughness, m.roughness, atol=0.5 / 255 + 1e-6, rtol=0)
    assert float((loaded.normal * m.normal).sum(0).min()) > 0.999
    flipped = load_texture_folder(tmp_path, normal_green_up=False)
    torch.testing.assert_close(flipped.normal[1], -loaded.normal[1])
    crop = crop_texture(loaded, 8, _gen(0))
    assert crop.shape == (8, 8) and crop.validate() is crop


def test_load_texture_folder_rejects_transparent_maps(tmp_path):
    m = _material(seed=5)
    _write_png(tmp_path / "diffuse.png", m.diffuse, alpha=128)
    for name, t in (("normal", encode_normal(m.normal)), ("roughness", m.roughness), ("specular", m.specular)):
        _write_png(tmp_path / f"{name}.png", t)
    with pytest.raises(ValueError, match="alpha"):
        load_texture_folder(tmp_path)
    with pytest.raises(ValueError, match="does not exist"):
        load_texture_folder(tmp_path / "missing")


def test_domain_validation():
    with pytest.raises(ValueError, match="probability"):
        CaptureDomain(p_noise=1.5)
    with pytest.raises(ValueError, match="unknown effect"):
        CaptureDomain().switched(blur=True)
    with pytest.raises(ValueError, match="dgrsise"):
        DomainGroups(TRAIN_SEEDS, replace(CFG, preset="materialgan"))


def test_p_paper_mixes_clean_paper_items_into_the_capture_stream():
    capture = DomainGroups(TRAIN_SEEDS, CFG, CaptureDomain(p_falloff=1.0))
    mixed = DomainGroups(TRAIN_SEEDS, CFG, CaptureDomain(p_falloff=1.0), p_paper=0.5)
    paper = RenderedGroups(TRAIN_SEEDS, CFG)
    kinds = []
    for i in range(24):
        item = mixed[i]
        if mixed.item_domain(i).geometry == "paper":
            kinds.append("paper")
            assert torch.equal(item["images"], paper[i]["images"]) and not bool(item["inverse_square"])
        else:
            kinds.append("capture")
            assert torch.equal(item["images"], capture[i]["images"]) and bool(item["inverse_square"])
    # Both kinds occur (24 Bernoulli(0.5) draws: all one kind has probability 2 * 2^-24).
    assert set(kinds) == {"paper", "capture"}
    # p_paper = 0 leaves every draw as it was; 1 is the paper's stream.
    assert torch.equal(
        DomainGroups(TRAIN_SEEDS, CFG, p_paper=0.0)[3]["images"], DomainGroups(TRAIN_SEEDS, CFG)[3]["images"]
    )
    assert torch.equal(DomainGroups(TRAIN_SEEDS, CFG, p_paper=1.0)[3]["images"], paper[3]["images"])
    with pytest.raises(ValueError, match="p_paper"):
        DomainGroups(TRAIN_SEEDS, CFG, p_paper=1.5)
