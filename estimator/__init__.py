"""Multi-image SVBRDF estimator (SPEC section 5): model, training loss, test-time
refinement through the renderer, and evaluation. Builds on ``kernels`` and ``materials``;
see ``DESIGN.md`` for what depends on what.

Training is a separate entry point, ``estimator.train.main(TrainConfig(...))`` or
``python -m estimator.train``, so importing the package does not import accelerate.
Evaluation from the shell: ``python -m estimator evaluate --model FOLDER``.
"""

from estimator.config import TRAINING_DEFAULTS, EstimatorConfig
from estimator.evaluate import HELDOUT_LIGHTS, evaluate, write_report
from estimator.losses import estimator_loss, map_l1
from estimator.model import SVBRDFEstimator, check_views
from estimator.refine import RefineResult, refine, refine_maps

__all__ = [
    "EstimatorConfig",
    "TRAINING_DEFAULTS",
    "SVBRDFEstimator",
    "check_views",
    "estimator_loss",
    "map_l1",
    "refine",
    "refine_maps",
    "RefineResult",
    "evaluate",
    "write_report",
    "HELDOUT_LIGHTS",
]
