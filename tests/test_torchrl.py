"""TorchRL on the env: its own PettingZooWrapper on the parallel env, as a MARL researcher's first try would
use it (arms of different kinds through :class:`~pan1_env.wrappers.PadToLargestArm`), and the native batched
env (:func:`pan1_env.marl.torchrl_env`): TorchRL's ``check_env_specs``, shielded and not, for a uniform team,
a mixed team, random teams and whole-arm teams, and the native env against the vector env."""

import os

import numpy as np
import pytest

if os.environ.get("PAN1_REQUIRE_MARL"):  # set by `make test`, which installs the marl extra: missing is a failure
    import torchrl  # noqa: F401
else:
    pytest.importorskip("torchrl")

import torch  # noqa: E402
from tensordict import TensorDict  # noqa: E402
from torchrl.envs.libs.pettingzoo import PettingZooWrapper  # noqa: E402
from torchrl.envs.utils import check_env_specs, step_mdp  # noqa: E402
from torchrl.modules import TanhNormal  # noqa: E402

from pan1_env.environment import parallel_env  # noqa: E402
from pan1_env.marl import MaskedTanhNormal, torchrl_env  # noqa: E402
from pan1_env.vector import Pan1VectorEnv  # noqa: E402
from pan1_env.wrappers import PadToLargestArm, SafetyShield  # noqa: E402

SHIELD_KEYS = ("shield_intervened", "shield_fallback", "shield_status", "shield_min_barrier", "shield_applied",
               "qp_counts")


def _wrapped(scenario: str, shield: bool, pad: bool = False) -> PettingZooWrapper:
    env = parallel_env(scenario, max_steps=12)
    if shield:
        env = SafetyShield(env)
    if pad:
        env = PadToLargestArm(env)
    return PettingZooWrapper(env=env, use_mask=False, return_state=True)


@pytest.mark.parametrize("shield", [True, False])
@pytest.mark.parametrize(("scenario", "pad"), [("paper_pa3_square", False), ("paper_pa_mixed_square", True),
                                               ("random", True), ("pan1_env/WholeArmStaticFormation-v0", True)])
def test_pettingzoo_wrapper_specs_hold(scenario: str, pad: bool, shield: bool) -> None:
    env = _wrapped(scenario, shield, pad)
    check_env_specs(env, seed=0)
    rollout = env.rollout(12, break_when_any_done=False)
    info = rollout["next", "arm", "info"]
    assert set(SHIELD_KEYS) <= set(info.keys()) if shield else not set(SHIELD_KEYS) & set(info.keys())
    assert info["cost"].shape == (12, 4)
    if shield:
        assert info["shield_applied"].shape == (12, 4, env.action_spec["arm", "action"].shape[-1])


def test_the_wrapper_steps_the_env_as_it_is() -> None:
    """The same actions through TorchRL and straight into the env give the same rewards and observations."""
    env = _wrapped("paper_pa_mixed_square", shield=True, pad=True)
    env.set_seed(5)
    td = env.reset()
    twin = PadToLargestArm(SafetyShield(parallel_env("paper_pa_mixed_square", max_steps=12)))
    obs, _ = twin.reset(seed=5)
    np.testing.assert_allclose(td["arm", "observation"].numpy(), np.stack([obs[a] for a in twin.possible_agents]))
    rng = np.random.default_rng(0)
    for _ in range(5):
        action = rng.uniform(-1, 1, env.action_spec["arm", "action"].shape).astype(np.float32)
        td["arm", "action"] = torch.as_tensor(action)
        td = env.step(td)
        obs, rewards, _, _, _ = twin.step(dict(zip(twin.possible_agents, action, strict=True)))
        np.testing.assert_allclose(td["next", "arm", "observation"].numpy(), np.stack(list(obs.values())), atol=1e-6)
        np.testing.assert_allclose(td["next", "arm", "reward"].numpy().ravel(), list(rewards.values()), atol=1e-6)
        td = step_mdp(td)


@pytest.mark.parametrize("shield", [True, False])
@pytest.mark.parametrize(("scenario", "mode"), [
    ("paper_pa3_square", "velocity"), ("paper_pa_mixed_square", "velocity"), ("random", "velocity"),
    ("pan1_env/WholeArmStaticFormation-v0", "velocity"), ("pan1_env/WholeArmStaticFormation-v1", "circulation")])
