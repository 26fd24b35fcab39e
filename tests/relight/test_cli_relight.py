"""``relight generate`` and ``relight eval relighting`` on tiny inputs; bad input gives one
clear line, exit code 2, nothing written."""

import json

import numpy as np
import pytest
import torch

from matcap.cli import main
from materials.io import read_capture, read_exr, write_exr, write_png


@pytest.fixture()
def photo_png(tmp_path):
    # 64 px: the smallest side materials.io.read_photo accepts (MIN_PHOTO_SIDE).
    path = tmp_path / "photo.png"
    write_png(path, np.random.default_rng(0).random((64, 64, 3)).astype(np.float32))
    return path


def test_generate_writes_one_pair_per_light(tmp_path, photo_png, tiny_checkpoint):
    out = tmp_path / "g"
    argv = [
        "generate",
        str(photo_png),
        "--model",
        "bieron",
        "--checkpoint",
        str(tiny_checkpoint),
        "--light",
        "1,1,4",
        "--light=-1,0,5",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    info = json.loads((out / "relit.json").read_text())
    assert len(info["lights"]) == 2
    # capture/: the photo as view 0, then one view per light, in our capture format.
    capture = read_capture(out / "capture")
    assert capture.num_views == 3 and torch.equal(capture.light_pos[0], capture.camera_pos[0])
    assert sorted(p.name for p in out.glob("relit_*")) == [
        "relit_00.exr",
        "relit_00.png",
        "relit_01.exr",
        "relit_01.png",
    ]


def test_generate_default_lights_from_exr(tmp_path):
    exr = tmp_path / "photo.exr"
    write_exr(exr, np.full((64, 80, 3), 0.3, dtype=np.float32))
    assert main(["generate", str(exr), "--model", "lambertian", "--out", str(tmp_path / "g")]) == 0
    relit = sorted((tmp_path / "g").glob("relit_*.exr"))
    assert len(relit) == 7
    # Non-square photo: padded to a square for the model, written back on its own grid.
    assert read_exr(relit[0]).shape == (64, 80, 3)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--light", "0,0,-2"], "below the material plane"),
        (["--camera", "0,0,0"], "below the material plane"),
        (["--model", "nope"], "unknown relighter 'nope'"),
    ],
)
def test_generate_bad_input(tmp_path, photo_png, capsys, extra, message):
    out = tmp_path / "g"
    assert main(["generate", str(photo_png), "--model", "lambertian", *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()


def test_generate_reads_photos_with_read_photo(tmp_path, capsys):
    # Grey photos are copied to R, G, B (materials.io.read_photo); a file that is no
    # photo, or one below 64 px, is one error line.
    grey = tmp_path / "grey.png"
    write_png(grey, np.full((64, 64, 1), 0.5, dtype=np.float32))
    assert main(["generate", str(grey), "--model", "input", "--out", str(tmp_path / "g")]) == 0
    (tmp_path / "photo.jpg").write_bytes(b"x")
    assert main(["generate", str(tmp_path / "photo.jpg"), "--out", str(tmp_path / "g2")]) == 2
    assert "not a PNG, JPEG or EXR file" in capsys.readouterr().err
    write_png(tmp_path / "small.png", np.full((16, 16, 3), 0.5, dtype=np.float32))
    assert main(["generate", str(tmp_path / "small.png"), "--model", "input", "--out", str(tmp_path / "g3")]) == 2
    assert "at least 64 pixels" in capsys.readouterr().err
    assert not (tmp_path / "g2").exists() and not (tmp_path / "g3").exists()


def test_eval_relighting_cli(tmp_path, tiny_checkpoint, capsys):
    out = tmp_path / "e"
    argv = [
        "eval",
        "relighting",
        "--count",
        "1",
        "--size",
        "16",
        "--methods",
        "input,lambertian,bieron",
        "--checkpoint",
        f"bieron={tiny_checkpoint}",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    rows = json.loads((out / "relight_eval.json").read_text())["rows"]
    assert [r["method"] for r in rows] == ["input", "lambertian", "bieron"]
    assert (out / "relight_eval.md").is_file() and (out / "relight_eval.png").is_file()
    assert "deprecated" not in capsys.readouterr().err
    assert main(["eval", "relighting", "--count", "0", "--out", str(tmp_path / "e2")]) == 2
    assert "count must be in 1..64" in capsys.readouterr().err


def test_old_eval_targets_still_work_with_a_deprecation_note(tmp_path, capsys):
    # ``relight`` -> ``relighting`` and ``estimator`` -> ``estimation`` (issue 17): the
    # old spellings run the same command for one release and say so on stderr.
    argv = ["--count", "1", "--size", "16", "--methods", "input", "--out"]
    assert main(["eval", "relight", *argv, str(tmp_path / "old")]) == 0
    assert "relight eval relight: deprecated name, use 'relight eval relighting'" in capsys.readouterr().err
    assert main(["eval", "relighting", *argv, str(tmp_path / "new")]) == 0
    assert "deprecated" not in capsys.readouterr().err
    old, new = (json.loads((tmp_path / d / "relight_eval.json").read_text())["rows"] for d in ("old", "new"))
    assert [r["PSNR"] for r in old] == [r["PSNR"] for r in new]
    from matcap.cli import build_parser
    from matcap.cmd_eval import run_estimator

    for target in ("estimator", "estimation"):
        assert build_parser().parse_args(["eval", target, "--out", str(tmp_path / "x")]).run is run_estimator


def test_steps_help_names_the_default(capsys):
    # The help texts are written without importing the diffusion package (it would slow
    # every command); this keeps the numbers in them from drifting from the code's.
    from matcap.capture import DEFAULT_RELIGHT_STEPS
    from relight.diffusion import DEFAULT_STEPS

    with pytest.raises(SystemExit):
        main(["generate", "--help"])
    assert f"(default {DEFAULT_RELIGHT_STEPS}, its best measured setting)" in " ".join(capsys.readouterr().out.split())
    with pytest.raises(SystemExit):
        main(["eval", "relighting", "--help"])
    assert f"{DEFAULT_STEPS} for diffusion" in " ".join(capsys.readouterr().out.split())


def test_eval_relighting_in_the_capture_domain(tmp_path, capsys):
    # --domain capture --first 16: the validation materials as phone-like photos; each
    # material's own camera and lights are recorded.
    argv = ["eval", "relighting", "--count", "2", "--size", "16", "--methods", "input", "--domain", "capture"]
    assert main([*argv, "--first", "16", "--out", str(tmp_path / "c")]) == 0
    blob = json.loads((tmp_path / "c" / "relight_eval.json").read_text())
    assert blob["config"]["domain"] == "capture" and blob["config"]["first"] == 16
    assert len(blob["camera"]) == 2 and len(blob["lights"]) == 2 and len(blob["lights"][0]) == 7
    assert blob["config"]["p_crop"] == 0.5  # the capture domain's share of windows
    # --p-crop 0: whole planes (what the diffusion relighter's global mode sees).
    assert main([*argv, "--p-crop", "0", "--out", str(tmp_path / "w")]) == 0
    assert json.loads((tmp_path / "w" / "relight_eval.json").read_text())["config"]["p_crop"] == 0.0
    assert main([*argv, "--first", "63", "--out", str(tmp_path / "bad")]) == 2
    assert "count must be in 1..1" in capsys.readouterr().err and not (tmp_path / "bad").exists()
