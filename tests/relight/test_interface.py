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
    """``(photo [B, 3, H, W], light_pos [B, K, 3], camera_pos [B, 3])``: one relight call."""
    photo = torch.rand(b, 3, size, size)
    light_pos = torch.tensor([[1.0, 1.0, 4.0], [-2.0, 0.5, 5.0], [0.0, -1.0, 7.0]])[:k].expand(b, k, 3).clone()
    camera_pos = torch.tensor([0.0, 0.0, 4.0]).expand(b, 3).clone()
    return photo, light_pos, camera_pos


def _all(tiny_checkpoint):
    return {
        name: get_relighter(name, tiny_checkpoint if name == "bieron" else None)
        for name in ("input", "lambertian", "bieron")
    }


def test_every_relighter_answers_the_same_call(tiny_checkpoint):
    photo, light_pos, camera_pos = _call()
    for name, relighter in _all(tiny_checkpoint).items():
        assert isinstance(relighter, Relighter)
        out = relighter.relight(photo, light_pos, camera_pos)
        assert out.shape == (2, 3, 3, 16, 16), name
        assert out.dtype == photo.dtype and torch.isfinite(out).all() and (out >= 0).all(), name


def test_network_pads_sizes_that_are_not_multiples(tiny_checkpoint):
    photo, light_pos, camera_pos = _call(b=1, k=2, size=15)
    assert get_relighter("bieron", tiny_checkpoint).relight(photo, light_pos, camera_pos).shape == (1, 2, 3, 15, 15)


def test_input_baseline_returns_the_photo():
    photo, light_pos, camera_pos = _call()
    out = get_relighter("input").relight(photo, light_pos, camera_pos)
    assert torch.equal(out, photo[:, None].expand_as(out))


def test_lambertian_is_exact_on_a_flat_diffuse_material():
    torch.manual_seed(0)
    b, size = 2, 32
    diffuse = torch.rand(b, 3, size, size)
    normal = torch.zeros(b, 3, size, size)
    normal[:, 2] = 1
    roughness = torch.ones(b, 1, size, size)
    specular = torch.zeros(b, 3, size, size)
    light_pos, camera_pos = eval_lights()
    images = kernels.render(diffuse, normal, roughness, specular, light_pos, camera_pos)
    out = LambertianRelighter().relight(
        images[:, 0], light_pos[None, 1:].expand(b, 7, 3), camera_pos[None, 0].expand(b, 3)
    )
    torch.testing.assert_close(out, images[:, 1:], rtol=0, atol=LAMBERTIAN_ATOL)


def test_lambertian_with_falloff_matches_the_materialgan_preset():
    b, size = 1, 16
    diffuse = torch.full((b, 3, size, size), 0.5)
    normal = torch.zeros(b, 3, size, size)
    normal[:, 2] = 1
    light_pos = torch.tensor([[0.0, 0.0, 30.0], [5.0, -3.0, 25.0]])
    camera_pos = torch.tensor([0.0, 0.0, 30.0])
    images = kernels.render(
        diffuse,
        normal,
        torch.ones(b, 1, size, size),
        torch.zeros(b, 3, size, size),
        light_pos,
        camera_pos,
        preset="materialgan",
    )
    out = LambertianRelighter("materialgan").relight(images[:, 0], light_pos[None, 1:], camera_pos[None])
    torch.testing.assert_close(out, images[:, 1:], rtol=1e-3, atol=LAMBERTIAN_ATOL)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda p, l, c: (p[:, :1], l, c), "photo must have shape [B, 3, H, W], got (2, 1, 16, 16): dim 1 is 1"),
        (lambda p, l, c: (p[0], l, c), "photo must have shape [B, 3, H, W], got (3, 16, 16): 3 dims"),
        (lambda p, l, c: (p.masked_fill(p > 0.5, float("nan")), l, c), "photo holds"),
        (lambda p, l, c: (-p, l, c), "negative"),
        (lambda p, l, c: (p, l * torch.tensor([1.0, 1.0, -1.0]), c), "light_pos has a position on or below"),
        (lambda p, l, c: (p, l, c * torch.tensor([1.0, 1.0, 0.0])), "camera_pos has a position on or below"),
        (lambda p, l, c: (p, l, c[:1]), "camera_pos must have shape [B, 3], got (1, 3): B is 1, but 2 in photo"),
        (lambda p, l, c: (p, l[..., :2], c), "light_pos must have shape [B, K, 3], got (2, 3, 2): dim 2 is 2"),
        (lambda p, l, c: (p, l[0], c), "light_pos must have shape [B, K, 3], got (3, 3): 2 dims"),
        (lambda p, l, c: (p, l[:, :0], c), "at least one target light"),
    ],
)
def test_bad_input_names_the_argument(change, message):
    args = change(*_call())
    with pytest.raises(
        ValueError, match=message.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(").replace(")", r"\)")
    ):
        LambertianRelighter().relight(*args)


def test_nan_photo_is_counted():
    photo, light_pos, camera_pos = _call()
    photo[0, 0, 0, :3] = float("nan")
    with pytest.raises(ValueError, match=r"photo holds 3 NaN or inf value"):
        LambertianRelighter().relight(photo, light_pos, camera_pos)


def test_wrong_dtype_or_type_is_a_type_error():
    photo, light_pos, camera_pos = _call()
    with pytest.raises(TypeError, match="photo must be float32 or float64, got torch.float16"):
        LambertianRelighter().relight(photo.half(), light_pos, camera_pos)
    with pytest.raises(TypeError, match="light_pos must be a torch.Tensor, got list"):
        LambertianRelighter().relight(photo, light_pos.tolist(), camera_pos)


def test_registry_is_open_and_names_unknowns():
    with pytest.raises(ValueError, match="unknown relighter 'no_such_model'"):
        get_relighter("no_such_model")
    with pytest.raises(ValueError, match="takes no checkpoint"):
        get_relighter("input", "some/folder")

    class Half(Relighter):
        def _relight(self, photo, light_pos, camera_pos, *, generator=None):
            return 0.5 * photo[:, None].expand(-1, light_pos.shape[1], -1, -1, -1)

    register_relighter("half_for_test", lambda checkpoint=None: Half())
    try:
        assert "half_for_test" in relighter_names()
        photo, light_pos, camera_pos = _call()
        assert get_relighter("half_for_test").relight(photo, light_pos, camera_pos).shape == (2, 3, 3, 16, 16)
    finally:
        from relight import interface

        interface._REGISTRY.pop("half_for_test")


def test_missing_checkpoint_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="no BieronRelighter checkpoint"):
        get_relighter("bieron", tmp_path)
