"""Tests for materials.io: round trips, every reader, and every bad input.

All files are small and written by the tests themselves (tmp_path); maps are simple
synthetic ones (random albedo, normals of a random smooth height field), independent of
the procedural generator.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
import torch
from PIL import Image

from kernels.tonemap import inverse_tonemap, srgb_decode, srgb_encode, tonemap
from materials.io import (
    FormatError,
    detect_capture_format,
    detect_material_format,
    load_capture,
    load_material,
    read_capture,
    read_exr,
    read_inria,
    read_ldr,
    read_material,
    read_materialgan,
    read_matsynth,
    read_png,
    save_capture,
    save_material,
    write_capture,
    write_exr,
    write_inria,
    write_material,
    write_png,
)
from materials.io.atomic import atomic_file, atomic_folder, clean_stale
from materials.io.encoding import decode_normal, encode_normal
from materials.io.inria import MAX_BELOW_HORIZON_FRACTION, NORMAL_Z_FLOOR
from materials.types import Capture, MapError, Material

#: One 8-bit quantisation step in the *encoded* domain (what the PNG stores). Writing
#: rounds to the nearest code, so a round trip is off by at most half of it; one full
#: step leaves margin for float32 arithmetic in the encode/decode curves.
ENCODED_TOL = 1.0 / 255.0
#: Normals read from 8-bit (n+1)/2: each component is off by up to 1/255 after
#: decoding (half a step times 2), and renormalising moves it by at most |len - 1| <=
#: sqrt(3)/255 more; 3/255 bounds the sum.
NORMAL_TOL = 3.0 / 255.0

SIZE = 16  # map side used throughout: small enough to keep every test well under a second


# ----------------------------------------------------------------------------- helpers
def smooth_normals(h: int, w: int, gen: torch.Generator) -> torch.Tensor:
    """Unit normals ``[3, h, w]`` of a random smooth height field (bilinear-upsampled noise)."""
    coarse = torch.rand(1, 1, 4, 4, generator=gen)
    height = torch.nn.functional.interpolate(coarse, size=(h, w), mode="bilinear", align_corners=False)[0, 0]
    dx = torch.gradient(height, dim=1)[0] * 4.0
    dy = -torch.gradient(height, dim=0)[0] * 4.0  # rows grow downwards, +y is up
    n = torch.stack([-dx, -dy, torch.ones_like(height)])
    return n / n.norm(dim=0, keepdim=True)


def make_material(h: int = SIZE, w: int = SIZE, seed: int = 0) -> Material:
    """A random, valid material: linear maps [C, h, w] float32."""
    gen = torch.Generator().manual_seed(seed)
    return Material(
        diffuse=torch.rand(3, h, w, generator=gen),
        normal=smooth_normals(h, w, gen),
        roughness=0.1 + 0.9 * torch.rand(1, h, w, generator=gen),
        specular=0.5 * torch.rand(3, h, w, generator=gen),
    )


def make_capture(views: int = 3, size: int = 8, seed: int = 0) -> Capture:
    gen = torch.Generator().manual_seed(seed)
    return Capture(
        images=torch.rand(views, 3, size, size, generator=gen),
        light_pos=torch.rand(views, 3, generator=gen) * torch.tensor([8.0, 8.0, 4.0]) + torch.tensor([-4.0, -4.0, 4.0]),
        camera_pos=torch.tensor([[0.0, 0.0, 4.0]]).repeat(views, 1),
        preset="dgrsise",
        plane_size=4.0,
        intensity=(3.0, 3.0, 3.0),
        meta={"note": "test"},
    )


def hwc(t: torch.Tensor) -> np.ndarray:
    return t.permute(1, 2, 0).numpy()


def assert_names(err: pytest.ExceptionInfo, path, *words: str) -> None:
    """The message names the file (or folder) and the problem (all ``words``)."""
    msg = str(err.value)
    assert str(path) in msg, f"{path} not named in: {msg}"
    for word in words:
        assert word.lower() in msg.lower(), f"{word!r} not in: {msg}"


def png_chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def write_raw_png(path: Path, h: int, w: int, bit_depth: int, colour_type: int, channels: int) -> None:
    """A valid all-zero PNG with any bit depth / colour type (Pillow cannot write 16-bit RGB)."""
    row = b"\x00" + bytes(w * channels * bit_depth // 8)
    ihdr = struct.pack(">IIBBBBB", w, h, bit_depth, colour_type, 0, 0, 0)
    data = zlib.compress(row * h)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) + png_chunk(b"IDAT", data) + png_chunk(b"IEND", b"")
    )


def write_exr_channels(path: Path, planes: dict[str, np.ndarray]) -> None:
    """Write an EXR with arbitrary channels, bypassing write_exr's checks."""
    planes = {k: np.ascontiguousarray(v) for k, v in planes.items()}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, planes) as f:
        f.write(str(path))


