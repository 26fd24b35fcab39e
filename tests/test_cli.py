"""The ``relight`` command line: main jobs on built-in defaults, and bad input gives one
clear line and exit code 2 (no traceback), with nothing written."""

import json
import os

import numpy as np
import pytest
import torch

import kernels
from matcap.args import join_negative_values
from matcap.cli import main
from materials.io import read_inria, write_inria, write_png
from materials.lights import EVAL_CAMERA
from materials.procedural import generate


def test_render_default(tmp_path, capsys):
    out = tmp_path / "r"
    assert main(["render", "--out", str(out), "--size", "32"]) == 0
    info = json.loads((out / "renders.json").read_text())
    assert len(info["lights"]) == 8
    assert (out / "render_00.exr").is_file() and (out / "render_07.png").is_file() and (out / "sheet.png").is_file()


def test_render_refuses_existing_output(tmp_path, capsys):
    out = tmp_path / "r"
    out.mkdir()
    (out / "precious.txt").write_text("keep me")
    assert main(["render", "--out", str(out), "--size", "16"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["render", "--out", str(out), "--size", "16", "--overwrite"]) == 2
    assert (out / "precious.txt").read_text() == "keep me"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["render", "--light", "1,2"], "three finite numbers"),
        (["render", "--light", "1,2,-1"], "below the material plane"),
        (["render", "--camera", "a,b,c"], "not x,y,z numbers"),
        (["render", "/does/not/exist"], "does not exist"),
        (["synth", "--count", "0"], "--count must be at least 1"),
        (["convert", "/does/not/exist", "--from", "inria"], "does not exist"),
    ],
)
def test_bad_input_is_one_clear_line(tmp_path, capsys, argv, message):
    out = tmp_path / "o"
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()


def test_synth_then_convert_then_render(tmp_path):
    assert main(["synth", "--count", "2", "--size", "32", "--format", "inria", "--out", str(tmp_path / "s")]) == 0
    png = sorted((tmp_path / "s").glob("*.png"))[0]
    assert main(["convert", str(png), "--from", "inria", "--out", str(tmp_path / "m")]) == 0
    assert (tmp_path / "m" / "material.json").is_file()
    assert main(["render", str(tmp_path / "m"), "--out", str(tmp_path / "r"), "--light", "0,0,4"]) == 0
    assert (tmp_path / "r" / "render_00.exr").is_file()


# ----------------------------------------------------------------------------- issue 15 item 7
def test_negative_positions_work_without_the_equals_form(tmp_path):
    out = tmp_path / "r"
    argv = ["render", "--size", "16", "--light", "-1,0,5", "--light", "-.5, -2, 4e0", "--camera", "-0.5,0,4"]
    assert main([*argv, "--out", str(out)]) == 0
    info = json.loads((out / "renders.json").read_text())
    assert info["lights"] == [[-1.0, 0.0, 5.0], [-0.5, -2.0, 4.0]] and info["camera"] == [-0.5, 0.0, 4.0]


def test_join_negative_values_leaves_everything_else_alone():
    argv = ["render", "--light", "-1,0,5", "--seed", "-3", "--light=-2,0,4", "--", "--x", "-1,2"]
    assert join_negative_values(argv) == [
        "render",
        "--light=-1,0,5",
        "--seed",
        "-3",
        "--light=-2,0,4",
        "--",
        "--x",
        "-1,2",
    ]


@pytest.fixture()
def inputs(tmp_path):
    """Cheap real inputs for every command that writes an output folder."""
    photo = tmp_path / "photo.png"
    write_png(photo, np.full((64, 64, 3), 0.5, np.float32))  # read_photo's smallest side
    material = generate(0, size=16)
    sheet = tmp_path / "sheet.png"
    write_inria(sheet, material, torch.full((3, 16, 16), 0.5))
    return {"photo": str(photo), "sheet": str(sheet), "nothing": str(tmp_path / "no_capture")}


WRITERS = {
    "render": ["render", "--size", "16"],
    "synth": ["synth", "--count", "1", "--size", "16"],
    "convert": ["convert", "{sheet}", "--from", "inria"],
    "generate": ["generate", "{photo}", "--model", "lambertian"],
    "estimate": ["estimate", "{nothing}"],
    "eval relighting": ["eval", "relighting", "--count", "1", "--size", "16", "--methods", "lambertian"],
    "eval estimation": ["eval", "estimation", "--num", "1", "--size", "16", "--refine-steps", "0"],
}


