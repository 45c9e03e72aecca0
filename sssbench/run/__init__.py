"""One run, end to end (DESIGN §6): a run's specification (:mod:`~sssbench.run.spec`), the
registry of names (:mod:`~sssbench.run.registry`), the runner and its steps
(:mod:`~sssbench.run.runner`: :func:`~sssbench.run.runner.execute`; the steps in
:mod:`~sssbench.run.settings`, :mod:`~sssbench.run.inputs`, :mod:`~sssbench.run.stochastic`,
:mod:`~sssbench.run.budget_step`, :mod:`~sssbench.run.mc_step`, :mod:`~sssbench.run.record`),
the parallel warm-up of a sweep's caches (:mod:`~sssbench.run.warm`) and the in-process memo of
a sweep's per-scene work (:mod:`~sssbench.run.runmemo`)."""
