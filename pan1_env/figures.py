"""Paper-style figures (the paper's Figures 4–8) from a recorded run, drawn headless with matplotlib.

* :func:`run_figure` – one run: (a) joint angles, (b) joint velocities, (c) edge-length errors
  ‖z_k‖ − d_k, (d) end-effector paths (× start, ∘ end) with the obstacles as red disks, the
  final formation, and for a 2-link PA arm its reachable curve (Remark 1) dashed. When the start
  transient dominates panel (b) (its whole range is more than three times that of the velocities
  after the first :data:`VELOCITY_AXIS_SKIP_S` seconds, e.g. 16 rad/s at t ≈ 0.04 s in Section
  5.2), the panel's y-axis is clipped to those later velocities and a note in the panel gives the
  off-axis peaks (value, arm, joint, time).
* :func:`obstacle_distance_figure` – for each PA arm that can reach an obstacle, its end-effector's
  distance to the nearest obstacle centre against the safety boundary r (Figure 8); several runs
  (e.g. nominal and safe) overlay.

Arms are labelled 1..N as in the paper. Matplotlib is imported only when a figure is drawn.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .dynamics import ArmParams, end_effector, mass_matrix
from .scenario import Scenario

__all__ = ["run_figure", "obstacle_distance_figure", "pa_reachable_curve", "save_figure", "VELOCITY_AXIS_SKIP_S"]

VELOCITY_AXIS_SKIP_S = 0.5  # panel (b)'s y-axis may be fitted to the velocities after this start transient


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path) -> Path:
    """Save atomically (a partial PNG never replaces a good one) and close the figure."""
    from .experiment import atomic_write

    atomic_write(Path(path), lambda fh: fig.savefig(fh, format="png", dpi=120))
    _pyplot().close(fig)
    return Path(path)


def pa_reachable_curve(arm: ArmParams, q0: np.ndarray, samples: int = 721) -> np.ndarray:
    """End-effector curve of a 2-link PA arm started at rest at q0 (Remark 1): ``(samples, 2)``.

    Zero passive momentum gives dq1/dq2 = −M_12(q2) / M_11(q2), integrated (trapezoidal rule)
    over q2 ∈ [−π, π] through q0's q2 (the elbow's whole range: at ±π the arm is folded).
    """
    if arm.n_links != 2 or not arm.passive_first_joint:
        raise ValueError("pa_reachable_curve is for 2-link arms with a passive first joint")
    q2 = np.linspace(-np.pi, np.pi, samples)
    M = mass_matrix(arm, np.stack([np.zeros_like(q2), q2], axis=-1))
    slope = -M[:, 0, 1] / M[:, 0, 0]
    q1 = np.concatenate([[0.0], np.cumsum(0.5 * (slope[1:] + slope[:-1]) * np.diff(q2))])
    q1 += q0[0] - np.interp(q0[1], q2, q1)
    return end_effector(arm, np.stack([q1, q2], axis=-1))


def run_figure(scenario: Scenario, traj: Mapping[str, np.ndarray], title: str = ""):
    """The four-panel figure of one run (Figures 4–7 of the paper)."""
    plt = _pyplot()
    t = traj["time"]
    fig, ax = plt.subplots(2, 2, figsize=(12, 9))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, arm in enumerate(scenario.arms):
        c = colors[i % len(colors)]
        for a in range(arm.n_links):
            style = "--" if (a == 0 and arm.passive_first_joint) else "-"
            label = f"arm {i + 1}" if a == 0 else None
            ax[0, 0].plot(t, traj["q"][:, i, a], style, color=c, lw=1, label=label)
            ax[0, 1].plot(t, traj["qd"][:, i, a], style, color=c, lw=1, label=label)
    ax[0, 0].set(xlabel="time [s]", ylabel="joint angle [rad]", title="(a) joint angles")
    ax[0, 1].set(xlabel="time [s]", ylabel="joint velocity [rad/s]", title="(b) joint velocities")
    _clip_start_transient(ax[0, 1], t, traj["qd"], "rad/s")
    ax[0, 0].legend(fontsize=8, title="dashed: passive joint", title_fontsize=8)
    for k, (i, j) in enumerate(scenario.formation.edges):
        ax[1, 0].plot(t, traj["edge_error"][:, k], lw=1, label=f"edge ({i + 1},{j + 1})")
    ax[1, 0].axhline(0.0, color="k", lw=0.5)
    ax[1, 0].set(xlabel="time [s]", ylabel="‖z_k‖ − d_k [m]", title="(c) edge-length errors")
    ax[1, 0].legend(fontsize=8)
    _trajectory_panel(ax[1, 1], scenario, traj, colors)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def _clip_start_transient(ax, t: np.ndarray, values: np.ndarray, unit: str,
                          skip: float = VELOCITY_AXIS_SKIP_S, ratio: float = 3.0) -> None:
    """Fit the y-axis to ``values`` (time first) after the first ``skip`` seconds when the whole
    range is more than ``ratio`` times that; note the clipping and the off-axis extremes in the panel."""
    t = np.asarray(t)
    later = values[t >= t[0] + skip]
    later = later[np.isfinite(later)]
    every = values[np.isfinite(values)]
    if later.size == 0 or every.size == 0:
        return
    lo, hi = float(later.min()), float(later.max())
    pad = 0.1 * max(hi - lo, 1e-3)
    lo, hi = lo - pad, hi + pad
    if every.max() - every.min() <= ratio * (hi - lo):
        return  # nothing dominates: matplotlib's own limits
    ax.set_ylim(lo, hi)
    flat = np.where(np.isfinite(values), values, np.nan).reshape(len(t), -1)
    n_joints = values.shape[2] if values.ndim == 3 else 1
    notes = []
    for pick, outside in ((np.nanargmax, lambda v: v > hi), (np.nanargmin, lambda v: v < lo)):
        r, col = np.unravel_index(pick(flat), flat.shape)
        value = flat[r, col]
        if outside(value):
            sign = "+" if value >= 0 else "−"
            notes.append(f"{sign}{abs(value):.1f} {unit} (arm {col // n_joints + 1} joint {col % n_joints + 1}, "
                         f"t = {t[r]:.2f} s)")
    head = [f"y-axis clipped to the data after t = {skip:g} s", f"off-axis peak{'s' if len(notes) > 1 else ''}:"]
    ax.text(0.98, 0.97, "\n".join(head + notes),
            transform=ax.transAxes, ha="right", va="top", multialignment="left", fontsize=8,
            bbox={"boxstyle": "round", "fc": "white", "ec": "0.7", "alpha": 0.9})


def _trajectory_panel(ax, scenario: Scenario, traj: Mapping[str, np.ndarray], colors) -> None:
    import matplotlib.patches as mpatches

    for c, r in zip(scenario.obstacles.centers, scenario.obstacles.radii, strict=True):
        ax.add_patch(mpatches.Circle(c, r, color="red", alpha=0.6, lw=0))
    P = traj["p_end"]
    for i, arm in enumerate(scenario.arms):
        col = colors[i % len(colors)]
        ax.plot(P[:, i, 0], P[:, i, 1], color=col, lw=1.2, label=f"arm {i + 1}"
                + (" (PA)" if arm.passive_first_joint and arm.n_links == 2 else ""))
        ax.plot(*P[0, i], "x", color=col, ms=8)
        ax.plot(*P[-1, i], "o", mfc="none", color=col, ms=8)
        ax.plot(*arm.base, "s", color=col, ms=5)
        if arm.passive_first_joint and arm.n_links == 2 and not arm.passive_damping:  # zero momentum throughout
            curve = pa_reachable_curve(arm, scenario.q0[i])
            ax.plot(curve[:, 0], curve[:, 1], "--", color=col, lw=0.8)
    for i, j in scenario.formation.edges:
        ax.plot(*np.stack([P[-1, i], P[-1, j]]).T, color="0.4", lw=0.8)
    ax.set(xlabel="X [m]", ylabel="Y [m]", title="(d) end-effector paths (× start, ∘ end)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)


def obstacle_distance_figure(scenario: Scenario, runs: Mapping[str, Mapping[str, np.ndarray]]):
    """Distance of each obstacle-reaching PA arm to its nearest obstacle centre (Figure 8).

    ``runs`` maps a label (e.g. ``"nominal"``, ``"safe"``) to a trajectory. Returns None when no PA
    arm can reach an obstacle.
    """
    plt = _pyplot()
    mask = scenario.obstacle_mask()
    arms = [i for i, a in enumerate(scenario.arms) if a.passive_first_joint and mask[i].any()]
    if not arms or len(scenario.obstacles) == 0:
        return None
    fig, axes = plt.subplots(1, len(arms), figsize=(5.5 * len(arms), 4), squeeze=False)
    centers, radii = scenario.obstacles.centers, scenario.obstacles.radii
    for ax, i in zip(axes[0], arms, strict=True):
        radius_lines = set()
        for label, traj in runs.items():
            d = np.linalg.norm(traj["p_end"][:, i, None, :] - centers[mask[i]], axis=-1)
            nearest = np.argmin(d - radii[mask[i]], axis=-1)
            dist = d[np.arange(len(d)), nearest]
            ax.plot(traj["time"], dist, lw=1.2, label=label)
            radius_lines.update(radii[mask[i]][np.unique(nearest)].tolist())
        for r in sorted(radius_lines):
            ax.axhline(r, color="red", ls="--", lw=1, label=f"safety boundary r = {r:g} m")
        ax.set(xlabel="time [s]", ylabel="distance to obstacle centre [m]",
               title=f"arm {i + 1} (passive first joint)")
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
