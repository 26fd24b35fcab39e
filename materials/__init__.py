"""Material data: the SVBRDF / capture data model, file formats, the procedural
generator and rendered training batches. Builds on ``kernels``; knows nothing of the
models (``relight``, ``estimator``) that use it."""

from materials.types import MAP_CHANNELS, Capture, MapError, Material

__all__ = ["Material", "Capture", "MapError", "MAP_CHANNELS"]