# ----------------------------------------------------------------------------- EXR
@pytest.mark.parametrize("compression", ["zip", "none"])
def test_exr_round_trip_is_bit_exact(tmp_path, compression):
    rng = np.random.default_rng(0)
    rgb = (rng.standard_normal((5, 7, 3)) * 10).astype(np.float32)  # signed, > 1: any float
    grey = rng.random((5, 7, 1), dtype=np.float32)
    write_exr(tmp_path / "rgb.exr", rgb, compression=compression)
    write_exr(tmp_path / "y.exr", grey, compression=compression)
    back = read_exr(tmp_path / "rgb.exr")
    assert back.dtype == np.float32 and back.shape == (5, 7, 3)
    assert np.array_equal(back, rgb)
    assert np.array_equal(read_exr(tmp_path / "y.exr"), grey)
    assert np.array_equal(read_exr(tmp_path / "y.exr", channels=("Y",)), grey)


def test_exr_write_handles_non_contiguous_input(tmp_path):
    # A channels-first tensor permuted to channels-last is a strided view.
    t = torch.rand(3, 4, 6)
    write_exr(tmp_path / "a.exr", t.permute(1, 2, 0).numpy())
    assert np.array_equal(read_exr(tmp_path / "a.exr"), t.permute(1, 2, 0).numpy())


def test_exr_reads_half_channels_as_float32(tmp_path):
    half = np.random.default_rng(1).random((4, 4)).astype(np.float16)
    write_exr_channels(tmp_path / "h.exr", {"Y": half})
    back = read_exr(tmp_path / "h.exr")
    assert back.dtype == np.float32 and np.array_equal(back[..., 0], half.astype(np.float32))


def test_exr_missing_file(tmp_path):
    path = tmp_path / "nope.exr"
    with pytest.raises(FormatError) as err:
        read_exr(path)
    assert_names(err, path, "does not exist")


def test_exr_empty_file(tmp_path):
    path = tmp_path / "empty.exr"
    path.write_bytes(b"")
    with pytest.raises(FormatError) as err:
        read_exr(path)
    assert_names(err, path, "empty")


def test_exr_not_an_exr(tmp_path):
    path = tmp_path / "text.exr"
    path.write_text("definitely not an image")
    with pytest.raises(FormatError) as err:
        read_exr(path)
    assert_names(err, path, "not an OpenEXR file")


@pytest.mark.parametrize("keep", [0.3, 0.9])
def test_exr_truncated_file(tmp_path, keep):
    path = tmp_path / "cut.exr"
    write_exr(path, np.random.default_rng(0).random((32, 32, 3), dtype=np.float32), compression="none")
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(FormatError) as err:
        read_exr(path)
    assert_names(err, path, "truncated or corrupt")


@pytest.mark.parametrize("bad, word", [(np.nan, "1 NaN"), (np.inf, "1 inf"), (-np.inf, "1 inf")])
def test_exr_non_finite_values(tmp_path, bad, word):
    path = tmp_path / "bad.exr"
    planes = {c: np.zeros((4, 4), np.float32) for c in "RGB"}
    planes["G"][2, 3] = bad
    write_exr_channels(path, planes)
    with pytest.raises(FormatError) as err:
        read_exr(path)
    assert_names(err, path, word, "finite")


def test_exr_unexpected_channels(tmp_path):
    path = tmp_path / "rgba.exr"
    write_exr_channels(path, {c: np.zeros((4, 4), np.float32) for c in "RGBA"})
    with pytest.raises(FormatError) as err:
        read_exr(path)
    assert_names(err, path, "unexpected EXR channels", "'A'", "R,G,B or Y")
    y_path = tmp_path / "y.exr"
    write_exr(y_path, np.zeros((4, 4, 1), np.float32))
    with pytest.raises(FormatError) as err:
        read_exr(y_path, channels=("R", "G", "B"))
    assert_names(err, y_path, "unexpected EXR channels", "expected R,G,B")


def test_exr_write_refuses_non_finite_and_leaves_target_untouched(tmp_path):
    path = tmp_path / "a.exr"
    good = np.ones((2, 2, 3), np.float32)
    write_exr(path, good)
    bad = good.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(MapError) as err:
        write_exr(path, bad)
    assert_names(err, path, "NaN")
    assert np.array_equal(read_exr(path), good)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr"]  # no temp files left


def test_atomic_file_keeps_old_content_when_writer_fails(tmp_path):
    path = tmp_path / "x.txt"
    path.write_text("old")
    with pytest.raises(RuntimeError), atomic_file(path) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash mid-write")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["x.txt"]


# ----------------------------------------------------------------------------- PNG
@pytest.mark.parametrize("channels", [1, 3])
def test_png_round_trip_within_one_step(tmp_path, channels):
    values = np.random.default_rng(0).random((6, 9, channels), dtype=np.float32)
    write_png(tmp_path / "a.png", values)
    back = read_png(tmp_path / "a.png")
    assert back.dtype == np.float32 and back.shape == (6, 9, channels)
    assert np.abs(back - values).max() <= ENCODED_TOL
    # Codes survive exactly: a second round trip changes nothing.
    write_png(tmp_path / "b.png", back)
    assert np.array_equal(read_png(tmp_path / "b.png"), back)


def test_png_reads_jpeg_via_read_ldr(tmp_path):
    path = tmp_path / "a.jpg"
    Image.fromarray(np.full((8, 8, 3), 128, np.uint8)).save(path, quality=95)
    back = read_ldr(path)
    assert back.shape == (8, 8, 3) and np.abs(back - 128 / 255).max() < 2 * ENCODED_TOL
    with pytest.raises(FormatError) as err:
        read_png(path)
    assert_names(err, path, "not a PNG")


