"""Boundary validation of the public kernel functions: a clear TypeError (type, dtype,
unknown keyword) or ValueError (shape, values) that names the offending argument, raised
before any kernel launches.
"""

from __future__ import annotations

import pytest
import torch

import kernels
from kernels.checks import check_finite


@pytest.fixture
def good(make_maps, make_positions):
    """Valid render arguments: B=2, 4x5 maps, K=3 lights, one camera."""
    return {
        "maps": make_maps(2, 4, 5),
        "light_pos": make_positions((2, 3), seed=2),
        "camera_pos": torch.tensor([0.0, 0.0, 4.0]),
    }


def _render(good, index=None, value=None, *, light_pos=None, camera_pos=None, **kw):
    """kernels.render on the good arguments, with map ``index`` (or a position) replaced."""
    maps = list(good["maps"])
    if index is not None:
        maps[index] = value
    light = good["light_pos"] if light_pos is None else light_pos
    camera = good["camera_pos"] if camera_pos is None else camera_pos
    return kernels.render(*maps, light, camera, **kw)


# --------------------------------------------------------------------------- render: maps
@pytest.mark.parametrize(
    "index,shape,match",
    [
        (0, (2, 2, 4, 5), r"diffuse must have shape \[B, 3, H, W\], got \(2, 2, 4, 5\): dim 1 is 2, expected 3"),
        (2, (2, 3, 4, 5), r"roughness must have shape \[B, 1, H, W\], got \(2, 3, 4, 5\): dim 1 is 3"),
        (3, (2, 3, 4, 5, 1), r"specular must have shape \[B, 3, H, W\], got .*: 5 dims, expected 4"),
        (1, (2, 3, 4, 6), r"normal must have shape \[B, 3, H, W\], got \(2, 3, 4, 6\): W is 6, but 5 in diffuse"),
        (2, (1, 1, 4, 5), r"roughness must have shape .*: B is 1, but 2 in diffuse"),
    ],
)
def test_map_shapes(good, index, shape, match):
    with pytest.raises(ValueError, match=match):
        _render(good, index, torch.rand(shape))


def test_empty_maps(make_maps):
    maps = make_maps(1, 0, 5)
    with pytest.raises(ValueError, match="non-empty"):
        kernels.render(*maps, torch.tensor([[0.0, 0.0, 4.0]]), torch.tensor([0.0, 0.0, 4.0]))


def test_dtype_mismatch(good):
    with pytest.raises(TypeError, match=r"normal is torch.float64 but diffuse is torch.float32"):
        _render(good, 1, good["maps"][1].double())


@pytest.mark.parametrize("dtype", [torch.int64, torch.uint8, torch.float16, torch.bool])
def test_non_float_dtypes(good, dtype):
    with pytest.raises(TypeError, match=r"diffuse must be float32 or float64"):
        _render(good, 0, good["maps"][0].to(dtype))


def test_not_a_tensor(good):
    with pytest.raises(TypeError, match=r"specular must be a torch.Tensor, got ndarray"):
        _render(good, 3, good["maps"][3].numpy())


@pytest.mark.parametrize("index,name", [(0, "diffuse"), (1, "normal"), (2, "roughness"), (3, "specular")])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_maps_are_named(good, index, name, bad):
    t = good["maps"][index].clone()
    t[1, 0, 2, 3] = bad
    with pytest.raises(ValueError, match=rf"{name} holds 1 NaN or inf"):
        _render(good, index, t)


def test_finite_values_whose_sum_overflows_are_accepted(good):
    # check_finite tests the sum first; huge finite values overflow it to inf, and must
    # still pass (the elementwise test decides), while +inf and -inf together (sum NaN)
    # must still fail.
    t = good["maps"][0].clone()
    t[0, 0, 0, :2] = 3e38
    check_finite(diffuse=t)
    t[0, 0, 0, 0], t[0, 0, 0, 1] = float("inf"), float("-inf")
    with pytest.raises(ValueError, match=r"diffuse holds 2 NaN or inf"):
        check_finite(diffuse=t)


