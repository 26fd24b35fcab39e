"""The ``relight`` command line: main jobs on built-in defaults, and bad input gives one
clear line and exit code 2 (no traceback), with nothing written."""

import json

import pytest

from matcap.cli import main


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