def test_png_write_rejects_out_of_range(tmp_path):
    path = tmp_path / "a.png"
    with pytest.raises(MapError) as err:
        write_png(path, np.full((2, 2, 3), 1.5, np.float32))
    assert_names(err, path, "[0, 1]")
    assert not path.exists()


@pytest.mark.parametrize(
    "bit_depth, colour_type, channels, words",
    [
        (16, 2, 3, ("16-bit", "RGB")),
        (16, 0, 1, ("16-bit", "grey")),
        (8, 6, 4, ("alpha", "4 channels")),
        (8, 4, 2, ("alpha", "2 channels")),
    ],
)
def test_png_rejects_16_bit_and_alpha(tmp_path, bit_depth, colour_type, channels, words):
    path = tmp_path / "bad.png"
    write_raw_png(path, 4, 4, bit_depth, colour_type, channels)
    with pytest.raises(FormatError) as err:
        read_png(path)
    assert_names(err, path, *words)


def test_png_rejects_palette_transparency(tmp_path):
    path = tmp_path / "p.png"
    img = Image.fromarray(np.zeros((4, 4), np.uint8), mode="L").convert("P")
    img.save(path, transparency=0)
    with pytest.raises(FormatError) as err:
        read_png(path)
    assert_names(err, path, "transparency")


def test_png_missing_empty_truncated(tmp_path):
    missing = tmp_path / "missing.png"
    with pytest.raises(FormatError) as err:
        read_png(missing)
    assert_names(err, missing, "does not exist")

    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    with pytest.raises(FormatError) as err:
        read_png(empty)
    assert_names(err, empty, "empty")

    cut = tmp_path / "cut.png"
    write_png(cut, np.random.default_rng(0).random((32, 32, 3)))
    data = cut.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError) as err:
        read_png(cut)
    assert_names(err, cut, "truncated or corrupt")

    stub = tmp_path / "stub.png"
    stub.write_bytes(data[:20])  # signature and a partial header only
    with pytest.raises(FormatError) as err:
        read_png(stub)
    assert_names(err, stub, "truncated or corrupt")


# ----------------------------------------------------------------------------- encodings
def test_normal_encoding_round_trip_and_decode_renormalises():
    n = make_material().normal
    assert torch.allclose(decode_normal(encode_normal(n)), n, atol=1e-6)
    quantised = torch.round(encode_normal(n) * 255) / 255
    decoded = decode_normal(quantised)
    assert torch.allclose(decoded.norm(dim=0), torch.ones(SIZE, SIZE), atol=1e-6)
    assert (decoded - n).abs().max() <= NORMAL_TOL


# ----------------------------------------------------------------------------- our material folder
def test_material_folder_round_trip_exact(tmp_path):
    material = make_material()
    folder = tmp_path / "wood"
    write_material(folder, material, plane_size=4.0, provenance={"seed": 0, "family": "test"})
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted(
        [f"{m}.{e}" for m in ("diffuse", "normal", "roughness", "specular") for e in ("exr", "png")] + ["material.json"]
    )
    back, meta = read_material(folder)
    for name, t in material.maps().items():
        assert torch.equal(getattr(back, name), t), name
    assert meta["format_version"] == 1 and meta["preset"] == "dgrsise" and meta["plane_size"] == 4.0
    assert meta["provenance"] == {"seed": 0, "family": "test"}
    assert meta["sources"]["normal"] == "normal.exr"
    # The human-facing twins: sRGB colour, linear grey roughness, (n+1)/2 normal.
    assert read_png(folder / "roughness.png").shape == (SIZE, SIZE, 1)
    diffuse_png = torch.from_numpy(read_png(folder / "diffuse.png")).permute(2, 0, 1)
    assert (diffuse_png - srgb_encode(material.diffuse)).abs().max() <= ENCODED_TOL


def test_material_folder_png_only_within_tolerance(tmp_path):
    material = make_material(seed=1)
    folder = tmp_path / "m"
    write_material(folder, material)
    for exr in folder.glob("*.exr"):
        exr.unlink()
    back, meta = read_material(folder)
    assert meta["sources"]["diffuse"] == "diffuse.png"
    for name in ("diffuse", "specular"):
        err = (srgb_encode(getattr(back, name)) - srgb_encode(getattr(material, name))).abs().max()
        assert err <= ENCODED_TOL, name
    assert (back.roughness - material.roughness).abs().max() <= ENCODED_TOL
    assert (back.normal - material.normal).abs().max() <= NORMAL_TOL


def test_material_folder_overwrite_rules(tmp_path):
    folder = tmp_path / "m"
    write_material(folder, make_material(seed=0))
    with pytest.raises(FileExistsError) as err:
        write_material(folder, make_material(seed=1))
    assert_names(err, folder, "already exists")
    write_material(folder, make_material(seed=1), overwrite=True)
    assert torch.equal(read_material(folder)[0].diffuse, make_material(seed=1).diffuse)
    unrelated = tmp_path / "photos"
    unrelated.mkdir()
    (unrelated / "holiday.jpg").write_bytes(b"x")
    with pytest.raises(FileExistsError) as err:
        write_material(unrelated, make_material(), overwrite=True)
    assert_names(err, unrelated, "material.json")
    assert (unrelated / "holiday.jpg").exists()


