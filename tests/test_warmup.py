"""``pan1-env warmup``: the arm-kind syntax, and the warm-up of a kind into an empty numba cache."""

import os
import subprocess
import sys

import pytest

from pan1_env.warmup import _kinds_team, parse_kind


def test_kinds_are_links_then_p_or_f() -> None:
    assert parse_kind("4p") == (4, True) and parse_kind(" 2F ") == (2, False)
    for bad in ("4", "p4", "1p", "4x", "4pf", ""):
        with pytest.raises(ValueError, match="LINKS"):
            parse_kind(bad)
    # one random team holds every kind: passive arms first, as the generator numbers them
    assert _kinds_team([(2, False), (5, True), (2, False)]) == {"n_arms": 2, "links": (5, 2), "passive_fraction": 0.5}
    assert _kinds_team([(3, True)]) == {"n_arms": 2, "links": (3, 3), "passive_fraction": 1.0}


def test_cli_rejects_a_bad_kind() -> None:
    proc = subprocess.run([sys.executable, "-m", "pan1_env", "warmup", "--kinds", "4x"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2 and "arm kind '4x'" in proc.stderr


# after a warmup: steps a kind's team once on one copy (the serial kernel) and on 128 copies (256 arms of the
# kind: the multi-threaded kernels); says which kernel each engine chose and what numba loaded or compiled
_AFTER_WARMUP = r"""
import numpy as np
from pan1_env import kernels
from pan1_env.environment import parallel_env
from pan1_env.vector import Pan1VectorEnv
env = parallel_env("random", random_options=TEAM)
env.reset(seed=0)
env.step({a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents})
print("serial", [kind.specialised for kind in env.unwrapped.engine.kinds])
venv = Pan1VectorEnv("random", num_envs=128, random_options=TEAM)
venv.reset(seed=0)
venv.step(np.zeros(venv.action_space.shape, np.float32))
print("chunks", [venv.core.engine.chunks(len(kind.q)) > 0 for kind in venv.core.engine.kinds])
for name in ("group_advance", "group_advance_parallel"):
    stats = getattr(kernels, name).stats
    print(name, "loaded", len(stats.cache_hits), "compiled", len(stats.cache_misses))
"""


@pytest.mark.slow
def test_warmup_builds_what_the_views_use(tmp_path) -> None:
    """``pan1-env warmup`` compiles a kind's serial and multi-threaded kernels (saying so); a later process
    loads both from the cache, steps the kind on its own kernel and prints no notice."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PAN1_ENV_KERNELS="auto")
    warm = subprocess.run([sys.executable, "-m", "pan1_env", "warmup", "--kinds", "2f"], env=env,
                          capture_output=True, text=True, timeout=900)
    assert warm.returncode == 0, warm.stderr[-2000:]
    assert "compiling the sub-step kernel for arms of 2 links, fully actuated:" in warm.stderr
    assert "compiling the sub-step kernel for arms of 2 links, fully actuated (multi-threaded)" in warm.stderr
    team = repr(_kinds_team([parse_kind("2f")]))
    after = subprocess.run([sys.executable, "-c", _AFTER_WARMUP.replace("TEAM", team)], env=env,
                           capture_output=True, text=True, timeout=600)
    assert after.returncode == 0, after.stderr[-2000:]
    assert "pan1_env:" not in after.stderr, "a notice after the warmup: " + after.stderr[-2000:]
    lines = after.stdout.splitlines()
    assert lines[0] == "serial [True]", "the kind's own kernel, from the cache: " + after.stdout
    assert lines[1] == "chunks [True]", "256 arms of the kind: the multi-threaded kernel: " + after.stdout
    assert lines[2:] == ["group_advance loaded 1 compiled 0", "group_advance_parallel loaded 1 compiled 0"], \
        after.stdout


def test_notice_reaches_the_user_whatever_the_logging_setup(capsys, caplog) -> None:
    import logging

    from pan1_env.compile_notice import notify

    # a root handler at WARNING (what a library's first logging.warning sets up) must not swallow it
    with caplog.at_level(logging.WARNING):
        notify("compiling X")
    assert "pan1_env: compiling X" in capsys.readouterr().err and not caplog.records
    # an application that shows INFO from pan1_env gets it through logging instead
    with caplog.at_level(logging.INFO, logger="pan1_env"):
        notify("compiling Y")
    assert [r.getMessage() for r in caplog.records] == ["compiling Y"] and not capsys.readouterr().err