def test_native_env_specs_hold(scenario: str, mode: str, shield: bool) -> None:
    env = torchrl_env(scenario, num_envs=3, max_steps=10, safety_filter=shield, action_mode=mode)
    check_env_specs(env, seed=0)
    rollout = env.rollout(25, break_when_any_done=False)  # past two ends: TorchRL resets the ended copies
    assert rollout["next", "arms", "reward"].shape == (3, 25, 4, 1)
    assert rollout["next", "done"].sum() == 6
    assert ("shield_applied" in rollout["next", "arms", "info"].keys()) == shield
    if shield:
        assert rollout["next", "arms", "cost"].sum() == 0


@pytest.mark.parametrize(("scenario", "mode"), [("paper_pa_mixed_square", "velocity"), ("random", "velocity"),
                                                ("paper_pa_mixed_square", "circulation")])
def test_native_env_matches_the_vector_env_step_for_step(scenario: str, mode: str) -> None:
    """The same seeds and actions give the vector env's observations (per arm, unpadded), rewards (the
    vector env's is the arms' mean), costs and ends, through the reset of the copies that end (random teams:
    the same new teams from the same generators). Circulation actions: one entry more per arm, in a team of
    two kinds."""
    B = 3
    env = torchrl_env(scenario, num_envs=B, max_steps=6, safety_filter=True, action_mode=mode)
    venv = Pan1VectorEnv(scenario, B, max_steps=6, action_mode=mode)
    env.set_seed(11)
    td = env.reset()
    obs, _ = venv.reset(seed=11)
    core = env.core
    sizes, ks = [len(core.task.bounds(i)[0]) for i in range(len(core.agents))], core.action_sizes
    rng = np.random.default_rng(0)
    for _ in range(9):  # the copies end at step 6 and start again
        per_arm = np.concatenate([td["arms", "observation"][:, i, :n].numpy() for i, n in enumerate(sizes)], axis=1)
        np.testing.assert_array_equal(per_arm, obs)
        flat = rng.uniform(-1, 1, (B, sum(ks))).astype(np.float32)
        padded = np.zeros((B, 4, core.action_width), np.float32)
        for i, (start, k) in enumerate(zip(np.cumsum([0, *ks[:-1]]), ks, strict=True)):
            padded[:, i, :k] = flat[:, start : start + k]
        td["arms", "action"] = torch.from_numpy(padded)
        td = env.step(td)
        obs, reward, terminated, truncated, info = venv.step(flat)
        np.testing.assert_allclose(td["next", "arms", "reward"].numpy()[..., 0].mean(axis=1), reward, atol=1e-6)
        np.testing.assert_array_equal(td["next", "arms", "cost"].numpy()[..., 0].sum(axis=1), info["cost"])
        np.testing.assert_array_equal(td["next", "done"].numpy()[:, 0], terminated | truncated)
        if truncated.any():  # the vector env starts them in the same step; TorchRL resets them now
            final = np.concatenate([td["next", "arms", "observation"][:, i, :n].numpy() for i, n in enumerate(sizes)],
                                   axis=1)
            np.testing.assert_array_equal(final[truncated], np.stack(info["final_obs"][truncated]))
        td = env.reset(step_mdp(td)) if truncated.any() else step_mdp(td)


def test_partial_resets_match_the_vector_env() -> None:
    """Copies that end at different steps (collisions end them) are reset alone, through the collector's path
    (``step_and_maybe_reset``), and start the same new episodes as the vector env's autoreset; the others go on."""
    B, kwargs = 6, {"max_steps": 60, "terminate_on_collision": True, "safety_filter": False}
    env = torchrl_env("paper_pa3_square", num_envs=B, **kwargs)
    venv = Pan1VectorEnv("paper_pa3_square", B, **kwargs)
    env.set_seed(0)
    td = env.reset()
    obs, _ = venv.reset(seed=0)
    ks, rng, partial = env.core.n_actuated, np.random.default_rng(0), 0
    for _ in range(30):
        flat = rng.uniform(-1, 1, (B, sum(ks))).astype(np.float32)
        padded = np.zeros((B, len(ks), env.core.k_max), np.float32)
        for i, (start, k) in enumerate(zip(np.cumsum([0, *ks[:-1]]), ks, strict=True)):
            padded[:, i, :k] = flat[:, start : start + k]
        td["arms", "action"] = torch.from_numpy(padded)
        td, root = env.step_and_maybe_reset(td)
        obs, reward, terminated, truncated, info = venv.step(flat)
        done = td["next", "done"].numpy()[:, 0]
        np.testing.assert_array_equal(done, terminated | truncated)
        partial += 0 < done.sum() < B
        np.testing.assert_allclose(td["next", "arms", "reward"].numpy()[..., 0].mean(axis=1), reward, atol=1e-6)
        np.testing.assert_array_equal(root["arms", "observation"].numpy().reshape(B, -1), obs)
        np.testing.assert_array_equal(env.core.steps, venv.core.steps)
        td = root
    assert partial > 5  # the test saw copies end alone


