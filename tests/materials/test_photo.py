"""Photos in: ``read_photo`` (PNG 8/16-bit, JPEG, EXR, EXIF), ``prepare_photo`` / ``Frame``
(crop, pad, resize and the way back), and the camera from a field of view."""

from __future__ import annotations

import json
import math
import struct
import zlib
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
import torch
from PIL import ExifTags, Image, ImageOps

from kernels.tonemap import inverse_tonemap
from materials.camera import (
    DEFAULT_FOV_DEG,
    camera_from_fov,
    camera_height,
    crop_fov,
    fov_from_camera,
    fov_from_exif,
)
from materials.frame import Frame, prepare_photo
from materials.io import FormatError, read_photo, write_exr
from materials.types import Material

#: Float32 rounding of x ** 2.2 and of the index arithmetic: results that should be
#: equal differ by at most a few ulps of values in [0, 1].
FLOAT_TOL = 1e-6
S = 64  # the smallest photo side read_photo accepts (MIN_PHOTO_SIDE)


# ----------------------------------------------------------------------------- helpers
def _chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def _paeth(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    p = a + b - c
    pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
    return np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))


def write_png16(path: Path, values: np.ndarray) -> None:
    """A 16-bit PNG of ``[H, W, C]`` uint16 (C = 1, 3 or 4), rows cycling through all five
    PNG filter types (PNG spec, section 9), so the decoder's unfiltering is exercised."""
    h, w, c = values.shape
    colour_type = {1: 0, 3: 2, 4: 6}[c]
    rows = values.astype(">u2").reshape(h, w * c).view(np.uint8).reshape(h, -1).astype(np.int32)
    bpp = 2 * c
    out = bytearray()
    prev = np.zeros_like(rows[0])
    for i, x in enumerate(rows):
        ftype = i % 5
        a = np.concatenate([np.zeros(bpp, np.int32), x[:-bpp]])  # left neighbour
        c_ = np.concatenate([np.zeros(bpp, np.int32), prev[:-bpp]])  # upper-left
        predictor = [np.zeros_like(x), a, prev, (a + prev) // 2, _paeth(a, prev, c_)][ftype]
        out.append(ftype)
        out.extend(((x - predictor) % 256).astype(np.uint8).tobytes())
        prev = x
    ihdr = struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(bytes(out))) + _chunk(b"IEND", b"")
    )


def smooth_image(h: int, w: int, seed: int = 0) -> np.ndarray:
    """``[h, w, 3]`` uint8, smooth (JPEG keeps it well)."""
    gen = torch.Generator().manual_seed(seed)
    coarse = torch.rand(1, 3, 4, 4, generator=gen)
    fine = torch.nn.functional.interpolate(coarse, size=(h, w), mode="bilinear", align_corners=False)[0]
    return (fine.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)


def exif_with(**tags) -> Image.Exif:
    exif = Image.Exif()
    if "orientation" in tags:
        exif[ExifTags.Base.Orientation] = tags["orientation"]
    sub = {}
    if "focal_35mm" in tags:
        sub[ExifTags.Base.FocalLengthIn35mmFilm] = tags["focal_35mm"]
    if "exif_size" in tags:
        sub[ExifTags.Base.ExifImageHeight], sub[ExifTags.Base.ExifImageWidth] = tags["exif_size"]
    if sub:
        exif[ExifTags.IFD.Exif] = sub
    return exif


def assert_names(err: pytest.ExceptionInfo, path, *words: str) -> None:
    msg = str(err.value)
    assert str(path) in msg, f"{path} not named in: {msg}"
    for word in words:
        assert word.lower() in msg.lower(), f"{word!r} not in: {msg}"


def chw(array: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32)).permute(2, 0, 1)


