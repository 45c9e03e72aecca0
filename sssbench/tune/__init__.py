"""Kernels fitted through the passes (:mod:`~sssbench.tune.optimise`): above the operators
(it runs and scores them), reaching them as data through the kernel-source registry
(:mod:`sssbench.kernels.sources`), never imported by them."""
