"""Frames of whole-arm scenarios: each link's capsule, moving obstacles where they are now and their paths.

Pixels are compared only between frames drawn in the same run (the same state, one feature switched off),
never with stored images, so a matplotlib upgrade cannot fail them.
"""

import dataclasses

import numpy as np
import pytest
from matplotlib.colors import to_rgb
from matplotlib.patches import Circle

import pan1_env
from pan1_env.dynamics import joint_positions
from pan1_env.render import Renderer

WHOLE_ARM = {"bodies": "links", "link_radius": 0.03, "inter_arm": True, "obstacle_speed": (0.05, 0.2)}
SIZE_PX = 1600  # large enough that a 3 cm capsule shows well beyond its arm's 3 pt line


@pytest.fixture(scope="module")
def whole_arm_env():
    env = pan1_env.parallel_env("random", render_mode="rgb_array", control_dt=0.01, physics_dt=0.01,
                                random_options=WHOLE_ARM)
    yield env
    env.close()


@pytest.fixture
def draw():
    """Draws an env with a new renderer each time: a renderer's layout depends on its previous frame, so
    frames to compare pixel by pixel are each a new renderer's first; returns the frame and its renderer."""
    made = []

    def _draw(env, size_px: int = SIZE_PX) -> tuple[np.ndarray, Renderer]:
        made.append(Renderer(size_px=size_px))
        return made[-1].draw(env), made[-1]

    yield _draw
    for r in made:
        r.close()


def _hold(env, steps: int) -> None:
    """Step with zero commands: the arms stay (about) still, the obstacles move."""
    for _ in range(steps):
        env.step({a: np.zeros(env.action_space(a).shape, dtype=np.float32) for a in env.agents})


def _segments(env) -> list[tuple[np.ndarray, np.ndarray]]:
    q, _ = env.joint_state()
    out = []
    for i, arm in enumerate(env.scenario.arms):
        pts = joint_positions(arm, q[i, : arm.n_links])
        out += list(zip(pts[:-1], pts[1:], strict=True))
    return out


