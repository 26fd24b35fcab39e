"""One training stack for the project's networks, below the model packages.

Each trainer (``relight.diffusion.train``, ``relight.bieron.train``, ``estimator.train``)
is a typed ``TrainConfig`` + ``main(cfg)`` + ``parse_args(argv)`` on top of these modules,
one job each (``DESIGN.md``):

- ``training.config``: dataclass <-> command line (help from docstrings) <-> JSON; model
  configs read from a model's constructor signature.
- ``training.checkpoint``: atomic, pickle-free checkpoints (weights, EMA, optimizer, RNG,
  history, config), ``latest`` pointer, pruning and snapshots.
- ``training.schedule``: learning-rate schedules as functions of the step.
- ``training.seeding``: seeds from (seed, step, stream), for exact resumes.
- ``training.plot``: the loss-curve PNG.
- ``training.loop``: the step loop (update, EMA, progress, logs, checkpoints, budget, signals).

Importing ``training`` imports none of them (``accelerate`` and ``matplotlib`` load only
with the modules that use them).
"""
