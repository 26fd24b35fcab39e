"""``relight generate`` and ``relight eval relighting`` on tiny inputs; bad input gives one
clear line, exit code 2, nothing written."""

import json

import numpy as np
import pytest

from matcap.cli import main
from materials.io import write_exr, write_png


@pytest.fixture()
def photo_png(tmp_path):
    path = tmp_path / "photo.png"
    write_png(path, np.random.default_rng(0).random((16, 16, 3)).astype(np.float32))
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
    assert sorted(p.name for p in out.glob("relit_*")) == [
        "relit_00.exr",
        "relit_00.png",
        "relit_01.exr",
        "relit_01.png",
    ]


def test_generate_default_lights_from_exr(tmp_path):
    exr = tmp_path / "photo.exr"
    write_exr(exr, np.full((8, 8, 3), 0.3, dtype=np.float32))
    assert main(["generate", str(exr), "--model", "lambertian", "--out", str(tmp_path / "g")]) == 0
    assert len(list((tmp_path / "g").glob("relit_*.exr"))) == 7


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


def test_generate_rejects_grey_and_unknown_files(tmp_path, capsys):
    grey = tmp_path / "grey.png"
    write_png(grey, np.zeros((8, 8, 1), dtype=np.float32))
    assert main(["generate", str(grey), "--model", "input", "--out", str(tmp_path / "g")]) == 2
    assert "expected 3 (RGB)" in capsys.readouterr().err
    (tmp_path / "photo.jpg").write_bytes(b"x")
    assert main(["generate", str(tmp_path / "photo.jpg"), "--out", str(tmp_path / "g")]) == 2
    assert ".png (tone-mapped) or .exr" in capsys.readouterr().err


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


@pytest.mark.parametrize(
    "command, text", [(["generate"], "(default {})"), (["eval", "relighting"], "{} for diffusion")]
)
def test_steps_help_names_the_pipeline_default(capsys, command, text):
    # The help texts are written without importing the diffusion package (it would slow
    # every command); this keeps the number in them from drifting from the pipeline's.
    from relight.diffusion import DEFAULT_STEPS

    with pytest.raises(SystemExit):
        main([*command, "--help"])
    assert text.format(DEFAULT_STEPS) in " ".join(capsys.readouterr().out.split())
