"""Relighting: one flash photo -> the same material under new point lights (SPEC section 4).

Layout and dependency direction (each layer imports only those to its left)::

    kernels, materials  <-  relight.interface  <-  relight.bieron, relight.diffusion
                                               <-  relight.evaluate (metrics: materials.metrics)
                                               <-  matcap (command line)

- ``relight.interface``: the ``Relighter`` contract every method implements
  (``relight(photo, light_pos, camera_pos, *, generator) -> [B, K, 3, H, W]`` linear radiance),
  boundary validation, the ``input`` and ``lambertian`` baselines and the open registry
  (``get_relighter``, ``register_relighter``).
- ``relight.bieron``: the deterministic single-image relighting network after Bieron,
  Tong and Peers 2023 (the paper's Table 1 competitor), its thin training entry point
  and checkpoints; shipped weights in ``weights/bieron``.
- ``relight.evaluate``: Table-1-style evaluation on held-out procedural materials
  (``relight eval relighting``), with the image metrics of ``materials.metrics``.

Nothing is imported here, so ``import relight.interface`` stays light.
"""