# --------------------------------------------------------------------------- render: positions
@pytest.mark.parametrize(
    "shape,match",
    [
        ((3, 4), r"light_pos must have shape \[3\], \[K, 3\] or \[B, K, 3\], got \(3, 4\): dim 1 is 4"),
        ((2, 3, 3, 3), r"light_pos must have shape"),
        ((5, 3, 3), r"light_pos has batch size 5, the maps have 2"),
    ],
)
def test_light_shapes(good, shape, match):
    with pytest.raises(ValueError, match=match):
        _render(good, light_pos=torch.rand(shape) + 1)


def test_camera_count_must_match_lights(good):
    with pytest.raises(ValueError, match=r"camera_pos has 2 positions, expected 1 or 3"):
        _render(good, camera_pos=torch.rand(2, 3) + 1)


def test_nan_light_and_camera_are_named(good):
    light = good["light_pos"].clone()
    light[0, 1, 2] = float("nan")
    with pytest.raises(ValueError, match=r"light_pos holds 1 NaN"):
        _render(good, light_pos=light)
    with pytest.raises(ValueError, match=r"camera_pos holds 1 NaN"):
        _render(good, camera_pos=torch.tensor([0.0, float("nan"), 4.0]))


def test_position_dtype_must_match_maps(good):
    with pytest.raises(TypeError, match=r"light_pos is torch.float64"):
        _render(good, light_pos=good["light_pos"].double())


# --------------------------------------------------------------------------- presets, overrides
def test_unknown_preset(good):
    with pytest.raises(
        ValueError, match=r"unknown preset 'mitsuba'; known: \['deschaintre', 'dgrsise', 'materialgan'\]"
    ):
        _render(good, preset="mitsuba")


def test_preset_of_wrong_type(good):
    with pytest.raises(TypeError, match=r"preset must be a name or a RenderPreset"):
        _render(good, preset=3)


def test_unknown_override_keyword(good):
    with pytest.raises(TypeError, match=r"unknown render override\(s\): \['falloff'\]"):
        _render(good, falloff=True)


@pytest.mark.parametrize(
    "overrides,match",
    [
        ({"plane_size": 0.0}, r"plane_size must be positive"),
        ({"intensity": (1.0, 2.0)}, r"intensity must be a scalar or 3 values"),
        ({"roughness_floor": 1.5}, r"roughness_floor must be in \[0, 1\)"),
    ],
)
def test_bad_override_values(good, overrides, match):
    with pytest.raises(ValueError, match=match):
        _render(good, **overrides)


def test_custom_preset_object_is_accepted(good):
    custom = kernels.get_preset("dgrsise").with_overrides(plane_size=3.0)
    out = _render(good, preset=custom)
    torch.testing.assert_close(out, _render(good, plane_size=3.0), rtol=0, atol=0)


# --------------------------------------------------------------------------- lvh_maps
def test_lvh_maps_validation():
    light = torch.tensor([[1.0, 0.0, 4.0]])
    with pytest.raises(ValueError, match=r"size must be positive"):
        kernels.lvh_maps(light, torch.tensor([0.0, 0.0, 4.0]), (0, 4))
    with pytest.raises(TypeError, match=r"camera_pos is torch.float64"):
        kernels.lvh_maps(light, torch.tensor([0.0, 0.0, 4.0], dtype=torch.float64), (4, 4))
    with pytest.raises(TypeError, match=r"light_pos must be float32 or float64"):
        kernels.lvh_maps(light.long(), torch.tensor([0.0, 0.0, 4.0]), (4, 4))


# --------------------------------------------------------------------------- translate
@pytest.mark.parametrize(
    "offsets,match",
    [
        (torch.zeros(3, 2), r"offsets must have shape \[B, 2\], got \(3, 2\): B is 3, but 2 in features"),
        (torch.zeros(2, 3), r"offsets must have shape \[B, 2\], got \(2, 3\): dim 1 is 3, expected 2"),
        (torch.zeros(2), r"offsets must have shape \[B, 2\], got \(2,\): 1 dims, expected 2"),
    ],
)
def test_translate_offsets_shape(offsets, match):
    with pytest.raises(ValueError, match=match):
        kernels.translate(torch.rand(2, 4, 5, 5), offsets)