@pytest.mark.parametrize("key", ["_reset", ("arms", "_reset")])
def test_a_reset_mask_resets_only_its_copies(key) -> None:
    env = torchrl_env("paper_pa3_square", num_envs=3, max_steps=10)
    env.set_seed(0)
    td = env.rollout(3)  # three steps of every copy
    assert env.core.steps.tolist() == [3, 3, 3]
    mask = torch.tensor([True, False, False])
    td = TensorDict({key: mask.reshape(3, 1) if key == "_reset" else mask.reshape(3, 1).expand(3, 4).clone()},
                    batch_size=[3])
    out = env.reset(td)
    assert env.core.steps.tolist() == [0, 3, 3]
    observed = env.core.padded_observations(env.core.observe())
    if key == "_reset":  # TorchRL merges by the root's mask: the others keep what the given tensordict held (none)
        np.testing.assert_array_equal(out["arms", "observation"].numpy()[0], observed[0])
    else:  # with the group's mask only it takes the env's whole output: every copy's own observation
        np.testing.assert_array_equal(out["arms", "observation"].numpy(), observed)
        assert np.abs(observed[1:]).sum(axis=-1).all()


@pytest.mark.parametrize("scenario", ["random", "pan1_env/FaultFormation-v1"])
def test_a_group_mask_reset_returns_the_others_as_last_returned(scenario: str) -> None:
    """With a group's mask only, TorchRL takes the env's whole output: the copies reset get a start's observations
    and infos, computed for them alone, and the others what the step before returned (their state has not moved),
    even after a user wrote into that step's observation tensor."""
    B = 4
    env = torchrl_env(scenario, num_envs=B, safety_filter=True)
    env.set_seed(0)
    td = env.reset()
    rng = np.random.default_rng(0)
    for _ in range(5):
        shape = (B, len(env.agent_names), env.core.k_max)
        td["arms", "action"] = torch.from_numpy(rng.uniform(-1, 1, shape).astype(np.float32))
        td = step_mdp(env.step(td))  # the step's output, the env's own tensors
    expected = td.clone()
    td["arms", "observation"].add_(7.0)  # a user's write into the step's tensors
    mask = torch.tensor([True, False, True, False])
    out = env.reset(TensorDict({("arms", "_reset"): mask.reshape(B, 1).expand(B, len(env.agent_names)).clone()},
                               batch_size=[B]))
    assert env.core.steps.tolist() == [0, 5, 0, 5]
    start = env._observations(*env.core.start())  # every copy's start, the reset ones' rows to compare
    keep, fresh = ~mask, mask
    for key in [("arms", "observation"), "state", *(("arms", "info", k) for k in env._arm_keys),
                *(("info", k) for k in env._copy_keys)]:
        assert torch.equal(out[key][keep], expected[key][keep]), key
        assert torch.equal(out[key][fresh], start[key][fresh]), key


