"""Picture for the README: normal maps from 1 vs 8 inputs on held-out materials with relief.

    python estimator/results/make_normal_picture.py

Columns: flash photo (tone-mapped), ground-truth normals, normals from the flash photo
alone, from flash + 7 renders; no refinement. Normals shown as 0.5 + 2.5 * (x, y, z - 1)
around flat grey-blue, so that relief of a few degrees is visible (plain 0.5 + 0.5 n
would show all three as nearly the same flat colour).
"""

import torch

import kernels
from estimator.evaluate import EVAL_CROP_SEED
from matcap.estimate import load_estimator
from matcap.outputs import contact_sheet
from materials.dataset import EVAL_SEEDS, GroupConfig, RenderedGroups
from materials.io import write_png
from materials.io.encoding import chw_to_hwc
from materials.lights import eval_lights

torch.set_num_threads(1)
#: Exaggeration of the normal display (module docstring).
GAIN = 2.5


def show(normal: torch.Tensor) -> torch.Tensor:
    flat = torch.tensor([0.0, 0.0, 1.0])[:, None, None]
    return (0.5 + GAIN * (normal - flat)).clamp(0, 1)


model = load_estimator()
light, camera = eval_lights()
# The Table-2 materials (the crops `relight eval estimator --num 16 --size 64` scores);
# shown: the three with the most relief (largest ground-truth normal MSE to flat).
table2 = RenderedGroups(EVAL_SEEDS[:16], GroupConfig(size=64, source_size=128, seed=EVAL_CROP_SEED))
candidates = [table2.material(i) for i in range(16)]
relief = torch.stack([(m.normal[:2] ** 2).mean() for m in candidates])
rows = []
for i in relief.argsort(descending=True)[:3].tolist():
    m = candidates[i]
    imgs = kernels.render(*[t[None] for t in m.map_tensors()], light, camera)  # [1, 8, 3, H, W]
    with torch.no_grad():
        one = model(imgs[:, :1], light[None, :1], camera[None, :1])
        eight = model(imgs, light[None], camera[None])
    rows += [kernels.tonemap(imgs[0, 0]), show(m.normal), show(one.normal[0]), show(eight.normal[0])]
    print(
        f"seed {int(EVAL_SEEDS[i])}: normal MSE 1 input {float(((one.normal[0] - m.normal) ** 2).mean()):.5f}, "
        f"8 inputs {float(((eight.normal[0] - m.normal) ** 2).mean()):.5f}, "
        f"flat {float(((torch.tensor([0.0, 0, 1])[:, None, None] - m.normal) ** 2).mean()):.5f}"
    )
sheet = contact_sheet(torch.stack(rows), columns=4)
sheet = torch.nn.functional.interpolate(sheet[None], scale_factor=3, mode="nearest")[0]
write_png("estimator/results/normals_1_vs_8.png", chw_to_hwc(sheet))
