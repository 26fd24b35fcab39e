"""``matcap.capture_eval`` and ``relight eval capture``: the scores on known answers, the
ground-truth relighter, the data sets (INRIA round trip, texture folders), one tiny run
of every row end to end, and the command line's checks."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch

import kernels
from estimator.config import TINY_TEST_CONFIG
from estimator.model import SVBRDFEstimator
from matcap.capture import CaptureConfig, locate_flash
from matcap.capture_eval import (
    RUNS,
    TABLE2,
    TABLE4,
    CaptureEvalConfig,
    GroundTruthRelighter,
    evaluate,
    flash_photo,
    format_tables,
    load_materials,
    novel_lights,
    score,
    write_report,
)
from matcap.cli import main
from materials.camera import camera_from_fov
from materials.dataset import EVAL_SEEDS
from materials.domain_groups import save_texture_folder
from materials.frame import prepare_photo
from materials.lights import EVAL_LIGHTS
from materials.procedural import generate
from relight.interface import get_relighter

#: 8-bit maps (INRIA files, texture PNGs): half a code step, 0.5 / 255, in the stored
#: encoding; diffuse and specular are sRGB-encoded, whose inverse has slope <= 1 / 12.92 * ...
#: at most 2.4 / 1.055 * ((c + 0.055) / 1.055)^1.4 <= 2.28 per code unit: 2.28 * 0.5 / 255.
MAP_8BIT_TOL = 2.28 * 0.5 / 255 + 1e-6
#: A vignetted photo over the clean one, relative: both rounded to 8 bits after the tone
#: map, one code step is <= 2% of a pixel brighter than code 50; 4% covers two roundings.
VIGNETTED_8BIT_TOL = 0.04
#: psnr_from_mse's ceiling for an exact match: -10 log10(MSE_FLOOR = 1e-10).
EXACT_PSNR = 100.0


@pytest.fixture(scope="module")
def tiny_estimator():
    torch.manual_seed(0)
    return SVBRDFEstimator(**TINY_TEST_CONFIG.to_dict()).eval()


def test_novel_lights_are_fixed_and_in_the_training_range():
    lights = novel_lights()
    assert lights.shape == (128, 3) and torch.equal(lights, novel_lights())
    assert bool((lights[:, :2].abs() <= 4).all()) and bool(((lights[:, 2] >= 4) & (lights[:, 2] <= 8)).all())
    assert not any(torch.allclose(lights, torch.tensor(p)) for p in EVAL_LIGHTS)
    # Spread over the range, not bunched (128 uniform draws: the mean is within ~0.7 of 0).
    assert abs(float(lights[:, 0].mean())) < 0.7 and float(lights[:, 0].std()) > 1.5


def _output(material, relit=None, relit_light_pos=None):
    camera = camera_from_fov()
    h = float(camera[2])
    scene = SimpleNamespace(
        render_kwargs={"preset": "dgrsise", "inverse_square": True, "intensity": torch.pi * h * h},
        relit_light_pos=relit_light_pos if relit_light_pos is not None else torch.zeros(0, 3),
    )
    return SimpleNamespace(
        material=material, scene=scene, relit=relit if relit is not None else torch.zeros(0, 3, 8, 8)
    )


def test_score_of_the_true_maps_is_exact_and_a_wrong_map_scores_lower():
    true = generate(int(EVAL_SEEDS[0]), size=32)
    camera = camera_from_fov()
    flash = flash_photo(true, camera)
    lights = novel_lights(16)
    perfect = score(_output(true), true, flash, camera, lights, flip_every=4)
    assert perfect["psnr"] == pytest.approx(EXACT_PSNR) and perfect["ssim"] == pytest.approx(1.0, abs=1e-6)
    assert perfect["flip"] == pytest.approx(0.0, abs=1e-6)
    assert all(perfect[k] == 0 for k in ("mse_diffuse", "mse_normal", "mse_roughness", "mse_specular"))
    wrong = replace(true, diffuse=(true.diffuse + 0.2).clamp(0, 1))
    bad = score(_output(wrong), true, flash, camera, lights, flip_every=4)
    assert bad["psnr"] < 40 and bad["flip"] > 0 and bad["mse_diffuse"] > 0.01
    assert bad["mse_diffuse_highlight"] > 0.01 and bad["mse_roughness"] == 0
    assert "relit_psnr" not in bad


def test_ground_truth_relighter_is_the_8bit_render_and_scores_as_such():
    true = generate(int(EVAL_SEEDS[1]), size=32)
    camera = camera_from_fov()
    lights = torch.tensor(EVAL_LIGHTS[:3])
    relit = GroundTruthRelighter(true).relight(torch.zeros(1, 3, 16, 16), lights[None], camera[None])[0]
    assert relit.shape == (3, 3, 16, 16)
    # On the 8-bit grid of the tone-mapped image.
    codes = kernels.tonemap(relit) * 255
    torch.testing.assert_close(codes, codes.round(), atol=1e-3, rtol=0)
    row = score(_output(true, relit, lights), true, flash_photo(true, camera), camera, novel_lights(4), flip_every=4)
    assert row["relit_psnr"] > 45  # only the 8-bit rounding differs (about 55 dB)


def test_inria_set_round_trips_held_out_materials():
    cfg = CaptureEvalConfig(sets=("inria",), count=2, size=64)
    items = list(load_materials(cfg))
    assert [i.set for i in items] == ["inria", "inria"]
    for item, seed in zip(items, EVAL_SEEDS[2:4]):  # the seeds after the procedural set's
        assert item.name.startswith(str(seed))
        expected = generate(seed, size=64)
        torch.testing.assert_close(item.material.diffuse, expected.diffuse, atol=MAP_8BIT_TOL, rtol=0)
        torch.testing.assert_close(item.material.roughness, expected.roughness, atol=0.5 / 255 + 1e-6, rtol=0)


def _texture_folder(root, name, size=40, seed=0):
    save_texture_folder(root / name, generate(seed, size=size))


def test_texture_set_reads_folders_and_crops_to_size(tmp_path):
    _texture_folder(tmp_path, "b_wood", size=80, seed=1)
    _texture_folder(tmp_path, "a_brick", size=48, seed=2)
    cfg = CaptureEvalConfig(sets=("textures",), size=64, textures=str(tmp_path))
    items = list(load_materials(cfg))
    assert [i.name for i in items] == ["a_brick", "b_wood"]
    assert items[0].material.shape == (48, 48) and items[1].material.shape == (64, 64)
    with pytest.raises(ValueError, match="--textures"):
        CaptureEvalConfig(sets=("textures",))
    with pytest.raises(FileNotFoundError, match="no material folders"):
        list(load_materials(replace(cfg, textures=str(tmp_path / "a_brick"))))


def test_every_row_end_to_end_with_tiny_models(tiny_estimator, tmp_path):
    lambertian = get_relighter("lambertian")
    cfg = CaptureEvalConfig(
        sets=("procedural",), count=1, size=64, capture=CaptureConfig(refine_steps=2, steps=None), flip_every=64
    )
    seen = []
    report = evaluate(
        cfg, tiny_estimator, {"diffusion": lambertian, "bieron": lambertian}, progress=False, on_row=seen.append
    )
    assert [r["run"] for r in report["rows"]] == list(RUNS) and seen == report["rows"]
    assert [r["inputs"] for r in report["rows"]] == [1, 4, 8, 8, 8]
    rows = {r["run"]: r for r in report["rows"]}
    assert rows["gt"]["relit_psnr"] > 45 and rows["diffusion"]["relit_psnr"] < rows["gt"]["relit_psnr"]
    assert all(np.isfinite(r["psnr"]) and 0 < r["ssim"] <= 1 for r in report["rows"])
    tables = format_tables(report)
    assert "Table 2" in tables and "Table 4" in tables
    for run in (*TABLE2, *TABLE4):
        assert f"| {run} |" in tables
    paths = write_report(report, tmp_path / "out", command="relight eval capture ...")
    assert json.loads(paths[0].read_text())["rows"] == report["rows"]
    with pytest.raises(ValueError, match="need relighters"):
        evaluate(cfg, tiny_estimator, {}, progress=False)


def test_photo_vignetting_darkens_the_photo_the_pipeline_sees(tiny_estimator, monkeypatch):
    # The photo handed to the pipeline is the flash render times the gain about its
    # centre (then 8 bits): the corner over the centre falls by the gain's ratio.
    import matcap.capture_eval as capture_eval

    seen = []

    class Recording(capture_eval.CapturePipeline):
        def __call__(self, photo, **kwargs):
            seen.append(photo.image.clone())
            return super().__call__(photo, **kwargs)

    monkeypatch.setattr(capture_eval, "CapturePipeline", Recording)
    cfg = CaptureEvalConfig(
        sets=("procedural",), count=1, size=64, runs=("alone",), capture=CaptureConfig(refine_steps=0), flip_every=64
    )
    evaluate(cfg, tiny_estimator, {}, progress=False)
    evaluate(replace(cfg, photo_vignetting=(-0.3, -0.05)), tiny_estimator, {}, progress=False)
    clean, dark = seen
    ratio = dark / clean.clamp_min(1e-6)
    corner_gain = math.exp(-0.3 * 2 * (63 / 64) ** 2 - 0.05 * 4 * (63 / 64) ** 4)  # rho^2 = 2 (63/64)^2 at a corner
    # 8-bit rounding of the photo: a code step is under 2% of these pixels' values.
    assert float(ratio[:, 0, 0].mean()) == pytest.approx(corner_gain, rel=VIGNETTED_8BIT_TOL)
    assert float(ratio[:, 31:33, 31:33].mean()) == pytest.approx(1.0, rel=VIGNETTED_8BIT_TOL)


def test_photo_offset_moves_the_photos_camera_and_the_pipeline_is_told_the_centre(tiny_estimator, monkeypatch):
    # The photo is rendered from the offset camera (its brightest point moves there);
    # the pipeline is told the centred camera, or nothing with flash_point="auto", in
    # which case it finds the highlight itself.
    import matcap.capture_eval as capture_eval

    seen = []

    class Recording(capture_eval.CapturePipeline):
        def __call__(self, photo, **kwargs):
            out = super().__call__(photo, **kwargs)
            seen.append((photo.image.clone(), self.config.camera, out.scene.camera_pos.clone()))
            return out

    monkeypatch.setattr(capture_eval, "CapturePipeline", Recording)
    centre = CaptureConfig(refine_steps=0, flash_point="centre")
    cfg = CaptureEvalConfig(sets=("procedural",), count=1, size=64, runs=("alone",), capture=centre, flip_every=64)
    offset = (0.8, -0.6)
    report = evaluate(replace(cfg, photo_offset=offset), tiny_estimator, {}, progress=False)
    centred = camera_from_fov().tolist()
    assert report["camera"] == pytest.approx([centred[0] + 0.8, centred[1] - 0.6, centred[2]])
    assert report["camera_told"] == pytest.approx(centred)
    image, told, used = seen[-1]
    assert told == pytest.approx(tuple(centred)) and used.tolist() == pytest.approx(centred)
    auto = replace(cfg, photo_offset=offset, capture=replace(cfg.capture, flash_point="auto"))
    report = evaluate(auto, tiny_estimator, {}, progress=False)
    image, told, used = seen[-1]
    assert report["camera_told"] is None and told is None
    # The pipeline's camera is over what the locator makes of this photo (the pipeline's
    # own tests check the locator).
    x, y = locate_flash(image).plane_point(prepare_photo(image)[1])
    assert used.tolist() == pytest.approx([x, y, centred[2]], abs=1e-5)


@pytest.fixture(scope="module")
def estimator_folder(tmp_path_factory, tiny_estimator):
    folder = tmp_path_factory.mktemp("est") / "tiny"
    tiny_estimator.save_pretrained(folder)
    return folder


def test_cli_eval_capture_writes_the_report(tmp_path, estimator_folder, capsys):
    out = tmp_path / "o"
    argv = ["eval", "capture", "--out", str(out), "--sets", "procedural", "--runs", "alone,gt"]
    argv += ["--count", "1", "--size", "64", "--refine", "1", "--estimator", str(estimator_folder)]
    argv += ["--photo-maps", "normal", "--relit-maps", "roughness,specular", "--relit-weight", "0.5"]
    argv += ["--shared-step-maps", "none", "--radial", "2", "--radial-maps", "normal"]
    argv += ["--vignetting", "all", "--photo-vignetting", "-0.3,-0.05"]
    assert main(argv) == 0
    data = json.loads((out / "capture_eval.json").read_text())
    assert data["config"]["photo_vignetting"] == [-0.3, -0.05] and data["config"]["capture"]["vignetting"] == "all"
    capture = data["config"]["capture"]  # the flags reach the pipeline's settings
    assert (capture["photo_maps"], capture["relit_maps"], capture["relit_weight"]) == (
        ["normal"],
        ["roughness", "specular"],
        0.5,
    )
    assert capture["shared_step_maps"] == [] and (capture["radial"], capture["radial_maps"]) == (2.0, ["normal"])
    assert [r["run"] for r in data["rows"]] == ["alone", "gt"]
    assert "Table 2" in (out / "capture_eval.md").read_text()
    # An existing result is kept unless --overwrite.
    assert main(argv) == 2 and "--overwrite" in capsys.readouterr().err


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--sets", "nosuch"], "unknown sets or runs"),
        (["--runs", "alone,nosuch"], "unknown sets or runs"),
        (["--sets", "textures"], "--textures"),
        (["--sets", "textures", "--textures", "/nonexistent"], "is not a folder"),
        (["--count", "0"], "count >= 1"),
        (["--size", "32"], "size >= 64"),
        (["--runs", "alone,gt", "--checkpoint", "diffusion=/x"], "no run of --runs uses it"),
        (["--checkpoint", "diffusion"], "must be NAME=PATH"),
        (["--relit-size", "100"], "relit size must be a multiple of the working size"),
        (["--photo-maps", "albedo"], "--photo-maps takes distinct names"),
        (["--shared-step-maps", "normal,normal"], "--shared-step-maps takes distinct names"),
        (["--relit-maps", "none"], "--relit-maps takes distinct names"),
        (["--radial-maps", "gloss"], "--radial-maps takes distinct names"),
        (["--photo-vignetting", "0.3,x"], "must be comma-separated numbers"),
        (["--photo-vignetting", "0.3"], "photo_vignetting must be finite numbers <= 0"),
        (["--photo-offset", "0.3"], "photo_offset must be two finite numbers"),
        (["--photo-offset", "a,b"], "--photo-offset 'a,b' must be comma-separated numbers"),
        (["--radial", "-1"], "radial must be a finite number >= 0"),
        (["--relit-weight", "-1"], "relit_weight must be a finite number >= 0"),
        (["--runs", "alone,diffusion", "--checkpoint", "diffusion=/nonexistent"], "/nonexistent"),
        (["--large", "nosuch"], "is not one of"),
        (["--large", "global,whole"], "takes one mode"),
        (["--runs", "alone,gt", "--large", "global"], "no run of --runs uses a relighter"),
        (["--runs", "alone,bieron", "--large", "tiles"], "none of bieron takes tiles"),
    ],
)
def test_cli_eval_capture_bad_settings(tmp_path, estimator_folder, capsys, extra, message):
    out = tmp_path / "o"
    assert main(["eval", "capture", "--out", str(out), "--estimator", str(estimator_folder), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and not out.exists()


def test_cli_eval_capture_hands_the_checkpoint_to_the_relighter(tmp_path, estimator_folder, monkeypatch):
    # --checkpoint diffusion=PATH evaluates other diffusion weights (e.g. a training
    # snapshot) through the same pipeline; a stand-in relighter records what it was given.
    import relight.interface

    asked = []
    real = relight.interface.get_relighter

    def recording(name, checkpoint=None):
        asked.append((name, checkpoint))
        return real("lambertian")

    monkeypatch.setattr(relight.interface, "get_relighter", recording)
    argv = ["eval", "capture", "--out", str(tmp_path / "o"), "--sets", "procedural", "--runs", "alone,diffusion3"]
    argv += ["--count", "1", "--size", "64", "--refine", "1", "--estimator", str(estimator_folder)]
    assert main([*argv, "--checkpoint", f"diffusion={tmp_path / 'snapshot'}"]) == 0
    assert asked == [("diffusion", str(tmp_path / "snapshot"))]


def test_cli_eval_capture_large_sets_the_mode_of_the_relighters_that_take_it(tmp_path, estimator_folder):
    # --large whole reaches Bieron (which takes it) and leaves the diffusion relighter at
    # its own mode; the report records both.
    out = tmp_path / "o"
    argv = ["eval", "capture", "--out", str(out), "--sets", "procedural", "--runs", "diffusion3,bieron"]
    argv += ["--count", "1", "--size", "64", "--refine", "1", "--estimator", str(estimator_folder)]
    assert main([*argv, "--large", "whole"]) == 0
    settings = json.loads((out / "capture_eval.json").read_text())["relighters"]
    assert settings["bieron"]["large"] == "whole" and settings["diffusion"]["large"] == "global"
    assert main([*argv, "--large", "global", "--overwrite"]) == 0
    settings = json.loads((out / "capture_eval.json").read_text())["relighters"]
    assert settings["bieron"]["large"] == "global" and settings["diffusion"]["large"] == "global"