def test_fault_task_specs_hold() -> None:
    """``FaultFormation-v1`` (behind the fault margin) with every full arm faulting within 0.3 s: both TorchRL views
    pass their spec check through the faults, and the infos carry ``actuator_lost``."""
    early = {"fault_probability": 1.0, "fault_time": (0.1, 0.3)}
    native = torchrl_env("pan1_env/FaultFormation-v1", num_envs=3, max_steps=10, safety_filter=True,
                         random_options=early)
    check_env_specs(native, seed=0)
    lost = native.rollout(10, break_when_any_done=False)["next", "arms", "info", "actuator_lost"]
    assert lost[:, -1].sum() >= 3 and not lost[:, 0].any()
    env = PadToLargestArm(SafetyShield(parallel_env("pan1_env/FaultFormation-v1", max_steps=12, random_options=early)))
    wrapped = PettingZooWrapper(env=env, use_mask=False, return_state=True)
    check_env_specs(wrapped, seed=0)
    assert wrapped.rollout(12, break_when_any_done=False)["next", "arm", "info", "actuator_lost"][-1].sum() >= 1


def test_moving_task_specs_hold() -> None:
    """``MovingFormation-v0``: both TorchRL views pass their spec check while the shape moves."""
    native = torchrl_env("pan1_env/MovingFormation-v0", num_envs=3, max_steps=10, safety_filter=True, success_hold=0.2,
                         random_options={"scale_period": 1.0})
    check_env_specs(native, seed=0)
    env = PadToLargestArm(SafetyShield(parallel_env("pan1_env/MovingFormation-v0", max_steps=12, success_hold=0.2)))
    check_env_specs(PettingZooWrapper(env=env, use_mask=False, return_state=True), seed=0)


def test_native_env_is_shaped_like_torchrl_multi_agent_envs() -> None:
    """``group_map``, ``n_agents`` and the standard key accessors, as VmasEnv and PettingZooWrapper have them; a
    ``device``; every float entry float32."""
    env = torchrl_env("paper_pa_mixed_square", num_envs=2, max_steps=4, safety_filter=True, device=torch.device("cpu"))
    assert env.group_map == {"arms": ["arm_0", "arm_1", "arm_2", "arm_3"]} and env.n_agents == 4
    assert (env.done_key, env.reward_key, env.action_key) == ("done", ("arms", "reward"), ("arms", "action"))
    assert env.device == torch.device("cpu") and torchrl_env(num_envs=1, device="cpu").device == torch.device("cpu")
    rollout = env.rollout(4, break_when_any_done=False)
    assert rollout["next", env.done_key][:, -1].all()
    floats = {key: value.dtype for key, value in rollout.items(True, True) if value.is_floating_point()}
    assert ("next", "arms", "info", "min_clearance") in floats and set(floats.values()) == {torch.float32}
    assert torchrl_env("paper_pa3_square", control_dt=0.1).dt == 0.1  # seconds per step, as every view says


def test_an_unknown_argument_gets_a_did_you_mean() -> None:
    with pytest.raises(TypeError, match="torchrl_env got an unknown argument 'max_step'; did you mean 'max_steps'"):
        torchrl_env("paper_pa3_square", max_step=10)
    with pytest.raises(TypeError, match="did you mean 'device'"):
        torchrl_env("paper_pa3_square", devices="cpu")


def test_the_masked_distribution_leaves_padding_out_of_the_log_prob() -> None:
    """``MaskedTanhNormal``: the arm's padding entries change neither its log-prob nor its gradient; with nothing
    masked it is TorchRL's ``TanhNormal`` over the whole action."""
    gen = torch.Generator().manual_seed(0)
    loc = torch.randn(5, 4, 3, generator=gen).requires_grad_()
    scale = torch.rand(5, 4, 3, generator=gen) + 0.2
    mask = torch.tensor([True, True, False]).expand(5, 4, 3)
    dist = MaskedTanhNormal(loc, scale, mask)
    assert (dist.batch_shape, dist.event_shape) == ((5, 4), (3,))
    action = dist.sample()
    moved = action.clone()
    moved[..., 2] = -moved[..., 2]
    torch.testing.assert_close(dist.log_prob(moved), dist.log_prob(action))
    dist.log_prob(action).sum().backward()
    assert (loc.grad[..., 2] == 0).all() and (loc.grad[..., :2] != 0).all()
    whole = MaskedTanhNormal(loc, scale, torch.ones(5, 4, 3, dtype=torch.bool))
    torch.testing.assert_close(whole.log_prob(action), TanhNormal(loc, scale, event_dims=1).log_prob(action))
    assert dist.rsample((7,)).shape == (7, 5, 4, 3) and dist.log_prob(dist.rsample((7,))).shape == (7, 5, 4)
