"""Scoring a result against the reference: image metrics (:mod:`~sssbench.score.metrics`),
skill and visibility (:mod:`~sssbench.score.verdict`), the error budget
(:mod:`~sssbench.score.budget`), a stochastic method's bias and noise
(:mod:`~sssbench.score.bias_noise`) and preview strips (:mod:`~sssbench.score.previews`)."""