def test_translate_features_and_dtypes():
    with pytest.raises(ValueError, match=r"features must have shape \[B, C, h, w\], got \(4, 5, 5\): 3 dims"):
        kernels.translate(torch.rand(4, 5, 5), torch.zeros(4, 2))
    with pytest.raises(TypeError, match=r"offsets is torch.float64 but features is torch.float32"):
        kernels.translate(torch.rand(2, 4, 5, 5), torch.zeros(2, 2, dtype=torch.float64))
    with pytest.raises(TypeError, match=r"features must be float32 or float64"):
        kernels.translate(torch.zeros(2, 4, 5, 5, dtype=torch.int32), torch.zeros(2, 2))
    with pytest.raises(ValueError, match=r"offsets holds 1 NaN"):
        kernels.translate(torch.rand(2, 4, 5, 5), torch.tensor([[0.0, 0.0], [float("nan"), 1.0]]))
    with pytest.raises(ValueError, match=r"features must be non-empty"):
        kernels.translate(torch.rand(2, 0, 5, 5), torch.zeros(2, 2))


def test_highlight_offsets_validation():
    cam = torch.tensor([0.0, 0.0, 4.0])
    with pytest.raises(ValueError, match=r"above the plane"):
        kernels.highlight_offsets(torch.tensor([1.0, 0.0, -1.0]), cam, 4.0, (8, 8))
    with pytest.raises(ValueError, match=r"plane_size must be positive"):
        kernels.highlight_offsets(torch.tensor([1.0, 0.0, 4.0]), cam, 0.0, (8, 8))


# --------------------------------------------------------------------------- losses
def test_rendering_loss_target_shape(good):
    target = torch.rand(2, 3, 3, 4, 6)
    with pytest.raises(
        ValueError, match=r"target must have shape \[B, K, 3, H, W\], got \(2, 3, 3, 4, 6\): W is 6, but 5"
    ):
        kernels.rendering_loss(*good["maps"], target, good["light_pos"], good["camera_pos"])
    with pytest.raises(ValueError, match=r"target must have shape \[B, K, 3, H, W\], got \(2, 9, 4, 5\): 4 dims"):
        kernels.rendering_loss(*good["maps"], torch.rand(2, 9, 4, 5), good["light_pos"], good["camera_pos"])


def test_rendering_loss_target_values(good):
    target = torch.rand(2, 3, 3, 4, 5)
    bad = target.clone()
    bad[0, 0, 0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match=r"target holds 1 NaN"):
        kernels.rendering_loss(*good["maps"], bad, good["light_pos"], good["camera_pos"])
    with pytest.raises(ValueError, match=r"target must be > -eps"):
        kernels.rendering_loss(*good["maps"], target - 1, good["light_pos"], good["camera_pos"])
    with pytest.raises(TypeError, match=r"target is torch.float64"):
        kernels.rendering_loss(*good["maps"], target.double(), good["light_pos"], good["camera_pos"])


@pytest.mark.parametrize("name", ["log_l1_loss", "mse_loss"])
def test_image_loss_validation(name):
    fn = getattr(kernels, name)
    with pytest.raises(ValueError, match=r"x and y must have the same shape, got \(2, 3\) and \(3, 2\)"):
        fn(torch.rand(2, 3), torch.rand(3, 2))
    with pytest.raises(TypeError, match=r"y is torch.float64 but x is torch.float32"):
        fn(torch.rand(2, 3), torch.rand(2, 3, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"y holds 1 NaN"):
        fn(torch.rand(2, 3), torch.tensor([[0.0, float("nan"), 0.0], [0.0, 0.0, 0.0]]))
    with pytest.raises(ValueError, match=r"non-empty"):
        fn(torch.rand(0, 3), torch.rand(0, 3))


def test_log_l1_loss_rejects_values_below_minus_eps():
    with pytest.raises(ValueError, match=r"log_l1_loss needs x, y > -eps"):
        kernels.log_l1_loss(torch.full((2, 2), -0.5), torch.rand(2, 2))


def test_map_rendering_loss_arguments(make_maps):
    maps = make_maps(1, 4, 4)
    with pytest.raises(ValueError, match=r"pred and target must each be"):
        kernels.map_rendering_loss(maps[:3], maps)
    with pytest.raises(ValueError, match=r"give both light_pos and camera_pos, or neither"):
        kernels.map_rendering_loss(maps, maps, light_pos=torch.tensor([[0.0, 0.0, 4.0]]))
