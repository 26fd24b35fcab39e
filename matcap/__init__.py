"""The end-to-end tool: the ``relight`` command line and the pipelines behind it.

Top of the dependency graph: it uses ``kernels``, ``materials``, ``relight`` and
``estimator``; nothing imports it.
"""
