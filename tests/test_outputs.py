"""Output images: labelled tiles and the capture preview sheet."""

import pytest
import torch

from matcap.capture.output import _SHEET_TILE, _preview_sheet
from matcap.outputs import _LABEL_BAND_SCALE as LABEL_BAND_SCALE
from matcap.outputs import EMPTY_TILE_GREY, contact_sheet, label_tiles
from materials.types import Material

#: Rows of the label band (``matcap.outputs._LABEL_PX + 4``): the only rows a label may touch.
LABEL_BAND_ROWS = 16


def test_labels_touch_only_the_band_and_write_white_text():
    tiles = torch.full((3, 3, 64, 64), 0.5)
    out = label_tiles(tiles, ["diffuse", None, ""])
    assert torch.equal(tiles, torch.full((3, 3, 64, 64), 0.5))  # input not modified
    assert torch.equal(out[0, :, LABEL_BAND_ROWS:], tiles[0, :, LABEL_BAND_ROWS:])
    assert torch.equal(out[1:], tiles[1:])  # unlabelled tiles untouched
    band = out[0, :, :LABEL_BAND_ROWS]
    assert float(band.min()) < 0.5 * 0.5  # the band is darkened ...
    assert float(band.max()) > 0.9  # ... and carries white text


def test_labels_need_one_per_tile():
    with pytest.raises(ValueError, match="one label per tile"):
        label_tiles(torch.zeros(2, 3, 8, 8), ["a"])


def test_preview_sheet_fills_empty_slots_with_grey_not_black():
    side, k = 32, 7
    m = Material(
        torch.full((1, 3, side, side), 0.3),
        torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, side, side),
        torch.full((1, 1, side, side), 0.5),
        torch.full((1, 3, side, side), 0.04),
    )
    image = torch.full((3, side, side), 0.2)
    sheet = _preview_sheet(image, torch.rand(k, 3, 16, 16), m, m, None, torch.rand(1 + k, 3, side, side))
    t = _SHEET_TILE
    assert sheet.shape == (3, 3 * t, (1 + k) * t)
    # Row 2 holds 5 maps (no confidence with one sample); its last 3 slots are empty.
    empty = sheet[:, t : 2 * t, 5 * t :]
    assert torch.equal(empty, torch.full_like(empty, EMPTY_TILE_GREY))
    # Every map tile is labelled: left of the text (x < 3) the band is the constant map
    # darkened by the band's scale, to 8-bit rounding.
    for col in range(5):
        tile = sheet[:, t : 2 * t, col * t : (col + 1) * t]
        below = tile[:, LABEL_BAND_ROWS:, :3]
        assert torch.allclose(
            tile[:, :LABEL_BAND_ROWS, :3], below[:, :1].expand(-1, LABEL_BAND_ROWS, -1) * LABEL_BAND_SCALE, atol=1 / 255
        )


def test_contact_sheet_places_tiles_row_major():
    tiles = torch.arange(6, dtype=torch.float32).view(6, 1, 1, 1).expand(6, 3, 2, 2)
    sheet = contact_sheet(tiles, columns=3)
    assert sheet.shape == (3, 4, 6)
    assert float(sheet[0, 0, 4]) == 2 and float(sheet[0, 2, 0]) == 3
