"""The common relighting interface: every registered relighter answers the same call with
``[B, K, 3, H, W]``; the Lambertian baseline is exact where its assumptions hold; bad
input is rejected at the boundary, naming the argument."""

import pytest
import torch

import kernels
from materials.lights import eval_lights
from relight.interface import (
    LambertianRelighter,
    Relighter,
    get_relighter,
    register_relighter,
    relighter_names,
)

#: Lambertian relighting vs the renderer on a flat, purely diffuse material (F0 = 0,
#: roughness 1). Not exact to float precision: the SPEC's Schlick Fresnel is
#: 2^((-5.55473 v.h - 6.98316) v.h) > 0 even at F0 = 0, a specular remainder of
#: ~1e-3 * D * G / 4; measured max error 4.3e-5 at the evaluation lights.
LAMBERTIAN_ATOL = 1e-4


def _call(b: int = 2, k: int = 3, size: int = 16):
    photo = torch.rand(b, 3, size, size)
    camera = torch.tensor([0.0, 0.0, 4.0]).expand(b, 3).clone()
    lights = torch.tensor([[1.0, 1.0, 4.0], [-2.0, 0.5, 5.0], [0.0, -1.0, 7.0]])[:k].expand(b, k, 3).clone()
    return photo, camera, lights


def _all(tiny_checkpoint):
    return {
        name: get_relighter(name, tiny_checkpoint if name == "bieron" else None)
        for name in ("input", "lambertian", "bieron")
    }


def test_every_relighter_answers_the_same_call(tiny_checkpoint):
    photo, camera, lights = _call()
    for name, relighter in _all(tiny_checkpoint).items():
        assert isinstance(relighter, Relighter)
        out = relighter.relight(photo, camera, lights)
        assert out.shape == (2, 3, 3, 16, 16), name
        assert out.dtype == photo.dtype and torch.isfinite(out).all() and (out >= 0).all(), name


def test_network_pads_sizes_that_are_not_multiples(tiny_checkpoint):
    photo, camera, lights = _call(b=1, k=2, size=15)
    assert get_relighter("bieron", tiny_checkpoint).relight(photo, camera, lights).shape == (1, 2, 3, 15, 15)


def test_input_baseline_returns_the_photo():
    photo, camera, lights = _call()
    out = get_relighter("input").relight(photo, camera, lights)
    assert torch.equal(out, photo[:, None].expand_as(out))


def test_lambertian_is_exact_on_a_flat_diffuse_material():
    torch.manual_seed(0)
    b, size = 2, 32
    diffuse = torch.rand(b, 3, size, size)
    normal = torch.zeros(b, 3, size, size)
    normal[:, 2] = 1
    roughness = torch.ones(b, 1, size, size)
    specular = torch.zeros(b, 3, size, size)
    light, camera = eval_lights()
    images = kernels.render(diffuse, normal, roughness, specular, light, camera)
    out = LambertianRelighter().relight(images[:, 0], camera[None, 0].expand(b, 3), light[None, 1:].expand(b, 7, 3))
    torch.testing.assert_close(out, images[:, 1:], rtol=0, atol=LAMBERTIAN_ATOL)


def test_lambertian_with_falloff_matches_the_materialgan_preset():
    b, size = 1, 16
    diffuse = torch.full((b, 3, size, size), 0.5)
    normal = torch.zeros(b, 3, size, size)
    normal[:, 2] = 1
    light = torch.tensor([[0.0, 0.0, 30.0], [5.0, -3.0, 25.0]])
    camera = torch.tensor([0.0, 0.0, 30.0])
    images = kernels.render(
        diffuse,
        normal,
        torch.ones(b, 1, size, size),
        torch.zeros(b, 3, size, size),
        light,
        camera,
        preset="materialgan",
    )
    out = LambertianRelighter("materialgan").relight(images[:, 0], camera[None], light[None, 1:])
    torch.testing.assert_close(out, images[:, 1:], rtol=1e-3, atol=LAMBERTIAN_ATOL)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda p, c, l: (p[:, :1], c, l), "3 (RGB) channels"),
        (lambda p, c, l: (p[0], c, l), "photo must have shape [B, 3, H, W]"),
        (lambda p, c, l: (p.masked_fill(p > 0.5, float("nan")), c, l), "photo holds NaN"),
        (lambda p, c, l: (-p, c, l), "negative"),
        (lambda p, c, l: (p, c, l * torch.tensor([1.0, 1.0, -1.0])), "lights has a position on or below"),
        (lambda p, c, l: (p, c * torch.tensor([1.0, 1.0, 0.0]), l), "camera has a position on or below"),
        (lambda p, c, l: (p, c[:1], l), "camera must have shape [B, 3]"),
        (lambda p, c, l: (p, c, l[..., :2]), "lights must have shape [B, K, 3]"),
        (lambda p, c, l: (p, c, l[0]), "lights must have shape [B, K, 3]"),
        (lambda p, c, l: (p, c, l[:, :0]), "at least one target light"),
    ],
)
def test_bad_input_names_the_argument(change, message):
    args = change(*_call())
    with pytest.raises(
        ValueError, match=message.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(").replace(")", r"\)")
    ):
        LambertianRelighter().relight(*args)


def test_wrong_dtype_is_a_type_error():
    photo, camera, lights = _call()
    with pytest.raises(TypeError, match="photo"):
        LambertianRelighter().relight(photo.half(), camera, lights)


def test_registry_is_open_and_names_unknowns():
    with pytest.raises(ValueError, match="unknown relighter 'no_such_model'"):
        get_relighter("no_such_model")
    with pytest.raises(ValueError, match="takes no checkpoint"):
        get_relighter("input", "some/folder")

    class Half(Relighter):
        def _relight(self, photo, camera, lights, *, generator=None):
            return 0.5 * photo[:, None].expand(-1, lights.shape[1], -1, -1, -1)

    register_relighter("half_for_test", lambda checkpoint=None: Half())
    try:
        assert "half_for_test" in relighter_names()
        photo, camera, lights = _call()
        assert get_relighter("half_for_test").relight(photo, camera, lights).shape == (2, 3, 3, 16, 16)
    finally:
        from relight import interface

        interface._REGISTRY.pop("half_for_test")


def test_missing_checkpoint_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="no BieronRelighter checkpoint"):
        get_relighter("bieron", tmp_path)
