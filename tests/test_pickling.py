"""A pickled or deep-copied env, taken mid-episode, continues exactly as the original does."""

from __future__ import annotations

import copy
import pickle

import gymnasium
import numpy as np
import pytest
from rollouts import bits, random_actions, replay

import pan1_env  # noqa: F401  (registers the Gymnasium ids)
from pan1_env.environment import parallel_env
from pan1_env.wrappers import SafetyShield

_MIXED = {"links": (2, 3, 4, 3)}


def _make_parallel():
    return parallel_env("paper_pa_mixed_square")


def _make_shielded():
    return SafetyShield(parallel_env("random", random_options=_MIXED))


def _make_gym():
    return gymnasium.make("pan1_env/PaperPA3Square-v0")


def _make_whole_arm():  # the kinds' whole-arm arrays are views of the engine's team arrays
    return SafetyShield(parallel_env("random", random_options={
        "bodies": "links", "link_radius": 0.03, "inter_arm": True, "obstacle_speed": (0.1, 0.3)}))


@pytest.mark.parametrize("make", [_make_parallel, _make_shielded, _make_gym, _make_whole_arm],
                         ids=["parallel_mixed", "shielded_random", "gym_pa3", "shielded_whole_arm"])
def test_pickled_and_copied_env_continues_identically(make) -> None:
    env = make()
    env.reset(seed=5)
    rng = np.random.default_rng(11)
    for _ in range(20):
        env.step(random_actions(env, rng))
    pickled = pickle.loads(pickle.dumps(env))
    copied = copy.deepcopy(env)
    later = [random_actions(env, rng) for _ in range(30)]
    # the original runs first: a copy sharing any mutable state with it would then diverge
    reference = replay(env, later)
    assert any(r[1] != reference[0][1] for r in reference), "the rollout should change the reward"
    for twin in (pickled, copied):
        assert twin is not env
        got = replay(twin, later)
        for step, (a, b) in enumerate(zip(got, reference, strict=True)):
            assert a[0] == b[0], f"observations differ at step {step}"
            assert a[1] == b[1], f"rewards differ at step {step}"
            assert a[4] == b[4], f"costs differ at step {step}"
            assert a == b, f"terminations, truncations or infos differ at step {step}"


def test_copy_keeps_the_reset_generator() -> None:
    # a copied random env draws the same next team on reset() as the original
    env = parallel_env("random", random_options=_MIXED)
    env.reset(seed=3)
    twin = pickle.loads(pickle.dumps(env))
    a, _ = env.reset()
    b, _ = twin.reset()
    assert bits(a) == bits(b)
    np.testing.assert_array_equal([arm.base for arm in env.scenario.arms], [arm.base for arm in twin.scenario.arms])


def test_an_engine_pickled_before_its_physics_was_one_part_is_refused() -> None:
    """An engine pickled by an older release (its step's settings loose, its team arrays under other names) would
    load with its kinds unlinked from those arrays and step wrongly without a sound: it is refused, naming why."""
    import pickle

    from pan1_env.engine import Engine
    from pan1_env.scenario import load

    engine = Engine(load("paper_pa3_square"))
    state = dict(engine.__dict__)
    state.pop("_physics")
    state |= {"physics_dt": 0.01, "max_speed": 2.0, "max_torque": float("inf"), "qp_solver": "active_set"}
    old = Engine.__new__(Engine)
    with pytest.raises(ValueError, match="pickled by an older pan1-env"):
        old.__setstate__(state)
    assert pickle.loads(pickle.dumps(engine)).physics == engine.physics


class _Earlier(pickle.Pickler):
    """Pickles as the release before the kept kernel arguments did: the engine without its working record and its
    obstacles' motion flag, the kinds without their held command and plans, the core without its report's slots,
    the reach task without its reward's parts."""

    def reducer_override(self, obj):
        import copyreg

        from pan1_env.core import FormationCore
        from pan1_env.engine import Engine
        from pan1_env.kinds import Kind
        from pan1_env.tasks import ReachTask

        dropped = {Engine: ("_work", "moving"), Kind: ("held", "plan", "ready"), FormationCore: ("_slots",),
                   ReachTask: ("_weights", "_terms")}.get(type(obj))
        if dropped is None:
            return NotImplemented
        state = obj.__getstate__() if hasattr(type(obj), "__getstate__") else dict(obj.__dict__)
        return copyreg.__newobj__, (type(obj),), {k: v for k, v in state.items() if k not in dropped}


@pytest.mark.parametrize("env_id", ["pan1_env/MovingFormation-v1", "pan1_env/PaperPA3Square-v0",
                                    "pan1_env/WholeArmFormation-v2", "pan1_env/PAReach-v0"])
def test_an_env_pickled_by_the_release_before_the_kept_kernel_arguments_steps_on_identically(env_id: str) -> None:
    import io

    env = gymnasium.make(env_id).unwrapped
    env.reset(seed=1)
    rng = np.random.default_rng(2)
    for _ in range(3):
        env.step(random_actions(env, rng))
    buffer = io.BytesIO()
    _Earlier(buffer).dump(env)
    old = pickle.loads(buffer.getvalue())
    assert "_slots" in vars(old.core)  # made again on loading
    for _ in range(5):
        action = random_actions(env, rng)
        assert [bits(x) for x in env.step(action)] == [bits(x) for x in old.step(action)]