# ----------------------------------------------------------------------------- PNG / JPEG
def test_png8_decodes_with_the_inverse_tone_map(tmp_path):
    pixels = smooth_image(S, 80)
    Image.fromarray(pixels).save(tmp_path / "p.png")
    photo = read_photo(tmp_path / "p.png")
    assert photo.image.dtype == torch.float32 and photo.image.shape == (3, S, 80)
    assert torch.allclose(photo.image, inverse_tonemap(chw(pixels / 255.0)), atol=FLOAT_TOL)
    assert (photo.format, photo.bit_depth, photo.channels, photo.file_size) == ("png", 8, 3, (S, 80))
    json.dumps(photo.metadata())  # provenance-ready


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_png16_keeps_all_16_bits(tmp_path, channels):
    gen = np.random.default_rng(channels)
    values = gen.integers(0, 65536, size=(S, 70, channels), dtype=np.uint32).astype(np.uint16)
    path = tmp_path / "p16.png"
    write_png16(path, values)
    photo = read_photo(path)
    expected = values[..., :3] if channels > 1 else np.repeat(values, 3, axis=-1)
    assert photo.bit_depth == 16 and photo.channels == channels
    assert torch.allclose(photo.image, inverse_tonemap(chw(expected / 65535.0)), atol=FLOAT_TOL)
    # Codes that differ only in the low byte decode to different values: not 8-bit.
    assert len(np.unique((photo.image[0] ** (1 / 2.2) * 65535).round().numpy())) > 256
    if channels == 4:
        assert any("alpha" in n for n in photo.notes)


def test_png16_grey_written_by_pillow(tmp_path):
    values = (np.arange(S * S, dtype=np.uint32).reshape(S, S) * 7 % 65536).astype(np.uint16)
    Image.fromarray(values).save(tmp_path / "g.png")
    photo = read_photo(tmp_path / "g.png")
    assert photo.bit_depth == 16 and any("grey" in n for n in photo.notes)
    assert torch.allclose(photo.image[1], inverse_tonemap(torch.from_numpy(values / 65535.0).float()), atol=FLOAT_TOL)


def test_rgba_png_drops_alpha_with_a_note(tmp_path):
    pixels = np.dstack([smooth_image(S, S), np.full((S, S), 7, np.uint8)])
    Image.fromarray(pixels).save(tmp_path / "a.png")
    photo = read_photo(tmp_path / "a.png")
    assert photo.channels == 4 and any("alpha channel dropped" in n for n in photo.notes)
    assert torch.allclose(photo.image, inverse_tonemap(chw(pixels[..., :3] / 255.0)), atol=FLOAT_TOL)


def test_jpeg_decode(tmp_path):
    pixels = smooth_image(S, 96, seed=2)
    Image.fromarray(pixels).save(tmp_path / "p.jpg", quality=95)
    photo = read_photo(tmp_path / "p.jpg")
    with Image.open(tmp_path / "p.jpg") as img:
        decoded = np.asarray(img.convert("RGB"))
    assert (photo.format, photo.bit_depth) == ("jpeg", 8)
    assert torch.allclose(photo.image, inverse_tonemap(chw(decoded / 255.0)), atol=FLOAT_TOL)
    # and it is the picture that was saved (JPEG at quality 95 on a smooth image: a few codes)
    assert np.abs(decoded.astype(int) - pixels).max() <= 8


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_matches_pillow(tmp_path, orientation):
    pixels = smooth_image(S, 96, seed=orientation)
    pixels[:8, :8] = [255, 0, 0]  # a marker in the stored top-left corner
    path = tmp_path / "o.jpg"
    Image.fromarray(pixels).save(path, quality=95, exif=exif_with(orientation=orientation))
    photo = read_photo(path)
    with Image.open(path) as img:
        upright = np.asarray(ImageOps.exif_transpose(img).convert("RGB"))
    assert photo.orientation == orientation and photo.file_size == (S, 96)
    assert photo.size == upright.shape[:2]
    assert torch.allclose(photo.image, inverse_tonemap(chw(upright / 255.0)), atol=FLOAT_TOL)


def test_exif_focal_length_and_recorded_size(tmp_path):
    path = tmp_path / "f.jpg"
    Image.fromarray(smooth_image(S, S)).save(path, exif=exif_with(focal_35mm=26, exif_size=(3024, 4032)))
    photo = read_photo(path)
    assert photo.focal_35mm == 26.0 and photo.exif_size == (3024, 4032)
    Image.fromarray(smooth_image(S, S)).save(tmp_path / "none.jpg")
    assert read_photo(tmp_path / "none.jpg").focal_35mm is None


