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


def pytest_configure(config) -> None:
    """Under xdist's default ``--dist load``, hand each worker its next test only as it finishes one
    (``--maxschedchunk 1``, unless given) rather than a block of consecutive ones: with the slow tests first
    (below), a first block of a hundred-odd items would give one worker all of them."""
    if config.pluginmanager.hasplugin("xdist") and config.getoption("maxschedchunk", None) is None:
        config.option.maxschedchunk = 1


def pytest_collection_modifyitems(config, items) -> None:
    """The slow tests first, each module's in file order, then the rest: the minutes-long tests share the
    workers from the start and the run ends on short ones, where in file order one worker sat idle for
    minutes while the other worked through test_soak's and test_specialise's slow tests."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)  # stable: file order within each group
