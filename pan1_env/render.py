"""Frames of an environment (``rgb_array``) and its window (``human``), drawn with matplotlib.

A frame shows each arm's links and joints (a PA arm's passive joint as a hollow red ring), its
end-effector labelled with the arm's number 1..N (as in the figures and tables; agent ``arm_i`` is
arm i + 1), the obstacles (red disks, where they are now) with the safety filter's boundary (dashed)
and a moving obstacle's path (thin, dashed), the formation's edges between the end-effectors (green
when within 1 cm of their length, orange otherwise) and the target shape (grey, dashed) fitted to the
end-effectors by the best rigid motion, or where it stands for a placed shape (docs/MODEL.md §8). With
``bodies = "links"`` each link is also shaded as the capsule of radius ``link_radius`` that the filter keeps
clear, so a frame shows what is protected.
Matplotlib is imported only when the first frame is drawn; ``rgb_array`` needs no display.
"""

from __future__ import annotations

import numpy as np

from .config import SUCCESS_TOLERANCE
from .dynamics import joint_positions

__all__ = ["Renderer", "fit_shape"]


def fit_shape(target: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The rigid motion (rotation and translation, no reflection) of ``target`` closest to ``points``."""
    tc, pc = target.mean(0), points.mean(0)
    H = (target - tc).T @ (points - pc)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, d]) @ U.T
    return (target - tc) @ R.T + pc


def _capsule(a: np.ndarray, b: np.ndarray, radius: float, n: int = 16) -> np.ndarray:
    """The outline ``(2n, 2)`` of the capsule of ``radius`` about segment a–b: a half circle round each end,
    so the drawn shape is exactly the set the filter keeps clear (a stroke's width would be in points)."""
    d = np.asarray(b, dtype=float) - a
    theta = np.arctan2(d[1], d[0])  # 0 for a zero-length link: a disk
    arc = np.linspace(-np.pi / 2, np.pi / 2, n)
    ends = [(b, theta + arc), (a, theta + np.pi + arc)]
    return np.concatenate([c + radius * np.stack([np.cos(t), np.sin(t)], axis=-1) for c, t in ends])


class Renderer:
    """Draws an environment's current state into a fixed-size figure."""

    def __init__(self, human: bool = False, size_px: int = 480) -> None:
        import matplotlib

        if not human:
            matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        self._plt = plt
        self.human = human
        if human:
            plt.ion()
        self.fig, self.ax = plt.subplots(figsize=(size_px / 80, size_px / 80), dpi=80)
        self._limits = None

    def draw(self, env) -> np.ndarray | None:
        import matplotlib.patches as mpatches

        sc, ax = env.scenario, self.ax
        ax.clear()
        if self._limits is None or getattr(self, "_scenario", None) is not sc:
            self._scenario = sc
            pts = [a.base for a in sc.arms] + list(sc.obstacles.centers)
            pts += [] if sc.obstacle_paths is None else list(sc.obstacle_paths)  # whole paths in view
            reach = max(a.reach for a in sc.arms)
            pts = np.array(pts)
            self._limits = (pts.min(0) - reach, pts.max(0) + reach)
        lo, hi = self._limits
        margin = sc.filter.margin
        if sc.obstacle_paths is not None:  # a moving obstacle goes back and forth along its path
            moving = sc.moving_obstacles
            for path in np.stack([sc.obstacles.centers[moving], sc.obstacle_paths[moving]], axis=1):
                ax.plot(*path.T, "--", color="tab:red", lw=0.8, alpha=0.7, gid="obstacle_path")
        # where the obstacles are now: the engine moves them (a stand-in env without one: the scenario's centres)
        engine = getattr(env, "engine", None)
        centers = sc.obstacles.centers if engine is None else engine.centers[0]
        for c, r in zip(centers, sc.obstacles.radii, strict=True):
            ax.add_patch(mpatches.Circle(c, r, color="tab:red", alpha=0.55, lw=0))
            ax.add_patch(mpatches.Circle(c, np.sqrt(r * r + margin), fill=False, ls="--", color="tab:red", lw=1))
        q, _ = env.joint_state()
        P = env.end_effectors()
        colors = self._plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for i, arm in enumerate(sc.arms):
            pts = joint_positions(arm, q[i, : arm.n_links])
            col = colors[i % len(colors)]
            if sc.bodies == "links" and sc.link_radius > 0:
                for p0, p1 in zip(pts[:-1], pts[1:], strict=True):
                    ax.add_patch(mpatches.Polygon(_capsule(p0, p1, sc.link_radius), color=col, alpha=0.3,
                                                  lw=0, gid="capsule"))
            ax.plot(pts[:, 0], pts[:, 1], "-", color=col, lw=3, solid_capstyle="round")
            ax.plot(pts[1:-1, 0], pts[1:-1, 1], "o", color="k", ms=4)
            ax.plot(*arm.base, "s", color="k", ms=7)
            if arm.passive_first_joint:
                ax.plot(*arm.base, "o", mfc="none", mec="red", ms=12, mew=2)
            ax.plot(*pts[-1], "o", color=col, ms=7)
            ax.annotate(str(i + 1), pts[-1], textcoords="offset points", xytext=(5, 5), fontsize=8)
        f = sc.formation
        shape, distances, placed = f.target, f.distances, False
        task = getattr(env, "task", None)
        motion = getattr(task, "motion", None)
        if motion is not None:  # a moving formation: its shape (where it stands, if placed) and lengths now
            shape = motion.placement(env.engine.elapsed[:1], np.zeros(1, np.int64))[0][0]
            distances, placed = task.distances[0], motion.placed[0]
        fitted = shape if placed else fit_shape(shape, P)
        err = np.abs(np.linalg.norm(P[f.edges[:, 0]] - P[f.edges[:, 1]], axis=-1) - distances)
        for (a, b), e in zip(f.edges, err, strict=True):
            ax.plot(*fitted[[a, b]].T, "--", color="0.5", lw=1)
            formed = e < getattr(getattr(env, "config", None), "success_tolerance", SUCCESS_TOLERANCE)
            ax.plot(*P[[a, b]].T, "-", color="tab:green" if formed else "tab:orange", lw=1.5)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        time = env.num_steps * env.dt
        ax.set_title(f"{sc.name}  t = {time:.2f} s  max edge error {err.max():.3f} m", fontsize=9)
        self.fig.tight_layout()
        self.fig.canvas.draw()
        if self.human:
            self._plt.pause(0.001)
            return None
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        self._plt.close(self.fig)
