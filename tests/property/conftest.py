"""Hypothesis profiles of the property-based tests.

* ``ci`` (selected when the environment variable CI is set): a fixed number of examples per
  test, derandomised (the same examples every run, so CI is reproducible), no deadline (shared
  runners are slow).
* ``dev`` (the default): the same number of examples, random, so local runs keep exploring.
* ``thorough``: 20x the examples, for a fuzzing session: ``ABYSSAL_HYPOTHESIS_PROFILE=thorough``.
* ``debug``: like ``dev`` but shrinks a failing example to a minimal one (slow when a test fails).

``ci`` and ``dev`` skip shrinking: a failure is reported with the first failing example, so a
failing (or xfail) test costs no more than a passing one.

The whole folder is kept to well under a minute on 2 cores with ``ci``/``dev``.
"""
from __future__ import annotations

import os

from hypothesis import HealthCheck, Phase, settings

EXAMPLES = 40
_common = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
_no_shrink = (Phase.explicit, Phase.reuse, Phase.generate)
settings.register_profile("ci", max_examples=EXAMPLES, derandomize=True, print_blob=True, phases=_no_shrink, **_common)
settings.register_profile("dev", max_examples=EXAMPLES, phases=_no_shrink, **_common)
settings.register_profile("debug", max_examples=EXAMPLES, **_common)
settings.register_profile("thorough", max_examples=20 * EXAMPLES, **_common)
settings.load_profile(os.environ.get("ABYSSAL_HYPOTHESIS_PROFILE") or ("ci" if os.environ.get("CI") else "dev"))
