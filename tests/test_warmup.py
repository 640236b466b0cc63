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


@pytest.mark.slow
def test_warmup_compiles_a_kind_once_and_says_so(tmp_path) -> None:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    cmd = [sys.executable, "-m", "pan1_env", "warmup", "--kinds", "3p"]
    first, second = (subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900) for _ in range(2))
    assert first.returncode == 0 and second.returncode == 0, first.stderr[-2000:] + second.stderr[-2000:]
    assert "compiling the sub-step kernel for arms of 3 links, passive first joint (PA2)" in first.stderr
    assert "compil" not in second.stderr and "kernels ready" in second.stdout


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
