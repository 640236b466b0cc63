"""Figures and frames: what a reader sees (no simulation: synthetic trajectories and states)."""

from types import SimpleNamespace

import numpy as np
import pytest

from pan1_env import figures, scenario
from pan1_env.dynamics import end_effector
from pan1_env.render import Renderer


def _trajectory(sc, spike: float) -> dict[str, np.ndarray]:
    """10 s of a smooth ±0.8 rad/s velocity record with ``spike`` rad/s on arm 3, joint 2 at t = 0.05 s."""
    t = np.arange(0.0, 10.0 + 1e-9, 0.01)
    N, n_max = sc.n_arms, max(a.n_links for a in sc.arms)
    qd = np.full((len(t), N, n_max), np.nan)
    for i, arm in enumerate(sc.arms):
        qd[:, i, : arm.n_links] = 0.8 * np.sin(t + i)[:, None]
    qd[5, 2, 1] = spike
    q = np.where(np.isnan(qd), np.nan, 0.0)
    p_end = np.broadcast_to(np.array([a.base for a in sc.arms]), (len(t), N, 2)).copy()
    return {"time": t, "q": q, "qd": qd, "p_end": p_end,
            "edge_error": np.zeros((len(t), len(sc.formation.distances)))}


def test_velocity_panel_clips_the_start_transient_and_names_the_peak() -> None:
    sc = scenario.load("paper_pa_mixed_square")
    fig = figures.run_figure(sc, _trajectory(sc, 16.3))
    ax = fig.axes[1]
    assert ax.get_title() == "(b) joint velocities"
    lo, hi = ax.get_ylim()
    assert -1.0 < lo < -0.8 and 0.8 < hi < 1.0  # the smooth data after 0.5 s, not the spike
    notes = [t.get_text() for t in ax.texts]
    assert len(notes) == 1 and "clipped" in notes[0]
    assert "+16.3 rad/s (arm 3 joint 2, t = 0.05 s)" in notes[0]
    figures._pyplot().close(fig)


def test_velocity_panel_without_a_transient_is_not_clipped() -> None:
    sc = scenario.load("paper_pa_mixed_square")
    fig = figures.run_figure(sc, _trajectory(sc, 0.5))
    ax = fig.axes[1]
    assert ax.get_ylim()[1] >= 0.8 and not ax.texts
    figures._pyplot().close(fig)


@pytest.mark.parametrize("name", ["paper_pa3_square", "paper_pa_mixed_square"])
def test_frames_number_the_arms_from_one_like_the_figures(name: str) -> None:
    sc = scenario.load(name)
    n_max = max(a.n_links for a in sc.arms)
    q = np.zeros((sc.n_arms, n_max))
    for i, q0 in enumerate(sc.q0):
        q[i, : len(q0)] = q0
    P = np.array([end_effector(arm, q0) for arm, q0 in zip(sc.arms, sc.q0, strict=True)])
    # what the renderer reads of an env (the edge colours compare with the env's success tolerance)
    env = SimpleNamespace(scenario=sc, joint_state=lambda: (q, np.zeros_like(q)), end_effectors=lambda: P,
                          num_steps=0, dt=0.05, config=SimpleNamespace(success_tolerance=0.01))
    renderer = Renderer()
    try:
        frame = renderer.draw(env)
        assert frame.ndim == 3
        assert [t.get_text() for t in renderer.ax.texts] == [str(i) for i in range(1, sc.n_arms + 1)]
    finally:
        renderer.close()


def _bench_row(policy: str, shield: bool, success: float, time: float | None, cost: float) -> dict:
    return {"scenario": "paper_pa3_square", "policy": policy, "shield": shield, "episodes": 2,
            "success_rate": success, "mean_time_to_formation_s": time, "mean_return": -1.0, "total_cost": cost,
            "min_clearance_m": 0.1, "intervention_rate": 0.0 if shield else None,
            "fallback_steps": 0 if shield else None}


def test_the_benchmark_figure_draws_the_table_with_axes_from_zero() -> None:
    from pan1_env.baselines.benchmark import benchmark_figure

    rows = [_bench_row("reference", True, 1.0, 31.5, 0.0), _bench_row("zero", True, 0.0, None, 0.0),
            _bench_row("reference", False, 0.5, 20.0, 0.0)]
    fig = benchmark_figure(rows)
    success, time, cost = fig.axes
    assert "time to formation" in time.get_title()
    assert [p.get_height() for p in time.patches] == [31.5, 0.0, 20.0]
    assert [t.get_text() for t in time.texts] == ["never"]  # the row without a success, not a zero bar
    assert time.get_ylim()[0] == 0 and time.get_ylim()[1] >= 31.5
    assert cost.get_ylim() == (0.0, 1.0)  # all-zero costs: not a −0.04…0.04 axis
    assert [p.get_height() for p in success.patches] == [1.0, 0.0, 0.5]
    rows[2]["total_cost"] = 7.0
    cost = benchmark_figure(rows).axes[2]
    assert cost.get_ylim()[0] == 0 and cost.get_ylim()[1] >= 7.0
