"""Rendered training groups: shapes, light ranges, determinism, and one batch checked
against the pure-torch reference renderer."""

import torch
from torch.utils.data import DataLoader

import kernels
import kernels.reference as ref
from materials.dataset import EVAL_SEEDS, TRAIN_SEEDS, GroupConfig, RenderedGroups, scale_and_crop
from materials.lights import (
    EVAL_LIGHTS,
    TRAIN_CAMERA_HEIGHT,
    TRAIN_LIGHT_HEIGHT,
    TRAIN_LIGHT_XY,
    eval_lights,
    sample_paper_lights,
)
from materials.procedural import generate
from materials.types import Material

CFG = GroupConfig(size=32, views=8, source_size=64)


def test_item_shapes_and_ranges():
    item = RenderedGroups(TRAIN_SEEDS, CFG)[5]
    assert item["images"].shape == (8, 3, 32, 32)
    assert item["light_pos"].shape == (8, 3) and item["camera_pos"].shape == (8, 3)
    assert item["maps"].shape == (10, 32, 32)
    assert torch.isfinite(item["images"]).all() and (item["images"] >= 0).all()
    Material.from_stacked(item["maps"]).validate()


def test_paper_light_ranges():
    gen = torch.Generator().manual_seed(0)
    for _ in range(50):
        light, camera = sample_paper_lights(8, gen)
        assert torch.equal(light[0], camera[0]), "view 0 is lit from the camera"
        assert (camera[:, :2] == 0).all()
        assert TRAIN_CAMERA_HEIGHT[0] <= camera[0, 2] <= TRAIN_CAMERA_HEIGHT[1]
        assert ((light[1:, :2] >= TRAIN_LIGHT_XY[0]) & (light[1:, :2] <= TRAIN_LIGHT_XY[1])).all()
        assert ((light[1:, 2] >= TRAIN_LIGHT_HEIGHT[0]) & (light[1:, 2] <= TRAIN_LIGHT_HEIGHT[1])).all()


def test_eval_set_is_fixed():
    light, camera = eval_lights()
    assert light.shape == (8, 3) and len(EVAL_LIGHTS) == 7
    assert torch.equal(light[0], camera[0])
    assert set(EVAL_SEEDS).isdisjoint(range(2_000_000)) and max(TRAIN_SEEDS) < min(EVAL_SEEDS)


def test_deterministic_items():
    a = RenderedGroups(TRAIN_SEEDS, CFG)[3]
    b = RenderedGroups(TRAIN_SEEDS, CFG)[3]
    c = RenderedGroups(TRAIN_SEEDS, GroupConfig(size=32, views=8, source_size=64, seed=1))[3]
    assert torch.equal(a["images"], b["images"]) and torch.equal(a["light_pos"], b["light_pos"])
    assert not torch.equal(a["light_pos"], c["light_pos"])


def test_batch_matches_reference_renderer():
    """The batch's images are its maps rendered under its lights: the float32 images
    against the reference renderer in float64 on the same maps and positions, within the
    float32 error bound of the rendering formula (``kernels.reference.render_rtol``, at the
    smallest roughness the BRDF sees: these materials go down to the 0.0993 floor)."""
    loader = DataLoader(RenderedGroups(TRAIN_SEEDS, CFG), batch_size=2)
    batch = next(iter(loader))
    assert batch["images"].shape == (2, 8, 3, 32, 32) and batch["images"].dtype == torch.float32
    maps = Material.from_stacked(batch["maps"])
    tensors = maps.map_tensors()
    expected = ref.render(*(t.double() for t in tensors), batch["light_pos"].double(), batch["camera_pos"].double())
    floor = kernels.get_preset(CFG.preset).roughness_floor
    rtol = ref.render_rtol(torch.float32, max(float(tensors[2].min()), floor))
    err = float((batch["images"].double() - expected).abs().max())
    assert err <= rtol * float(expected.abs().max()), (err, rtol, float(expected.abs().max()))


def test_scale_and_crop_keeps_valid_maps():
    material = generate(11, size=64)
    gen = torch.Generator().manual_seed(0)
    crop = scale_and_crop(material, 24, gen, min_scale=0.5)
    assert crop.shape == (24, 24)
    crop.validate()