def test_material_folder_write_is_atomic(tmp_path, monkeypatch):
    import materials.io.ours as ours

    calls = {"n": 0}
    real = ours.write_png

    def failing_write_png(path, array):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError("disk full")
        real(path, array)

    monkeypatch.setattr(ours, "write_png", failing_write_png)
    with pytest.raises(OSError):
        write_material(tmp_path / "m", make_material())
    assert list(tmp_path.iterdir()) == []  # neither the folder nor a temporary sibling


def test_material_folder_missing_map(tmp_path):
    folder = tmp_path / "m"
    write_material(folder, make_material())
    (folder / "roughness.exr").unlink()
    (folder / "roughness.png").unlink()
    with pytest.raises(FormatError) as err:
        read_material(folder)
    assert_names(err, folder, "missing maps: roughness")


def test_material_folder_sizes_differ(tmp_path):
    folder = tmp_path / "m"
    write_material(folder, make_material())
    write_exr(folder / "specular.exr", np.zeros((8, 8, 3), np.float32))
    with pytest.raises(FormatError) as err:
        read_material(folder)
    assert_names(err, folder, "sizes differ", "specular.exr 8x8", "diffuse.exr 16x16")


def test_material_folder_wrong_channel_count(tmp_path):
    folder = tmp_path / "m"
    write_material(folder, make_material())
    (folder / "diffuse.exr").unlink()
    write_png(folder / "diffuse.png", np.zeros((SIZE, SIZE, 1), np.float32))
    with pytest.raises(FormatError) as err:
        read_material(folder)
    assert_names(err, folder / "diffuse.png", "1 channels", "expected 3")


def test_material_folder_alpha_channel(tmp_path):
    folder = tmp_path / "m"
    write_material(folder, make_material())
    (folder / "normal.exr").unlink()
    Image.fromarray(np.full((SIZE, SIZE, 4), 128, np.uint8)).save(folder / "normal.png")
    with pytest.raises(FormatError) as err:
        read_material(folder)
    assert_names(err, folder / "normal.png", "alpha")


def test_material_folder_bad_values_name_the_folder(tmp_path):
    folder = tmp_path / "m"
    write_material(folder, make_material())
    write_exr(folder / "roughness.exr", np.full((SIZE, SIZE, 1), 2.0, np.float32))
    with pytest.raises(MapError) as err:
        read_material(folder)
    assert_names(err, folder, "roughness values must lie in [0, 1]")


def test_material_folder_bad_json(tmp_path):
    folder = tmp_path / "m"
    write_material(folder, make_material())
    meta = json.loads((folder / "material.json").read_text())
    meta["format_version"] = 7
    (folder / "material.json").write_text(json.dumps(meta))
    with pytest.raises(FormatError) as err:
        read_material(folder)
    assert_names(err, folder / "material.json", "format_version is 7")
    (folder / "material.json").write_text("{not json")
    with pytest.raises(FormatError) as err:
        read_material(folder)
    assert_names(err, folder / "material.json", "not valid JSON")


# ----------------------------------------------------------------------------- our capture folder
def test_capture_round_trip(tmp_path):
    capture = make_capture()
    folder = tmp_path / "cap"
    write_capture(folder, capture)
    assert sorted(p.name for p in folder.iterdir()) == ["0.png", "1.png", "2.png", "capture.json"]
    back = read_capture(folder)
    assert back.images.shape == capture.images.shape
    assert (tonemap(back.images) - tonemap(capture.images)).abs().max() <= ENCODED_TOL
    assert torch.equal(back.light_pos, capture.light_pos)
    assert torch.equal(back.camera_pos, capture.camera_pos)
    assert (back.preset, back.plane_size, back.intensity) == ("dgrsise", 4.0, (3.0, 3.0, 3.0))
    assert back.meta["note"] == "test" and back.meta["format"] == "ours"
    # The PNGs hold the SPEC tone map of the linear images.
    stored = torch.from_numpy(read_png(folder / "1.png")).permute(2, 0, 1)
    assert (stored - capture.images[1].clamp(0, 1) ** (1 / 2.2)).abs().max() <= ENCODED_TOL


def test_capture_mismatched_counts(tmp_path):
    folder = tmp_path / "cap"
    write_capture(folder, make_capture())
    meta = json.loads((folder / "capture.json").read_text())
    meta["light_pos"] = meta["light_pos"][:2]
    (folder / "capture.json").write_text(json.dumps(meta))
    with pytest.raises(FormatError) as err:
        read_capture(folder)
    assert_names(err, folder / "capture.json", "mismatched counts", "3 images", "2 light_pos")


def test_capture_missing_image(tmp_path):
    folder = tmp_path / "cap"
    write_capture(folder, make_capture())
    (folder / "2.png").unlink()
    with pytest.raises(FormatError) as err:
        read_capture(folder)
    assert_names(err, folder / "2.png", "does not exist")