def _segment_distance(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    t = np.clip((x - a) @ d / max(d @ d, 1e-12), 0.0, 1.0)
    return np.linalg.norm(x - (a + t[:, None] * d), axis=-1)


def _pixel_points(renderer: Renderer, mask: np.ndarray) -> np.ndarray:
    """Data coordinates ``(K, 2)`` of the centres of the pixels set in ``mask`` (the figure's pixels)."""
    rows, cols = np.nonzero(mask)
    display = np.c_[cols + 0.5, mask.shape[0] - rows - 0.5]
    return renderer.ax.transData.inverted().transform(display)


def _pixels_of(renderer: Renderer, frame: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The frame's colours at data points ``xy (K, 2)``."""
    col, y = renderer.ax.transData.transform(xy).T
    return frame[(frame.shape[0] - y).astype(int), col.astype(int)]


def _metres_per_pixel(renderer: Renderer) -> float:
    inv = renderer.ax.transData.inverted()
    return float(inv.transform([[1.0, 0.0]])[0, 0] - inv.transform([[0.0, 0.0]])[0, 0])


def _gids(renderer: Renderer, gid: str) -> list:
    return [a for a in [*renderer.ax.patches, *renderer.ax.lines] if a.get_gid() == gid]


def test_links_are_drawn_as_capsules_of_link_radius(whole_arm_env, draw, monkeypatch) -> None:
    env = whole_arm_env
    env.reset(seed=0)
    sc, rho = env.scenario, env.scenario.link_radius
    assert sc.bodies == "links" and rho == 0.03
    segments = _segments(env)
    shaded, renderer = draw(env)
    capsules = _gids(renderer, "capsule")
    assert len(capsules) == len(segments) == sum(a.n_links for a in sc.arms)
    for patch, (a, b) in zip(capsules, segments, strict=True):  # the outline is ρ from its link all round
        np.testing.assert_allclose(_segment_distance(patch.get_xy(), a, b), rho, atol=1e-9)

    # the same state with the links unprotected: no capsule, and the frames differ only inside the capsules
    monkeypatch.setattr(env.engine, "teams", [dataclasses.replace(sc, bodies="end_effector", link_radius=0.0,
                                                                    inter_arm=False)])
    plain, renderer = draw(env)
    assert not _gids(renderer, "capsule")
    changed = np.any(shaded != plain, axis=-1)
    px = _metres_per_pixel(renderer)
    assert changed.sum() > len(segments) * 2 * rho / px  # at least a capsule's width of pixels per link
    pts = _pixel_points(renderer, changed)
    nearest = np.min([_segment_distance(pts, a, b) for a, b in segments], axis=0)
    assert nearest.max() <= rho + 2 * px

    # and the capsule shows along every link beside its line (0.75 ρ off the centre line, between the joints)
    beside = []
    for a, b in segments:
        d = (b - a) / np.linalg.norm(b - a)
        along = a + np.linspace(0.25, 0.75, 9)[:, None] * (b - a)
        beside += [along + s * 0.75 * rho * np.array([-d[1], d[0]]) for s in (-1, 1)]
    beside = np.concatenate(beside)
    differs = np.any(_pixels_of(renderer, shaded, beside) != _pixels_of(renderer, plain, beside), axis=-1)
    assert differs.mean() > 0.8


def test_paper_scenario_frame_has_no_capsules_or_paths(draw) -> None:
    env = pan1_env.parallel_env("paper_pa3_square", render_mode="rgb_array")
    env.reset(seed=0)
    _hold(env, 5)
    sc = env.scenario
    assert sc.bodies == "end_effector" and sc.obstacle_paths is None
    frame = env.render()
    drawn = env._renderer
    assert not _gids(drawn, "capsule") and not _gids(drawn, "obstacle_path")
    assert all(isinstance(p, Circle) for p in drawn.ax.patches) and len(drawn.ax.patches) == 2 * len(sc.obstacles)
    disks = [p.center for p in drawn.ax.patches if p.get_fill()]
    np.testing.assert_array_equal(disks, sc.obstacles.centers)
    # still obstacles: the engine's centres are the scenario's, so the frame is the one drawn from the scenario
    stand_in = dataclasses.make_dataclass("StandIn", ["scenario", "joint_state", "end_effectors", "num_steps", "dt"])
    plain, _ = draw(stand_in(sc, env.joint_state, env.end_effectors, env.num_steps, env.dt), 480)
    np.testing.assert_array_equal(frame, plain)
    env.close()


def test_moving_obstacles_are_drawn_where_the_engine_has_them(whole_arm_env, draw) -> None:
    env = whole_arm_env
    env.reset(seed=0)
    sc = env.scenario
    assert sc.moving_obstacles.all()
    start = env.engine.centers[0].copy()
    np.testing.assert_array_equal(start, sc.obstacles.centers)
    before, r0 = draw(env)
    _hold(env, 150)
    now = env.engine.centers[0].copy()
    moved = np.linalg.norm(now - start, axis=-1)
    assert (moved > sc.obstacles.radii).all()  # each disk has left its start
    after, r1 = draw(env)
    disks = [p for p in r1.ax.patches if isinstance(p, Circle) and p.get_fill()]
    np.testing.assert_allclose([p.center for p in disks], now)

    # the disk's colour (tab:red at alpha 0.55 on white): its pixels' centroid moves with the engine's centre
    # (an arm drawn over a disk hides some of it, so near the centre, not on it)
    disk = 255 * (0.45 + 0.55 * np.array(to_rgb("tab:red")))
    centroids = []
    for frame, r in [(before, r0), (after, r1)]:
        pts = _pixel_points(r, np.all(np.abs(frame - disk) <= 4, axis=-1))
        windows = [np.linalg.norm(pts - c, axis=-1) <= rj + m for c, rj, m in zip(start, sc.obstacles.radii, moved,
                                                                                  strict=True)]
        assert all(w.sum() > 100 for w in windows)  # each window holds both of its disk's positions, no other disk
        centroids.append(np.array([pts[w].mean(0) for w in windows]))
    shift = centroids[1] - centroids[0]
    assert (np.sum(shift * (now - start), axis=-1) > 0.6 * moved**2).all()
    assert (np.linalg.norm(centroids[0] - start, axis=-1) < 0.3 * moved).all()
    assert (np.linalg.norm(centroids[1] - now, axis=-1) < 0.3 * moved).all()


def test_obstacle_paths_are_drawn_and_in_view(whole_arm_env, draw, monkeypatch) -> None:
    env = whole_arm_env
    env.reset(seed=0)
    sc = env.scenario
    with_paths, r = draw(env)
    paths = _gids(r, "obstacle_path")
    assert len(paths) == len(sc.obstacles)
    for line, c, end in zip(paths, sc.obstacles.centers, sc.obstacle_paths, strict=True):
        np.testing.assert_array_equal(np.transpose(line.get_data()), [c, end])
        assert line.get_linestyle() == "--"

    # the same state with the obstacles still (their paths kept, so the same view): the frames differ on the paths
    monkeypatch.setattr(env.engine, "teams", [dataclasses.replace(sc, obstacle_speeds=np.zeros(len(sc.obstacles)))])
    without, r = draw(env)
    assert not _gids(r, "obstacle_path")
    changed = np.any(with_paths != without, axis=-1)
    px = _metres_per_pixel(r)
    pts = _pixel_points(r, changed)
    near = [_segment_distance(pts, c, end) <= 2 * px for c, end in zip(sc.obstacles.centers, sc.obstacle_paths,
                                                                       strict=True)]
    assert np.any(near, axis=0).all()  # nothing else changed
    for j, on_path in enumerate(near):  # a dashed line: at least a quarter of its length drawn
        length_px = np.linalg.norm(sc.obstacle_paths[j] - sc.obstacles.centers[j]) / px
        assert on_path.sum() > 0.25 * length_px

    # a path that ends far out stays in view
    far = sc.obstacle_paths.copy()
    far[0] = [8.0, -6.0]
    monkeypatch.setattr(env.engine, "teams", [dataclasses.replace(sc, obstacle_paths=far)])
    _, r = draw(env)
    (x0, x1), (y0, y1) = r.ax.get_xlim(), r.ax.get_ylim()
    assert x0 < 0 < 8.0 < x1 and y0 < -6.0 < 0 < y1
