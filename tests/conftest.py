"""Shared test settings: hypothesis profile tuned for a 2-core CI machine."""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci",
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

# Brains written by tests are signed by a key of the test run, never the user's own
# (robots started by tests inherit it and trust it as their user's key).
if "PATTERNRL_HOME" not in os.environ:
    import atexit
    import shutil
    import tempfile

    os.environ["PATTERNRL_HOME"] = tempfile.mkdtemp(prefix="patternrl-home-")
    atexit.register(shutil.rmtree, os.environ["PATTERNRL_HOME"], True)  # the run's own keys
    from runtime.brain.signing import user_key

    user_key(create=True)  # before any robot starts: robots read the keys they trust once