# ----------------------------------------------------------------------------- INRIA
def test_inria_round_trip(tmp_path):
    material = make_material(seed=2)
    render = torch.rand(3, SIZE, SIZE, generator=torch.Generator().manual_seed(3))
    path = tmp_path / "sample.png"
    write_inria(path, material, render)
    assert Image.open(path).size == (5 * SIZE, SIZE)
    back, render_back = read_inria(path)
    for name in ("diffuse", "specular", "roughness"):
        assert (getattr(back, name) - getattr(material, name)).abs().max() <= ENCODED_TOL, name
    assert (back.normal - material.normal).abs().max() <= NORMAL_TOL
    assert render_back.shape == (3, SIZE, SIZE)
    # The render panel is linear (issue 15): stored and read back without a tone map.
    assert (render_back - render).abs().max() <= ENCODED_TOL


def test_inria_render_panel_is_linear_and_clipped(tmp_path):
    material = make_material(seed=4)
    render = torch.linspace(0.0, 1.5, 3 * SIZE * SIZE).reshape(3, SIZE, SIZE)
    path = tmp_path / "lin.png"
    write_inria(path, material, render)
    stored = np.asarray(Image.open(path))[:, :SIZE].astype(np.float32) / 255.0
    # 8-bit codes are round(255 * clamp(x, 0, 1)): linear, radiance above 1 clipped.
    expected = np.round(np.clip(hwc(render), 0, 1) * 255) / 255
    assert np.abs(stored - expected).max() <= 1e-6
    _, back = read_inria(path)
    assert torch.allclose(back, torch.from_numpy(stored).permute(2, 0, 1))


def _inria_sheet_with_normals(path: Path, normal_codes: np.ndarray) -> None:
    s = normal_codes.shape[0]
    panels = [np.full((s, s, 3), 0.5), normal_codes / 255.0, np.full((s, s, 3), 0.5), np.full((s, s, 3), 0.5),
              np.full((s, s, 3), 0.04)]  # fmt: skip
    write_png(path, np.concatenate(panels, axis=1).astype(np.float32))


def test_inria_lifts_a_few_normals_below_the_surface(tmp_path):
    codes = np.tile(np.array([128.0, 128.0, 255.0]), (SIZE, SIZE, 1))
    codes[0, 0] = [255, 128, 126]  # grazing +x normal quantised to z = 2 * 126/255 - 1 < 0
    codes[3, 5] = [128, 0, 125]
    path = tmp_path / "grazing.png"
    _inria_sheet_with_normals(path, codes)
    with pytest.warns(UserWarning, match=r"2 of 256 normal pixels had z < 0"):
        material, _ = read_inria(path)
    z = material.normal[2]
    assert float(z.min()) > 0
    assert abs(float(z[0, 0]) - NORMAL_Z_FLOOR) < 1e-3 and float(material.normal[0, 0, 0]) > 0.99
    assert torch.allclose(material.normal.norm(dim=0), torch.ones(SIZE, SIZE), atol=1e-6)


def test_inria_refuses_many_normals_below_the_surface(tmp_path):
    codes = np.tile(np.array([128.0, 128.0, 255.0]), (SIZE, SIZE, 1))
    bad = int(MAX_BELOW_HORIZON_FRACTION * SIZE * SIZE) + 1
    codes.reshape(-1, 3)[:bad] = [255, 128, 100]
    path = tmp_path / "flipped.png"
    _inria_sheet_with_normals(path, codes)
    with pytest.raises(FormatError) as err:
        read_inria(path)
    assert_names(err, path, f"{bad} of 256 normal pixels", "into the surface")


def test_inria_panel_order_and_encodings(tmp_path):
    # Build the sheet by hand: render | normal | diffuse | roughness | specular.
    s = 4
    panels = [
        np.full((s, s, 3), 0.5),  # render, linear
        np.tile([0.5, 0.5, 1.0], (s, s, 1)),  # normal (0, 0, 1) as (n+1)/2
        np.tile([0.8, 0.4, 0.2], (s, s, 1)),  # diffuse, linear
        np.full((s, s, 3), 0.6),  # roughness grey
        np.tile([0.1, 0.2, 0.3], (s, s, 1)),  # specular, linear
    ]
    path = tmp_path / "hand.png"
    write_png(path, np.concatenate(panels, axis=1))
    material, render = read_inria(path)
    q = lambda v: round(v * 255) / 255  # noqa: E731 - the stored 8-bit value
    assert torch.allclose(material.diffuse[:, 0, 0], torch.tensor([q(0.8), q(0.4), q(0.2)]))
    assert torch.allclose(material.specular[:, 0, 0], torch.tensor([q(0.1), q(0.2), q(0.3)]))
    assert material.roughness.shape == (1, s, s) and abs(float(material.roughness[0, 0, 0]) - q(0.6)) < 1e-6
    assert torch.allclose(material.normal[:, 0, 0], torch.tensor([0.0, 0.0, 1.0]), atol=NORMAL_TOL)
    assert abs(float(render[0, 0, 0]) - q(0.5)) < 1e-6  # linear, as stored