# ----------------------------------------------------------------------------- EXR
def test_exr_is_linear_as_stored(tmp_path):
    values = np.random.default_rng(0).random((S, 72, 3), dtype=np.float32) * 3.0
    write_exr(tmp_path / "p.exr", values)
    photo = read_photo(tmp_path / "p.exr")
    assert photo.format == "exr" and photo.bit_depth is None
    assert torch.equal(photo.image, chw(values))


def test_exr_alpha_negative_and_grey(tmp_path):
    rgba = {k: np.full((S, S), v, np.float32) for k, v in {"R": 0.5, "G": -0.01, "B": 2.0, "A": 1.0}.items()}
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, rgba) as f:
        f.write(str(tmp_path / "rgba.exr"))
    photo = read_photo(tmp_path / "rgba.exr")
    assert photo.channels == 4 and float(photo.image.min()) == 0.0 and float(photo.image.max()) == 2.0
    assert any("alpha" in n for n in photo.notes) and any("negative" in n for n in photo.notes)
    write_exr(tmp_path / "y.exr", np.full((S, S, 1), 0.25, np.float32))
    assert torch.equal(read_photo(tmp_path / "y.exr").image, torch.full((3, S, S), 0.25))


# ----------------------------------------------------------------------------- refusals
def _write_cmyk(path: Path) -> None:
    Image.new("CMYK", (S, S), (10, 20, 30, 0)).save(path)


def _write_truncated_jpeg(path: Path) -> None:
    Image.fromarray(smooth_image(S, S)).save(path)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _write_corrupt_png(path: Path) -> None:
    Image.fromarray(smooth_image(S, S)).save(path)
    data = bytearray(path.read_bytes())
    data[60:120] = b"\x00" * 60  # inside the compressed pixel data
    path.write_bytes(bytes(data))


@pytest.mark.parametrize(
    "name, make, words",
    [
        ("missing.png", lambda p: None, ("does not exist",)),
        ("empty.png", lambda p: p.write_bytes(b""), ("empty",)),
        ("notes.png", lambda p: p.write_text("hello"), ("not a PNG, JPEG or EXR",)),
        ("cmyk.jpg", _write_cmyk, ("CMYK", "convert it to RGB")),
        ("cut.jpg", _write_truncated_jpeg, ("truncated or corrupt",)),
        ("bad.png", _write_corrupt_png, ("truncated or corrupt",)),
        ("one.png", lambda p: Image.new("RGB", (1, 1)).save(p), ("1x1", "at least 64")),
        ("thin.png", lambda p: Image.new("RGB", (200, 63)).save(p), ("200x63", "at least 64")),
        ("nan.exr", lambda p: write_nan_exr(p), ("NaN",)),
        ("z.exr", lambda p: write_z_exr(p), ("expected R,G,B or Y",)),
    ],
)
def test_bad_photos_are_refused_naming_the_file(tmp_path, name, make, words):
    path = tmp_path / name
    make(path)
    with pytest.raises(FormatError) as err:
        read_photo(path)
    assert_names(err, path, *words)


def write_nan_exr(path: Path) -> None:
    planes = {k: np.full((S, S), np.nan if k == "G" else 0.5, np.float32) for k in "RGB"}
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, planes) as f:
        f.write(str(path))


def write_z_exr(path: Path) -> None:
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, {"Z": np.ones((S, S), np.float32)}) as f:
        f.write(str(path))


def test_too_large_is_refused_from_the_header(tmp_path):
    # 9000 x 64 of zeros compresses to almost nothing; the header alone is refused.
    row = b"\x00" + bytes(9000 * 3)
    ihdr = struct.pack(">IIBBBBB", 9000, S, 8, 2, 0, 0, 0)
    path = tmp_path / "wide.png"
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(row * S)) + _chunk(b"IEND", b"")
    )
    with pytest.raises(FormatError) as err:
        read_photo(path)
    assert_names(err, path, "9000x64", "downscale")
    Image.new("RGB", (S, 100)).save(tmp_path / "mp.png")
    with pytest.raises(FormatError) as err:
        read_photo(tmp_path / "mp.png", max_pixels=5000)
    assert_names(err, tmp_path / "mp.png", "downscale")


