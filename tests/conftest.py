"""Test-wide settings: hypothesis is deterministic under CI.

With ``CI`` set (`.ci/run` sets it) every property test draws the same examples on every run
and machine (``derandomize``), and no example database carries state from one run to the next,
so a red CI is a finding that reproduces, never chance. Elsewhere hypothesis explores new
examples each run, which is how new findings come up; a failure prints the seed and blob that
rebuild it. Tests' own ``@settings`` override a profile field by field.
"""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
settings.register_profile("dev", print_blob=True)
settings.load_profile("ci" if os.environ.get("CI") else "dev")
