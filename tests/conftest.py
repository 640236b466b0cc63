"""Test-suite settings shared by every test module."""

import os

# The suite steps each arm kind with its own kernel (compiled once per kind, then loaded from numba's
# cache), not with the generic kernel and a background compilation per process, which would only add
# processes: tests/test_specialise.py and tests/test_determinism.py cover those, setting this themselves.
os.environ.setdefault("PAN1_ENV_KERNELS", "specialised")

try:
    from hypothesis import settings
except ImportError:  # the RLlib venv runs one module and may lack hypothesis
    settings = None

if settings is not None:
    # CI (and .ci/run, which sets CI=true) runs the property tests on hypothesis' fixed example sequence,
    # so a fresh machine's verdict does not depend on the day's random draw; a local run explores new
    # examples every time (PAN1_HYPOTHESIS_EXAMPLES / PAN1_FUZZ_EXAMPLES raise the counts).
    settings.register_profile("ci", derandomize=True, print_blob=True)
    if os.environ.get("CI"):
        settings.load_profile("ci")