@pytest.mark.parametrize("command", sorted(WRITERS))
def test_existing_output_is_refused_before_any_work(tmp_path, capsys, inputs, command):
    argv = [a.format(**inputs) for a in WRITERS[command]]
    out = tmp_path / "out"
    out.mkdir()
    (out / "precious.txt").write_text("keep me")
    # Checked first: `estimate` is given a capture that does not exist and still
    # reports the folder, so nothing was read or computed before.
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err and "--overwrite" in err and "already exists" in err
    assert main([*argv, "--out", str(out), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "not written by this command" in err and "Traceback" not in err
    assert [p.name for p in out.iterdir()] == ["precious.txt"] and (out / "precious.txt").read_text() == "keep me"


def test_output_under_a_file_or_unwritable_is_refused(tmp_path, capsys):
    (tmp_path / "file.txt").write_text("x")
    assert main(["render", "--size", "16", "--out", str(tmp_path / "file.txt" / "out")]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err
    if os.geteuid() == 0:
        pytest.skip("root writes into read-only folders; the permission case needs another user")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        assert main(["render", "--size", "16", "--out", str(locked / "out")]) == 2
        assert "cannot write in" in capsys.readouterr().err
    finally:
        locked.chmod(0o755)


def test_a_killed_runs_temporary_folder_is_cleaned_by_the_next_run(tmp_path):
    leftover = tmp_path / ".r.4194305-0123456789ab.tmp"  # pid above Linux's pid_max: dead
    leftover.mkdir()
    (leftover / "render_00.exr").write_bytes(b"x" * 1000)
    assert main(["render", "--size", "16", "--out", str(tmp_path / "r")]) == 0
    assert not leftover.exists() and (tmp_path / "r" / "renders.json").is_file()


def test_generate_unknown_model_lists_every_relighter(tmp_path, capsys, inputs):
    assert main(["generate", inputs["photo"], "--model", "nosuch", "--out", str(tmp_path / "g")]) == 2
    err = capsys.readouterr().err
    assert "unknown relighter 'nosuch'" in err
    for name in ("bieron", "diffusion", "estimator", "lambertian"):
        assert name in err
    assert not (tmp_path / "g").exists()


def test_generate_shows_progress(tmp_path, capsys, inputs):
    out = tmp_path / "g"
    assert main(["generate", inputs["photo"], "--model", "lambertian", "--out", str(out)]) == 0
    assert "relight (lambertian)" in capsys.readouterr().err


def test_estimate_without_capture_json_says_what_the_format_needs(tmp_path, capsys):
    folder = tmp_path / "photos"
    folder.mkdir()
    write_png(folder / "0.png", np.full((16, 16, 3), 0.5, np.float32))
    assert main(["estimate", str(folder), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "capture.json" in err and "light_pos" in err and "camera_pos" in err and "Traceback" not in err


def test_synth_inria_round_trips_a_linear_render(tmp_path):
    assert main(["synth", "--count", "1", "--size", "32", "--format", "inria", "--out", str(tmp_path / "s")]) == 0
    sheet = sorted((tmp_path / "s").glob("*.png"))[0]
    material, render = read_inria(sheet)
    seed = int(sheet.name.split("_")[0])
    flash = torch.tensor([EVAL_CAMERA])
    expected = kernels.render(*(t[None] for t in generate(seed, size=32).map_tensors()), flash, flash[0])[0, 0]
    # Linear radiance, clipped to [0, 1], to within half an 8-bit step (plus float slack).
    assert (render - expected.clamp(0, 1)).abs().max() <= 0.5 / 255 + 1e-6


@pytest.mark.parametrize("target", ["diffusion", "bieron", "estimator"])
def test_train_targets_show_their_flags(target, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["train", target, "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: relight train {target}") and "--ckpt-dir" in out and "--model." in out


def test_train_relight_is_an_alias_of_diffusion_for_one_release(tmp_path, monkeypatch, capsys):
    import relight.diffusion.train as trainer

    seen = []
    monkeypatch.setattr(trainer, "main", seen.append)  # parse only; no training
    assert main(["train", "relight", "--steps", "3", "--ckpt-dir", str(tmp_path)]) == 0
    assert seen[0].steps == 3 and seen[0].ckpt_dir == str(tmp_path)
    err = capsys.readouterr().err
    assert "deprecated" in err and "relight train diffusion" in err and len(err.strip().splitlines()) == 1
    assert main(["train", "diffusion", "--steps", "3"]) == 0
    assert "deprecated" not in capsys.readouterr().err


def test_train_rejects_an_unknown_target(capsys):
    with pytest.raises(SystemExit):
        main(["train", "unet"])
    assert "invalid choice" in capsys.readouterr().err
