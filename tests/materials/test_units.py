"""``materials.units``: a capture in its own units (MaterialGAN: cm, light power 1500,
1/d^2) becomes, exactly, what the models were trained on (plane of side 4, intensity pi,
no falloff), and the conversion of positions and intensity round-trips."""

import math

import pytest
import torch

import kernels
from kernels.reference import render_rtol
from materials.procedural import generate
from materials.types import Capture
from materials.units import MODEL_PLANE_SIZE, capture_units, model_gain, to_model_units

#: Both sides of each comparison are float32 renders of the same maps whose positions
#: differ by the float32 rounding of a scale (and, for the converted one, a float32
#: gain): the renderer's own float32 bound (``render_rtol`` at the roughness floor,
#: relative to the largest radiance) plus a few ulps of the gain.
CONVERSION_RTOL = render_rtol(torch.float32, 0.0993) + 1e-6


def _materialgan_capture(views=4, size=32, seed=3):
    """A MaterialGAN-geometry capture: plane 17 cm, phone 30-45 cm above, light power 1500."""
    m = generate(seed, size=size)
    gen = torch.Generator().manual_seed(seed)
    camera = torch.cat(
        [torch.rand(views, 2, generator=gen) * 20 - 10, 30 + 15 * torch.rand(views, 1, generator=gen)], 1
    )
    light = camera + torch.tensor([1.0, 0.5, 0.0])  # the flash beside the lens
    images = _render_each(m, light, camera, preset="materialgan")
    return m, Capture(images=images, light_pos=light, camera_pos=camera, preset="materialgan")


def _render_each(m, light, camera, **kw):
    """View v rendered under light v from camera v: ``[V, 3, H, W]``."""
    maps = [t[None] for t in m.map_tensors()]
    return torch.stack([kernels.render(*maps, light[v][None, None], camera[v], **kw)[0, 0] for v in range(len(light))])


def test_a_materialgan_capture_in_model_units_is_a_dgrsise_render():
    m, capture = _materialgan_capture()
    model = to_model_units(capture)
    assert model.preset == "dgrsise" and model.plane_size is None and model.intensity is None
    scale = MODEL_PLANE_SIZE / 17.0
    torch.testing.assert_close(model.light_pos, capture.light_pos * scale)
    expected = _render_each(m, model.light_pos, model.camera_pos, preset="dgrsise")
    err = float((model.images - expected).abs().max() / expected.abs().max())
    print(f"materialgan capture in model units vs a dgrsise render: {err:.1e} of the largest radiance")
    assert err < CONVERSION_RTOL
    # the raw capture is far from it: the conversion is what makes them agree
    assert float((capture.images - expected).abs().max() / expected.abs().max()) > 0.1


def test_model_intensity_renders_the_capture_in_model_units():
    m, capture = _materialgan_capture()
    units = capture_units(capture)
    assert units.plane_size == 17.0 and units.inverse_square and units.intensity == (1500.0,) * 3
    original = capture.images
    scaled = _render_each(
        m,
        capture.light_pos * units.scale,
        capture.camera_pos * units.scale,
        preset="materialgan",
        plane_size=MODEL_PLANE_SIZE,
        intensity=units.model_intensity(),
    )
    err = float((scaled - original).abs().max() / original.abs().max())
    assert err < CONVERSION_RTOL


def test_a_capture_already_in_model_units_is_unchanged():
    gen = torch.Generator().manual_seed(0)
    images = torch.rand(2, 3, 8, 8, generator=gen)
    light = torch.tensor([[0.0, 0.0, 4.0], [1.0, -1.0, 5.0]])
    capture = Capture(images=images, light_pos=light, camera_pos=light.clone())
    model = to_model_units(capture)
    torch.testing.assert_close(model.images, images, rtol=1e-6, atol=0)  # gain pi / pi
    torch.testing.assert_close(model.light_pos, light)


def test_gain_is_pi_d_squared_over_intensity_per_pixel_and_channel():
    light = torch.tensor([[1.0, -1.0, 3.0]])
    gain = model_gain(light, (2, 4), 4.0, (2.0, 4.0, 8.0), True)
    # pixel (row 1, col 3): x = (3.5 / 4 - 0.5) * 4 = 1.5, y = -(1.5 / 2 - 0.5) * 4 = -1
    d2 = (1.0 - 1.5) ** 2 + 0.0**2 + 9.0
    assert gain.shape == (1, 3, 2, 4)
    assert gain[0, :, 1, 3].tolist() == pytest.approx([math.pi * d2 / i for i in (2.0, 4.0, 8.0)])
    flat = model_gain(light, (2, 4), 4.0, (2.0, 4.0, 8.0), False)
    assert flat[0, :, 0, 0].tolist() == pytest.approx([math.pi / i for i in (2.0, 4.0, 8.0)])
