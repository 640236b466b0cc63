"""One closed-loop run of a scenario with the paper's controller: metrics, trajectory, outputs.

:func:`run` drives a :class:`~pan1_env.simulation.Simulation` over a horizon, keeps the metrics
that are minimised or maximised over *every physics sub-step* (clearance, tracking error, passive
momentum, edge error), records the trajectory at ``record_dt``, and returns a :class:`RunResult`.
:func:`write_outputs` saves ``metrics.json`` and ``trajectory.npz`` atomically (a partial file
never replaces a good one). The CLI's ``reproduce`` command is a thin shell around these.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .config import SUCCESS_TOLERANCE
from .formation import edge_length_errors, edge_vectors
from .safety import QPStatus
from .scenario import Scenario
from .simulation import Simulation

__all__ = ["CONTROLLERS", "RunResult", "run", "write_outputs", "atomic_write"]

CONTROLLERS = ("nominal", "safe")
MAX_SAMPLES = 10_000_000  # trajectory samples a run may record


@dataclass
class RunResult:
    metrics: dict[str, Any]
    trajectory: dict[str, np.ndarray]


def run(
    scenario: Scenario,
    controller: str = "safe",
    *,
    horizon: float | None = None,
    record_dt: float = 0.01,
    qp_solver: str = "active_set",
    progress: bool | Callable[[int], None] = False,
) -> RunResult:
    """Simulate ``scenario`` with the ``"nominal"`` (v* = v0) or ``"safe"`` (v* = QP(v0)) controller.

    Args:
        scenario: the scenario: RK4 every ``physics_dt``; the nominal law is evaluated every
            ``control_dt`` and held in between, the filter and tracker run every ``physics_dt``.
        controller: ``"nominal"`` or ``"safe"``.
        horizon: seconds to simulate (default: the scenario's).
        record_dt: trajectory sampling period (rounded to a whole number of control steps).
        qp_solver: ``"active_set"`` or ``"piqp"``.
        progress: ``True`` for a tqdm bar on stderr.
    """
    if controller not in CONTROLLERS:
        raise ValueError(f"unknown controller {controller!r}; choose one of {CONTROLLERS}")
    horizon = scenario.horizon if horizon is None else float(horizon)
    if not (math.isfinite(horizon) and horizon > 0):
        raise ValueError(f"horizon must be a positive number of seconds, got {horizon!r}")
    dt, substeps = scenario.physics_dt, scenario.substeps
    control_dt = dt * substeps
    n_control = int(round(horizon / control_dt))
    if n_control < 1:
        raise ValueError(f"horizon {horizon} s is shorter than one control step ({control_dt} s)")
    every = max(1, int(round(record_dt / control_dt)))
    n_rec = (n_control - 1) // every + 2  # samples at control steps 0, every, 2·every, … and the end
    if n_rec > MAX_SAMPLES:
        raise ValueError(f"{n_rec} trajectory samples exceed {MAX_SAMPLES}: shorten the horizon or raise record_dt")
    sim = Simulation(scenario, safety_filter=(controller == "safe"), qp_solver=qp_solver)
    sim.step(sim.nominal_velocity(), 1)  # compile (or load from cache) the kernels outside the timed loop
    sim.reset()
    incidence, distances = scenario.formation.incidence, scenario.formation.distances
    N = scenario.n_arms
    traj = {
        "time": np.zeros(n_rec),
        "q": np.full((n_rec, N, sim.n_max), np.nan),
        "qd": np.full((n_rec, N, sim.n_max), np.nan),
        "p_end": np.zeros((n_rec, N, 2)),
        "v_star": np.full((n_rec, N, sim.k_max), np.nan),
        "tau": np.full((n_rec, N, sim.n_max), np.nan),
        "edge_error": np.zeros((n_rec, len(distances))),
        "clearance": np.zeros((n_rec, N)),
    }

    def edge_error() -> np.ndarray:  # against the lengths now (a moving formation's change)
        return edge_length_errors(edge_vectors(incidence, sim.positions()), sim.targets()[0])

    def sample_state(r: int) -> None:
        traj["time"][r] = sim.time
        traj["q"][r], traj["qd"][r] = sim.joint_state()
        traj["p_end"][r] = sim.positions()
        traj["edge_error"][r] = edge_error()
        traj["clearance"][r] = sim.clearance()

    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=n_control * substeps, unit="step", desc=f"{scenario.name}/{controller}", mininterval=0.5)
    max_track = np.zeros(N)
    max_track_after_1s = np.zeros(N)
    max_momentum = 0.0
    has_passive = any(a.passive_first_joint for a in scenario.arms)
    qp_counts = np.zeros(3, dtype=int)
    sample_state(0)
    # last time the largest edge error was ≥ 1 cm (None: never)
    last_bad_time = 0.0 if np.abs(traj["edge_error"][0]).max() >= SUCCESS_TOLERANCE else None
    t0 = time.perf_counter()
    r = 0
    for c in range(n_control):
        if c % every == 0 and c > 0:
            r += 1
            sample_state(r)
        if has_passive:
            max_momentum = max(max_momentum, float(np.nanmax(np.abs(sim.passive_momentum()))))
        rec = sim.step(sim.nominal_velocity(), substeps)
        if c % every == 0:  # the v*, τ applied from the sampled state
            traj["v_star"][r] = rec.v_star
            traj["tau"][r] = rec.tau
        np.maximum(max_track, rec.max_tracking_error, out=max_track)
        if sim.time > 1.0:
            np.maximum(max_track_after_1s, rec.max_tracking_error, out=max_track_after_1s)
        qp_counts += rec.qp_counts.sum(axis=0)
        if np.abs(edge_error()).max() >= SUCCESS_TOLERANCE:
            last_bad_time = sim.time
        if bar is not None and (c + 1) % 100 == 0:
            bar.update((c + 1) * substeps - bar.n)
        elif callable(progress) and (c + 1) % 1000 == 0:
            progress((c + 1) * substeps)
    wall = time.perf_counter() - t0
    if bar is not None:
        bar.update(n_control * substeps - bar.n)
        bar.close()
    sample_state(n_rec - 1)
    if has_passive:
        max_momentum = max(max_momentum, float(np.nanmax(np.abs(sim.passive_momentum()))))
    final_edge = float(np.abs(traj["edge_error"][-1]).max())
    min_clear = sim.min_clearance
    arms = [
        {
            "index": i,
            "n_links": int(arm.n_links),
            "passive_first_joint": bool(arm.passive_first_joint),
            "min_clearance_m": _finite_or_none(min_clear[i]),
            "collided": bool(min_clear[i] < 0),
            "max_tracking_error": float(max_track[i]),
        }
        for i, arm in enumerate(scenario.arms)
    ]
    metrics = {
        "scenario": scenario.name,
        "controller": controller,
        "qp_solver": qp_solver if controller == "safe" else None,
        "horizon_s": horizon,
        "physics_dt": dt,
        "control_dt": control_dt,
        "steps": n_control * substeps,
        "wall_time_s": wall,
        "arms": arms,
        "min_clearance_m": _finite_or_none(min_clear.min()),
        "collided": bool(np.any(min_clear < 0)),
        "final_max_edge_error_m": final_edge,
        "time_to_edge_error_1cm_s": None if final_edge >= SUCCESS_TOLERANCE
        else (0.0 if last_bad_time is None else last_bad_time),
        "max_tracking_error": float(max_track.max()),
        "max_tracking_error_after_1s": float(max_track_after_1s.max()),
        # the integration's drift from p₁ = 0 for undamped arms; with passive_damping, the momentum itself
        "max_momentum_drift": max_momentum if has_passive else None,
        "qp_solved_steps": int(qp_counts[QPStatus.SOLVED]),
        "qp_fallback_steps": int(qp_counts[QPStatus.FALLBACK]),
    }
    traj.update(_static(scenario))
    return RunResult(metrics, traj)


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _static(scenario: Scenario) -> dict[str, np.ndarray]:
    return {
        "bases": np.array([a.base for a in scenario.arms]),
        "n_links": np.array([a.n_links for a in scenario.arms]),
        "passive_first_joint": np.array([a.passive_first_joint for a in scenario.arms]),
        "obstacle_centers": scenario.obstacles.centers,
        "obstacle_radii": scenario.obstacles.radii,
        "edges": scenario.formation.edges,
        "distances": scenario.formation.distances,
    }


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: Path, write: Callable[[Any], None], mode: str = "wb") -> None:
    """Write through ``write(file)`` to a temporary file beside ``path``, then rename it in place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, mode) as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_outputs(result: RunResult, out_dir: str | Path, *, trajectory: bool = True) -> dict[str, Path]:
    """Write ``metrics.json`` and (unless ``trajectory=False``) ``trajectory.npz`` into ``out_dir``,
    each atomically."""
    out = Path(out_dir)
    paths = {"metrics": out / "metrics.json", "trajectory": out / "trajectory.npz"}
    if trajectory:
        atomic_write(paths["trajectory"], lambda fh: np.savez_compressed(fh, **result.trajectory))
    atomic_write(paths["metrics"], lambda fh: fh.write(json.dumps(result.metrics, indent=2) + "\n"),
                 mode="w")
    return paths
