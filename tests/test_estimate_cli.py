"""``relight estimate`` end to end on a rendered capture, with a tiny estimator."""

import json

import torch

import kernels
from estimator import SVBRDFEstimator
from matcap.cli import main
from materials.io import save_capture
from materials.lights import eval_lights
from materials.procedural import generate
from materials.types import Capture


def _capture(tmp_path, views=3):
    material = generate(4, size=32)
    light, camera = eval_lights()
    light, camera = light[:views], camera[:views]
    images = kernels.render(*(t[None] for t in material.map_tensors()), light, camera)[0]
    folder = tmp_path / "capture"
    save_capture(folder, Capture(images=images, light_pos=light, camera_pos=camera))
    return folder


def _tiny_model(tmp_path):
    torch.manual_seed(0)
    model = SVBRDFEstimator(base_channels=8, channel_mults=(1, 2, 4), adapter_width=8, norm_groups=4)
    model.save_pretrained(tmp_path / "model")
    return tmp_path / "model"


def test_estimate_writes_maps_and_rerenders(tmp_path):
    out = tmp_path / "out"
    code = main(
        ["estimate", str(_capture(tmp_path)), "--out", str(out), "--model", str(_tiny_model(tmp_path)), "--refine", "3"]
    )
    assert code == 0
    assert (out / "material" / "diffuse.exr").is_file() and (out / "material" / "normal.png").is_file()
    assert len(list((out / "renders").glob("input_*.exr"))) == 3
    assert len(list((out / "renders").glob("novel_*.exr"))) == 7
    info = json.loads((out / "estimate.json").read_text())
    assert info["views"] == 3 and info["refine_steps"] == 3


def test_estimate_bad_capture_is_clear(tmp_path, capsys):
    folder = tmp_path / "empty"
    folder.mkdir()
    assert main(["estimate", str(folder), "--out", str(tmp_path / "o"), "--model", str(_tiny_model(tmp_path))]) == 2
    err = capsys.readouterr().err
    assert "error" in err and str(folder) in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_eval_estimation_command(tmp_path):
    out = tmp_path / "eval"
    code = main(
        [
            "eval",
            "estimation",
            "--model",
            str(_tiny_model(tmp_path)),
            "--num",
            "1",
            "--size",
            "32",
            "--refine-steps",
            "1",
            "--out",
            str(out),
            "--num-threads",
            "1",
        ]
    )
    assert code == 0
    assert any(out.glob("*.md")) and any(out.glob("*.json"))
