"""Deterministic single-image relighting network after Bieron, Tong and Peers 2023,
"Single Image Neural Material Relighting" (the paper's Table 1 competitor; issue 6).

``model.BieronRelighter`` holds the weights; ``train`` is the thin training entry point
(``python -m relight.bieron.train``). The shipped checkpoint lives in
``weights/bieron/`` (``weights.weights_dir("bieron")``; see its ``TRAINING.md``).
"""

from relight.bieron.model import BieronRelighter

__all__ = ["BieronRelighter"]