# ----------------------------------------------------------------------------- prepare / Frame
@pytest.mark.parametrize("size", [(300, 200), (64, 64), (65, 130), (64, 1000)])
@pytest.mark.parametrize("pad_mode", ["reflect", "edge"])
def test_pad_round_trip_gives_the_photo_back_exactly(size, pad_mode):
    photo = torch.rand(3, *size, generator=torch.Generator().manual_seed(sum(size)))
    image, frame = prepare_photo(photo, multiple=8, pad_mode=pad_mode)
    side = math.ceil(max(size) / 8) * 8
    assert image.shape == (3, side, side) and frame.size == (side, side)
    assert torch.equal(frame.to_photo(image), photo)
    mask = frame.valid_mask()
    assert int(mask.sum()) == size[0] * size[1]
    top, left, h, w = frame.content_box
    assert torch.equal(image[:, top : top + h, left : left + w], photo)


def test_reflect_padding_mirrors_about_the_border():
    photo = torch.arange(64 * 70, dtype=torch.float32).reshape(1, 64, 70)
    image, frame = prepare_photo(photo, multiple=8)
    assert image.shape == (1, 72, 72) and frame.pad == (4, 4, 1, 1)
    for k in range(4):  # padded row 3 - k repeats photo row k (the border row included)
        assert torch.equal(image[0, 3 - k, 1:71], photo[0, k])
        assert torch.equal(image[0, 68 + k, 1:71], photo[0, 63 - k])
    assert torch.equal(image[0, :, 0], image[0, :, 1]) and torch.equal(image[0, :, 71], image[0, :, 70])
    edge, _ = prepare_photo(photo, multiple=8, pad_mode="edge")
    assert torch.equal(edge[0, 0, 1:71], photo[0, 0]) and torch.equal(edge[0, 71, 1:71], photo[0, 63])


def test_crop_keeps_the_centre_and_maps_back_where_it_can():
    photo = torch.rand(3, 100, 150, generator=torch.Generator().manual_seed(1))
    image, frame = prepare_photo(photo, multiple=8, fit="crop")
    assert image.shape == (3, 96, 96) and frame.crop == (2, 2, 27, 27)
    assert torch.equal(image, photo[:, 2:98, 27:123])
    back = frame.to_photo(image, fill=-1.0)
    covered = frame.photo_coverage()
    assert torch.equal(back[:, covered], photo[:, covered])
    assert bool((back[:, ~covered] == -1.0).all()) and int(covered.sum()) == 96 * 96


def test_resize_bounds_the_side_and_maps_back_by_resampling():
    photo = torch.full((3, 500, 300), 0.3)
    image, frame = prepare_photo(photo, multiple=8, max_side=100)
    assert image.shape[-1] <= 100 and image.shape[-1] % 8 == 0
    assert frame.scaled_size == (96, 58) and frame.scale == (96 / 500, 58 / 300)
    # A constant survives resizing both ways.
    assert (frame.to_photo(image) - 0.3).abs().max() <= FLOAT_TOL


def test_to_photo_from_another_resolution_follows_the_plane_coordinates():
    """A map whose value is the plane x (at any resolution) comes back as the plane x of
    each photo pixel: the prepared grid, the plane and the photo agree."""
    _, frame = prepare_photo(torch.zeros(3, 120, 80), multiple=8, max_side=64)
    n = 64  # e.g. a relighting model's output size
    x_centres = ((torch.arange(n) + 0.5) / n - 0.5) * frame.plane_size
    plane_x = x_centres.view(1, 1, n).expand(1, n, n)
    back = frame.to_photo(plane_x)[0]
    rows, cols = torch.meshgrid(torch.arange(120.0), torch.arange(80.0), indexing="ij")
    x, y = frame.pixel_to_plane(rows, cols)
    assert (back - x).abs().max() <= 1e-5
    r, c = frame.plane_to_pixel(x, y)
    assert torch.allclose(r, rows, atol=1e-4) and torch.allclose(c, cols, atol=1e-4)


def test_photo_plane_distance_is_zero_at_the_point_and_grows_by_the_pitch():
    # A non-square photo, resized and padded: the pixel whose plane point is nearest the
    # given point is the one plane_to_pixel names, and neighbours sit one pitch further
    # (a pixel of the photo covers pixel_pitch * scale of the plane: it was resized by scale).
    _, frame = prepare_photo(torch.zeros(3, 120, 80), multiple=8, max_side=64)
    point = frame.pixel_to_plane(torch.tensor(37.0), torch.tensor(21.0))
    r = frame.photo_plane_distance((float(point[0]), float(point[1])))
    assert r.shape == (120, 80)
    assert float(r[37, 21]) <= 1e-5 and int(r.argmin()) == 37 * 80 + 21
    pitch = frame.pixel_pitch * frame.scale[1]
    assert float(r[37, 22]) == pytest.approx(pitch, rel=1e-4)