@pytest.mark.parametrize(
    "shape, words",
    [((16, 81, 3), ("width 81 is not 5 x height 16",)), ((16, 70, 3), ("not square", "16x14"))],
)
def test_inria_bad_layout(tmp_path, shape, words):
    path = tmp_path / "bad.png"
    write_png(path, np.zeros(shape, np.float32))
    with pytest.raises(FormatError) as err:
        read_inria(path)
    assert_names(err, path, *words)


def test_inria_wrong_channel_count_and_alpha(tmp_path):
    grey = tmp_path / "grey.png"
    write_png(grey, np.zeros((16, 80, 1), np.float32))
    with pytest.raises(FormatError) as err:
        read_inria(grey)
    assert_names(err, grey, "1 channel", "expected 3")
    rgba = tmp_path / "rgba.png"
    Image.fromarray(np.zeros((16, 80, 4), np.uint8)).save(rgba)
    with pytest.raises(FormatError) as err:
        read_inria(rgba)
    assert_names(err, rgba, "alpha")


# ----------------------------------------------------------------------------- MatSynth
def _write_matsynth(folder: Path, maps: dict[str, np.ndarray], prefix: str = "") -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, values in maps.items():
        write_png(folder / f"{prefix}{name}.png", values)


def _stored(folder: Path, pattern: str) -> torch.Tensor:
    """The decoded-to-[0,1] content of one written file, [C, H, W]."""
    (path,) = folder.glob(pattern)
    return torch.from_numpy(read_png(path)).permute(2, 0, 1)


def test_matsynth_metallic_roughness(tmp_path):
    rng = np.random.default_rng(0)
    material = make_material(seed=4)
    folder = tmp_path / "Wood_042"
    _write_matsynth(
        folder,
        {
            "BaseColor": rng.random((SIZE, SIZE, 3)),  # sRGB-encoded values
            "Metallic": (rng.random((SIZE, SIZE, 1)) > 0.5).astype(np.float32),
            "Roughness": rng.random((SIZE, SIZE, 1)),
            "Normal": hwc(encode_normal(material.normal)),
            "Height": rng.random((SIZE, SIZE, 1)),
        },
        prefix="Wood_042_",
    )
    (folder / "Wood_042.json").write_text("{}")  # other files are ignored
    got, meta = read_matsynth(folder)
    base = srgb_decode(_stored(folder, "*BaseColor.png"))
    metal = _stored(folder, "*Metallic.png")
    assert meta["workflow"] == "metallic-roughness" and meta["files"]["basecolor"] == "Wood_042_BaseColor.png"
    assert torch.allclose(got.diffuse, base * (1 - metal), atol=1e-6)
    assert torch.allclose(got.specular, 0.04 * (1 - metal) + base * metal, atol=1e-6)
    assert torch.equal(got.roughness, _stored(folder, "*Roughness.png"))
    assert (got.normal - material.normal).abs().max() <= NORMAL_TOL


