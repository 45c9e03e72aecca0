"""Hypothesis profiles of the API fuzzer (``tests/reliability/test_fuzz.py``).

- ``ci`` (default): deterministic (``derandomize=True``, no example database, no deadline), a
  few examples per property so the whole fuzzer file runs in about two minutes on one core;
- ``long``: ``HYPOTHESIS_PROFILE=long``, 25× the examples, randomised (a different search
  each run; a failure prints its reproducing ``@reproduce_failure`` blob).

The fuzzer applies the chosen profile to its own tests only (``FUZZ`` in ``test_fuzz.py``),
so loading it does not change the settings of other hypothesis tests of the session.
"""

from __future__ import annotations

from hypothesis import HealthCheck, settings

#: examples per property under ``ci`` (a property's weight multiplies it)
CI_EXAMPLES = 12
_SLOW = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much]

settings.register_profile(
    "ci",
    max_examples=CI_EXAMPLES,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=_SLOW,
    print_blob=True,
)
settings.register_profile(
    "long",
    max_examples=25 * CI_EXAMPLES,
    derandomize=False,
    database=None,
    deadline=None,
    suppress_health_check=_SLOW,
    print_blob=True,
)
