"""The engine keeps the behaviour it had: fixed-action rollouts of both paper scenarios (velocity mode
shielded and unshielded, torque mode shielded) end where the recorded ones did, within 1e-6.

The record (tests/golden/rollouts.npz) was made by tests/golden/make_rollouts.py on the engine
before the middle layer was redesigned; it is regenerated only for an intended behaviour change.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).with_name("golden")))
import make_rollouts  # noqa: E402

GOLDEN = np.load(make_rollouts.PATH)
TOLERANCE = 1e-6


@pytest.mark.parametrize("scenario", make_rollouts.SCENARIOS)
@pytest.mark.parametrize("setup", list(make_rollouts.SETUPS))
def test_rollout_matches_the_recorded_engine(scenario: str, setup: str) -> None:
    mode, shielded = make_rollouts.SETUPS[setup]
    env = make_rollouts.make_env(scenario, mode, shielded)
    got = make_rollouts.rollout(env, lambda e: e.unwrapped.joint_state())
    for key, value in got.items():
        expected = GOLDEN[f"{scenario}/{setup}/{key}"]
        np.testing.assert_allclose(value, expected, rtol=0, atol=TOLERANCE, err_msg=f"{scenario}/{setup}/{key}")