def test_matsynth_diffuse_specular_preferred_and_resized(tmp_path):
    rng = np.random.default_rng(1)
    material = make_material(seed=5)
    folder = tmp_path / "tiles"
    diffuse_linear = rng.random((SIZE, SIZE, 3)).astype(np.float32)
    _write_matsynth(
        folder,
        {
            "diffuse": hwc(srgb_encode(torch.from_numpy(diffuse_linear).permute(2, 0, 1))),
            "specular": np.full((SIZE, SIZE, 1), 0.3),  # grey file broadcast to RGB
            "basecolor": np.ones((SIZE, SIZE, 3)),  # ignored: diffuse + specular win
            "roughness": np.full((SIZE, SIZE, 3), 0.5),  # RGB grey: channel 0
            "normal": hwc(encode_normal(material.normal)),
        },
    )
    got, meta = read_matsynth(folder)
    assert meta["workflow"] == "diffuse-specular"
    assert (
        srgb_encode(got.diffuse) - srgb_encode(torch.from_numpy(diffuse_linear).permute(2, 0, 1))
    ).abs().max() <= ENCODED_TOL
    assert got.specular.shape == (3, SIZE, SIZE)
    assert torch.allclose(got.specular, srgb_decode(torch.tensor(round(0.3 * 255) / 255)).expand(3, SIZE, SIZE))
    assert got.roughness.shape == (1, SIZE, SIZE)

    small, meta = read_matsynth(folder, size=SIZE // 2)
    assert small.shape == (SIZE // 2, SIZE // 2) and meta["original_size"] == [SIZE, SIZE]
    # Area downsampling: each output pixel is the mean of a 2x2 block (linear values).
    assert torch.allclose(small.diffuse, torch.nn.functional.avg_pool2d(got.diffuse[None], 2)[0], atol=1e-6)
    assert torch.allclose(small.normal.norm(dim=0), torch.ones(SIZE // 2, SIZE // 2), atol=1e-5)


def test_matsynth_missing_maps(tmp_path):
    folder = tmp_path / "m"
    _write_matsynth(folder, {"basecolor": np.zeros((4, 4, 3)), "normal": np.full((4, 4, 3), 0.5)})
    with pytest.raises(FormatError) as err:
        read_matsynth(folder)
    assert_names(err, folder, "missing maps: metallic, roughness")


def test_matsynth_sizes_differ(tmp_path):
    folder = tmp_path / "m"
    _write_matsynth(
        folder,
        {
            "basecolor": np.zeros((8, 8, 3)),
            "metallic": np.zeros((8, 8, 1)),
            "roughness": np.zeros((4, 4, 1)),
            "normal": np.tile([0.5, 0.5, 1.0], (8, 8, 1)),
        },
    )
    with pytest.raises(FormatError) as err:
        read_matsynth(folder)
    assert_names(err, folder, "sizes differ", "roughness.png 4x4", "basecolor.png 8x8")


def test_matsynth_wrong_channel_count(tmp_path):
    folder = tmp_path / "m"
    _write_matsynth(
        folder,
        {
            "basecolor": np.zeros((4, 4, 3)),
            "metallic": np.zeros((4, 4, 1)),
            "roughness": np.zeros((4, 4, 1)),
            "normal": np.full((4, 4, 1), 0.5),
        },
    )
    with pytest.raises(FormatError) as err:
        read_matsynth(folder)
    assert_names(err, folder / "normal.png", "1 channel", "expected 3")


# ----------------------------------------------------------------------------- MaterialGAN
def _write_materialgan(folder: Path, n: int = 3, size: int = 8, *, light_pos: bool = True) -> np.ndarray:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    photos = rng.random((n, size, size, 3)).astype(np.float32)
    for i in range(n):
        write_png(folder / f"{i:02d}.png", photos[i])  # zero-padded like the released data
    (folder / "camera_pos.txt").write_text("".join(f"{i}.0,{-i}.5,20.0\n" for i in range(n)))
    if light_pos:
        (folder / "light_pos.txt").write_text("".join(f"{i} 1 30\n" for i in range(n)))
    (folder / "image_size.txt").write_text("6.8480\n")
    (folder / "light_power.txt").write_text("1500.0000,1500.0000,1500.0000\n")
    return photos


def test_materialgan_reader(tmp_path):
    folder = tmp_path / "cards"
    photos = _write_materialgan(folder)
    capture = read_materialgan(folder)
    assert capture.images.shape == (3, 3, 8, 8)
    assert capture.preset == "materialgan" and capture.plane_size == pytest.approx(6.848)
    assert capture.intensity == (1500.0, 1500.0, 1500.0)
    assert torch.equal(capture.camera_pos[2], torch.tensor([2.0, -2.5, 20.0]))
    assert torch.equal(capture.light_pos[1], torch.tensor([1.0, 1.0, 30.0]))
    stored = torch.from_numpy(photos).permute(0, 3, 1, 2)
    assert (tonemap(capture.images) - stored).abs().max() <= ENCODED_TOL  # linear after inverse tone map
    assert torch.allclose(capture.images, inverse_tonemap(tonemap(capture.images)), atol=1e-6)


def test_materialgan_without_light_pos_is_collocated(tmp_path):
    folder = tmp_path / "flash"
    _write_materialgan(folder, light_pos=False)
    capture = read_materialgan(folder)
    assert torch.equal(capture.light_pos, capture.camera_pos)
    assert "collocated" in capture.meta["light_pos_source"]


def test_materialgan_missing_positions_file(tmp_path):
    folder = tmp_path / "c"
    _write_materialgan(folder)
    (folder / "camera_pos.txt").unlink()
    with pytest.raises(FormatError) as err:
        read_materialgan(folder)
    assert_names(err, folder / "camera_pos.txt", "missing positions file")


def test_materialgan_mismatched_counts(tmp_path):
    folder = tmp_path / "c"
    _write_materialgan(folder)
    (folder / "light_pos.txt").write_text("0 0 30\n1 1 30\n")
    with pytest.raises(FormatError) as err:
        read_materialgan(folder)
    assert_names(err, folder / "light_pos.txt", "mismatched counts", "3 photos but 2 positions")


def test_materialgan_malformed_number(tmp_path):
    folder = tmp_path / "c"
    _write_materialgan(folder)
    (folder / "camera_pos.txt").write_text("0,0,20\n1,abc,20\n2,0,20\n")
    with pytest.raises(FormatError) as err:
        read_materialgan(folder)
    assert_names(err, folder / "camera_pos.txt", "line 2", "'abc' is not a number")
    (folder / "camera_pos.txt").write_text("0,0,20\n1,0\n2,0,20\n")
    with pytest.raises(FormatError) as err:
        read_materialgan(folder)
    assert_names(err, folder / "camera_pos.txt", "line 2", "expected 3 numbers, found 2")


def test_materialgan_images_of_different_sizes(tmp_path):
    folder = tmp_path / "c"
    _write_materialgan(folder)
    write_png(folder / "01.png", np.zeros((4, 4, 3), np.float32))
    with pytest.raises(FormatError) as err:
        read_materialgan(folder)
    assert_names(err, folder, "sizes differ", "01.png 4x4", "00.png 8x8")


def test_materialgan_non_square_image(tmp_path):
    folder = tmp_path / "c"
    _write_materialgan(folder)
    write_png(folder / "02.png", np.zeros((8, 6, 3), np.float32))
    with pytest.raises(FormatError) as err:
        read_materialgan(folder)
    assert_names(err, folder / "02.png", "8x6", "not square")


# ----------------------------------------------------------------------------- loaders
def test_load_material_detects_every_format(tmp_path):
    material = make_material(seed=6)
    save_material(tmp_path / "ours", material)
    save_material(tmp_path / "sheet.png", material, "inria", render=torch.rand(3, SIZE, SIZE))
    _write_matsynth(
        tmp_path / "ms",
        {
            "diffuse": np.zeros((4, 4, 3)),
            "specular": np.zeros((4, 4, 3)),
            "roughness": np.zeros((4, 4, 1)),
            "normal": np.tile([0.5, 0.5, 1.0], (4, 4, 1)),
        },
    )
    for name, fmt in [("ours", "ours"), ("sheet.png", "inria"), ("ms", "matsynth")]:
        assert detect_material_format(tmp_path / name) == fmt
        loaded, meta = load_material(tmp_path / name)
        assert meta["format"] == fmt and isinstance(loaded, Material)
    assert load_material(tmp_path / "sheet.png")[1]["render"].shape == (3, SIZE, SIZE)
    assert torch.equal(load_material(tmp_path / "ours")[0].normal, material.normal)


def test_load_capture_detects_every_format(tmp_path):
    save_capture(tmp_path / "ours", make_capture())
    _write_materialgan(tmp_path / "mg")
    assert detect_capture_format(tmp_path / "ours") == "ours"
    assert detect_capture_format(tmp_path / "mg") == "materialgan"
    assert load_capture(tmp_path / "ours").meta["format"] == "ours"
    assert load_capture(tmp_path / "mg").preset == "materialgan"


def test_unknown_format(tmp_path):
    folder = tmp_path / "stuff"
    folder.mkdir()
    (folder / "notes.txt").write_text("hello")
    with pytest.raises(FormatError) as err:
        load_material(folder)
    assert_names(err, folder, "unknown material format", "material.json", "MatSynth", "INRIA")
    with pytest.raises(FormatError) as err:
        load_capture(folder)
    assert_names(err, folder, "unknown capture format", "capture.json", "camera_pos.txt")
    with pytest.raises(FormatError) as err:
        load_material(folder / "notes.txt")
    assert_names(err, folder / "notes.txt", "unknown material format")
    with pytest.raises(FormatError) as err:
        load_material(folder, fmt="blender")
    assert_names(err, folder, "unknown material format 'blender'")
    missing = tmp_path / "nothing"
    with pytest.raises(FormatError) as err:
        load_material(missing)
    assert_names(err, missing, "does not exist")


def test_format_error_pickles():
    import pickle

    err = pickle.loads(pickle.dumps(FormatError("a/b.png", "file is empty")))
    assert isinstance(err, FormatError) and str(err) == "a/b.png: file is empty" and err.path == "a/b.png"


# ----------------------------------------------------------------------------- atomic leftovers
def _dead_pid() -> int:
    """A pid no process has: one past the largest possible (Linux pid_max <= 2^22)."""
    return 4_194_304 + 1


def test_killed_writers_leftovers_are_cleaned_by_the_next_write(tmp_path):
    target = tmp_path / "out"
    dead = tmp_path / f".out.{_dead_pid()}-0123456789ab.tmp"
    legacy = tmp_path / ".out.abcdefabcdef.tmp"  # named before pids were recorded
    live = tmp_path / f".out.{os.getpid()}-0123456789ab.tmp"  # this process: still writing
    unrelated = tmp_path / ".other.0123456789ab.tmp"
    for folder in (dead, legacy, live, unrelated):
        folder.mkdir()
        (folder / "big.bin").write_bytes(b"x" * 1000)
    with atomic_folder(target, marker="m.txt") as tmp:
        (tmp / "m.txt").write_text("done")
    assert (target / "m.txt").read_text() == "done"
    assert not dead.exists() and not legacy.exists()
    assert live.exists() and unrelated.exists()


def test_a_folder_replacement_killed_between_renames_is_restored(tmp_path):
    # Killed after moving the old folder aside and before moving the new one in.
    old = tmp_path / f".out.{_dead_pid()}-0123456789ab.old"
    old.mkdir()
    (old / "m.txt").write_text("previous")
    assert clean_stale(tmp_path / "out") == [old]
    assert (tmp_path / "out" / "m.txt").read_text() == "previous" and not old.exists()


def test_material_json_describes_each_exr(tmp_path):
    write_material(tmp_path / "m", make_material())
    files = json.loads((tmp_path / "m" / "material.json").read_text())["files"]
    assert "albedo" in files["diffuse.exr"] and "signed" not in files["diffuse.exr"]
    assert "roughness" in files["roughness.exr"] and "signed" not in files["roughness.exr"]
    assert "F0" in files["specular.exr"] and "signed" not in files["specular.exr"]
    assert "signed unit x, y, z" in files["normal.exr"]


def test_capture_detection_says_what_our_format_needs(tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    write_png(folder / "0.png", np.zeros((8, 8, 3), np.float32))
    with pytest.raises(FormatError) as err:
        detect_capture_format(folder)
    assert_names(err, folder, "no capture.json", "light_pos", "camera_pos", "Capture folder format")