def test_square_plane_keeps_the_pixel_pitch_equal():
    _, frame = prepare_photo(torch.zeros(3, 64, 128), multiple=8)
    width, height = frame.photo_plane_size
    assert width == pytest.approx(4.0) and height == pytest.approx(2.0)
    assert frame.photo_long_side == pytest.approx(4.0)
    x0, y0 = frame.pixel_to_plane(torch.tensor(0.0), torch.tensor(0.0))
    x1, y1 = frame.pixel_to_plane(torch.tensor(1.0), torch.tensor(1.0))
    assert float(x1 - x0) == pytest.approx(-float(y1 - y0)) == pytest.approx(frame.pixel_pitch)


def test_material_to_photo_renormalises_normals():
    n = torch.nn.functional.normalize(torch.rand(3, 64, 64) + torch.tensor([0, 0, 1.0]).view(3, 1, 1), dim=0)
    material = Material(torch.rand(3, 64, 64), n, torch.rand(1, 64, 64), torch.rand(3, 64, 64))
    _, frame = prepare_photo(torch.zeros(3, 200, 150), multiple=8, max_side=64)
    back = frame.material_to_photo(material)
    assert back.shape == (200, 150)
    assert torch.allclose(back.normal.norm(dim=0), torch.ones(200, 150), atol=1e-5)


def test_frame_record_round_trips_through_json():
    _, frame = prepare_photo(torch.zeros(3, 90, 70), multiple=8, max_side=64, pad_mode="edge")
    assert Frame.from_dict(json.loads(json.dumps(frame.to_dict()))) == frame


def test_prepare_reads_a_photo_object(tmp_path):
    Image.fromarray(smooth_image(S, 80)).save(tmp_path / "p.png")
    photo = read_photo(tmp_path / "p.png")
    image, frame = prepare_photo(photo, multiple=16)
    assert image.shape == (3, 80, 80) and torch.equal(frame.to_photo(image), photo.image)


# ----------------------------------------------------------------------------- camera
def test_camera_from_fov_spans_the_long_side():
    camera = camera_from_fov(DEFAULT_FOV_DEG)
    assert camera.shape == (3,) and camera[:2].abs().max() == 0
    # 45 degrees over the 4-unit plane: h = 2 / tan(22.5 deg) = 2 (1 + sqrt 2)
    assert float(camera[2]) == pytest.approx(2 * (1 + math.sqrt(2)), rel=1e-6)
    assert fov_from_camera(camera) == pytest.approx(DEFAULT_FOV_DEG, rel=1e-6)
    assert camera_height(90.0, 4.0) == pytest.approx(2.0)
    assert float(camera_from_fov(45.0, plane_size=2.0)[2]) == pytest.approx(float(camera[2]) / 2)


def test_fov_from_exif_uses_the_diagonal():
    # 3:2 frame: the long side of the 43.27 mm diagonal is 36 mm, so 2 atan(18 / f).
    assert fov_from_exif(50.0, aspect=1.5) == pytest.approx(math.degrees(2 * math.atan(18 / 50)), rel=1e-6)
    # 4:3 (phones): long side 0.8 x 43.27 mm.
    assert fov_from_exif(26.0) == pytest.approx(math.degrees(2 * math.atan(0.4 * math.hypot(36, 24) / 26)))
    assert fov_from_exif(26.0, aspect=3 / 4) == fov_from_exif(26.0, aspect=4 / 3)
    assert crop_fov(60.0, 1.0) == pytest.approx(60.0)
    assert crop_fov(60.0, 0.5) == pytest.approx(math.degrees(2 * math.atan(0.5 * math.tan(math.radians(30)))))


@pytest.mark.parametrize("bad", [0.0, 180.0, -5.0, float("nan")])
def test_bad_fov_is_refused(bad):
    with pytest.raises(ValueError, match="field of view"):
        camera_from_fov(bad)
