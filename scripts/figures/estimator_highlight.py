"""Picture for the README: diffuse maps from 1 vs 8 inputs on strongly specular held-out materials.

python estimator/results/make_highlight_picture.py
"""

import torch

import kernels
from matcap.estimate import load_estimator
from matcap.outputs import contact_sheet
from materials.io import write_png
from materials.io.encoding import chw_to_hwc
from materials.lights import eval_lights
from materials.procedural import generate

torch.set_num_threads(1)

model = load_estimator()
light, camera = eval_lights()
rows = []
for seed in [10000004, 10000015, 10000013]:
    m = generate(seed, size=64)
    maps = [t[None] for t in m.map_tensors()]
    imgs = kernels.render(*maps, light, camera)  # [1,8,3,H,W]
    with torch.no_grad():
        one = model(imgs[:, :1], light[None, :1], camera[None, :1])
        eight = model(imgs, light[None], camera[None])
    rows += [
        kernels.tonemap(imgs[0, 0]),
        kernels.srgb_encode(m.diffuse),
        kernels.srgb_encode(one.diffuse[0]),
        kernels.srgb_encode(eight.diffuse[0]),
    ]
sheet = contact_sheet(torch.stack(rows), columns=4)
sheet = torch.nn.functional.interpolate(sheet[None], scale_factor=3, mode="nearest")[0]
write_png("estimator/results/highlight_diffuse.png", chw_to_hwc(sheet))
print("ok")
