"""The estimator as a relighting baseline: 1-input maps rendered under the target lights."""

import json

import pytest
import torch

import kernels
from estimator.config import TINY_TEST_CONFIG
from estimator.model import SVBRDFEstimator
from matcap.cli import main
from matcap.estimator_relighter import EstimatorRelighter, register
from relight.interface import get_relighter


@pytest.fixture(scope="module")
def tiny_estimator(tmp_path_factory):
    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("estimator")
    SVBRDFEstimator(**TINY_TEST_CONFIG.to_dict()).save_pretrained(folder)
    return folder


def _inputs(size=32, k=3):
    gen = torch.Generator().manual_seed(1)
    photo = torch.rand(2, 3, size, size, generator=gen)
    light_pos = torch.tensor([[1.0, 1.0, 4.0], [-2.0, 0.5, 5.0], [0.0, -1.5, 3.0]][:k]).expand(2, k, 3).contiguous()
    camera_pos = torch.tensor([[0.0, 0.0, 4.0], [0.5, -0.5, 4.5]])
    return photo, light_pos, camera_pos


def test_renders_the_maps_estimated_from_the_flash_photo(tiny_estimator):
    register()
    relighter = get_relighter("estimator", tiny_estimator)
    assert isinstance(relighter, EstimatorRelighter) and not relighter.stochastic
    photo, light_pos, camera_pos = _inputs()
    out = relighter.relight(photo, light_pos, camera_pos)
    assert out.shape == (2, 3, 3, 32, 32) and out.dtype == photo.dtype
    # the same thing by hand, per photo: one view lit from the camera, then the renderer
    model = SVBRDFEstimator.from_pretrained(tiny_estimator).eval()
    for b in range(2):
        with torch.no_grad():
            maps = model(photo[b, None, None], camera_pos[b, None, None], camera_pos[b, None, None])
            want = kernels.render(*maps.map_tensors(), light_pos[b, None], camera_pos[b].expand(1, 3, 3).contiguous())
        torch.testing.assert_close(out[b], want[0], rtol=0, atol=0)
    assert torch.equal(relighter.relight(photo, light_pos, camera_pos), out)  # deterministic


def test_bad_input_is_refused_at_the_boundary(tiny_estimator):
    register()
    relighter = get_relighter("estimator", tiny_estimator)
    photo, light_pos, camera_pos = _inputs()
    below = light_pos.clone()
    below[0, 1, 2] = -1.0
    with pytest.raises(ValueError, match="light_pos has a position on or below"):
        relighter.relight(photo, below, camera_pos)
    with pytest.raises(ValueError, match=r"photo must have shape \[B, 3, H, W\]"):
        relighter.relight(photo[:, :2], light_pos, camera_pos)


def test_missing_checkpoint_is_a_clear_error(tmp_path):
    register()
    with pytest.raises(FileNotFoundError, match="config.json"):
        get_relighter("estimator", tmp_path)


def test_eval_relighting_has_an_estimator_row(tmp_path, tiny_estimator):
    out = tmp_path / "e"
    argv = [
        "eval",
        "relighting",
        "--count",
        "1",
        "--size",
        "32",
        "--methods",
        "lambertian,estimator",
        "--checkpoint",
        f"estimator={tiny_estimator}",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    rows = json.loads((out / "relight_eval.json").read_text())["rows"]
    assert [r["method"] for r in rows] == ["lambertian", "estimator"]
