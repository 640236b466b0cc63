"""Test-suite settings shared by every test module."""

import os

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
