"""Train the arms with MAPPO (or IPPO) written in plain TorchRL, in the shape of TorchRL's multi-agent PPO tutorial:
one policy network shared by the arms, acting on each arm's own observation, behind the shield.

    pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu
    pip install -e ".[marl]"
    python examples/torchrl_mappo.py --scenario paper_pa3_square --iterations 50
    python examples/torchrl_mappo.py --scenario paper_pa_mixed_square --ippo

The env is :func:`pan1_env.marl.torchrl_env` (B copies in one batched call). Arms of different kinds share one
padded action; the policy's distribution is :class:`pan1_env.marl.MaskedTanhNormal`, which reads
``("arms", "action_mask")`` and leaves an arm's padding entries out of its log-prob, so out of PPO's ratio and
entropy. Before and after training the deterministic policy is evaluated on the same seeded episodes; ``main``
returns both evaluations (``tests/test_torchrl_example.py`` checks that the trained one forms better, at no cost).
Runs on TorchRL 0.11 (BenchMARL's pin) and 0.14 (the ``marl`` extra's).
"""

from __future__ import annotations

import argparse
import inspect
from dataclasses import dataclass

import torch
from tensordict.nn import TensorDictModule
from tensordict.nn.distributions import NormalParamExtractor
from torch import nn
from torchrl.data.replay_buffers import ReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.data.replay_buffers.storages import LazyTensorStorage
from torchrl.envs import RewardSum, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MultiAgentMLP, ProbabilisticActor
from torchrl.objectives import ClipPPOLoss, ValueEstimators
from tqdm import tqdm

from pan1_env.marl import GROUP, MaskedTanhNormal, torchrl_env

# TorchRL compatibility: 0.11 has both `SyncDataCollector` and its new name `Collector`, 0.14 only `Collector`;
# ClipPPOLoss's `entropy_coef` became `entropy_coeff` (BenchMARL 1.5 still allows TorchRL 0.10, which has the old
# names only).
try:
    from torchrl.collectors import Collector
except ImportError:  # TorchRL < 0.11
    from torchrl.collectors import SyncDataCollector as Collector
ENTROPY_COEFF = "entropy_coeff" if "entropy_coeff" in inspect.signature(ClipPPOLoss).parameters else "entropy_coef"


@dataclass
class Evaluation:
    """The deterministic policy over seeded episodes: the team's return (the arms' mean reward summed over the
    episode, averaged over episodes), the formation error at the end (m), the share of episodes that end formed,
    and the arm-steps inside an obstacle in all."""

    episode_return: float
    final_formation_error: float
    success_rate: float
    total_cost: float


def build_env(args: argparse.Namespace, copies: int) -> TransformedEnv:
    env = torchrl_env(args.scenario, num_envs=copies, max_steps=args.max_steps, safety_filter=not args.no_shield)
    return TransformedEnv(env, RewardSum(in_keys=[env.reward_key], out_keys=[(GROUP, "episode_reward")]))


def build_policy(env: TransformedEnv, args: argparse.Namespace) -> ProbabilisticActor:
    """Each arm's observation → the loc and scale of its padded action, one network shared by the arms."""
    obs, actions = env.observation_spec[GROUP, "observation"].shape[-1], env.action_spec[GROUP, "action"].shape[-1]
    net = nn.Sequential(
        MultiAgentMLP(n_agent_inputs=obs, n_agent_outputs=2 * actions, n_agents=env.n_agents, centralised=False,
                      share_params=True, depth=2, num_cells=args.cells, activation_class=nn.Tanh),
        NormalParamExtractor())
    module = TensorDictModule(net, in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "loc"), (GROUP, "scale")])
    return ProbabilisticActor(
        module, spec=env.full_action_spec_unbatched[env.action_key], out_keys=[env.action_key],
        in_keys={"loc": (GROUP, "loc"), "scale": (GROUP, "scale"), "mask": (GROUP, "action_mask")},
        distribution_class=MaskedTanhNormal, distribution_kwargs={"low": -1.0, "high": 1.0}, return_log_prob=True)


def build_critic(env: TransformedEnv, args: argparse.Namespace) -> TensorDictModule:
    """Each arm's value; MAPPO's critic reads every arm's observation (centralised), IPPO's its own."""
    net = MultiAgentMLP(n_agent_inputs=env.observation_spec[GROUP, "observation"].shape[-1], n_agent_outputs=1,
                        n_agents=env.n_agents, centralised=not args.ippo, share_params=True, depth=2,
                        num_cells=args.cells, activation_class=nn.Tanh)
    return TensorDictModule(net, in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "state_value")])


def build_loss(policy: ProbabilisticActor, critic: TensorDictModule, env: TransformedEnv,
               args: argparse.Namespace) -> ClipPPOLoss:
    # advantages normalised over the batch, each arm's apart (dim -2 of [batch, arms, 1])
    loss = ClipPPOLoss(actor_network=policy, critic_network=critic, clip_epsilon=args.clip, normalize_advantage=True,
                       normalize_advantage_exclude_dims=(-2,), **{ENTROPY_COEFF: args.entropy})
    loss.set_keys(reward=env.reward_key, action=env.action_key, value=(GROUP, "state_value"),
                  done=(GROUP, "done"), terminated=(GROUP, "terminated"))
    loss.make_value_estimator(ValueEstimators.GAE, gamma=args.gamma, lmbda=args.lmbda)
    return loss


def evaluate(env: TransformedEnv, policy: ProbabilisticActor, seed: int) -> Evaluation:
    """One episode of every copy of ``env``, from ``seed``, with the policy's deterministic action."""
    env.set_seed(seed)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        rollout = env.rollout(env.base_env.core.config.max_steps, policy, break_when_any_done=False)
    last = rollout[:, -1]["next"]
    return Evaluation(episode_return=last[GROUP, "episode_reward"].mean().item(),
                      final_formation_error=last["info", "formation_error"].mean().item(),
                      success_rate=last["info", "is_success"].float().mean().item(),
                      total_cost=rollout["next", GROUP, "cost"].sum().item())


def train(env: TransformedEnv, policy: ProbabilisticActor, critic: TensorDictModule, args: argparse.Namespace) -> None:
    """The tutorial's loop: collect a batch, compute GAE, then epochs of minibatch PPO updates."""
    frames = args.copies * args.max_steps  # an episode's length of every copy: each iteration ends episodes
    collector = Collector(env, policy, frames_per_batch=frames, total_frames=frames * args.iterations)
    buffer = ReplayBuffer(storage=LazyTensorStorage(frames), sampler=SamplerWithoutReplacement(),
                          batch_size=args.minibatch)
    loss = build_loss(policy, critic, env, args)
    optimiser = torch.optim.Adam(loss.parameters(), args.lr)
    name = "IPPO" if args.ippo else "MAPPO"
    bar = tqdm(collector, total=args.iterations, desc=f"{name} iterations", unit="iteration")  # minutes: say so
    for batch in bar:
        with torch.no_grad():
            loss.value_estimator(batch, params=loss.critic_network_params,
                                 target_params=loss.target_critic_network_params)
        buffer.extend(batch.reshape(-1))
        for _ in range(args.epochs):
            for _ in range(frames // args.minibatch):
                terms = loss(buffer.sample())
                value = terms["loss_objective"] + terms["loss_critic"] + terms["loss_entropy"]
                value.backward()
                nn.utils.clip_grad_norm_(loss.parameters(), args.max_grad_norm)
                optimiser.step()
                optimiser.zero_grad()
        collector.update_policy_weights_()
        done = batch["next", "done"].squeeze(-1)
        if done.any():  # the mean return of the episodes that ended in this batch
            bar.set_postfix(episode_return=f"{batch['next', GROUP, 'episode_reward'][done].mean().item():.3f}")
    collector.shutdown()


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_pa3_square", help="a scenario or registered id")
    parser.add_argument("--iterations", type=int, default=50, help="collect-and-update rounds")
    parser.add_argument("--copies", type=int, default=32, help="env copies stepped together (one episode each)")
    parser.add_argument("--max-steps", type=int, default=50, help="steps per episode (of 0.05 s)")
    parser.add_argument("--epochs", type=int, default=4, help="passes over each batch")
    parser.add_argument("--minibatch", type=int, default=400)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--gamma", type=float, default=0.99)
    parser.add_argument("--lmbda", type=float, default=0.9)
    parser.add_argument("--clip", type=float, default=0.2)
    parser.add_argument("--entropy", type=float, default=1e-4, help="entropy bonus coefficient")
    parser.add_argument("--max-grad-norm", type=float, default=1.0)
    parser.add_argument("--cells", type=int, default=64, help="hidden units per layer")
    parser.add_argument("--ippo", action="store_true", help="each arm's critic reads its own observation only")
    parser.add_argument("--no-shield", action="store_true", help="train without the safety filter")
    parser.add_argument("--eval-copies", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> tuple[Evaluation, Evaluation]:
    """Train as ``argv`` says; the deterministic policy's evaluation before and after training."""
    args = parse(argv)
    torch.manual_seed(args.seed)
    env, test_env = build_env(args, args.copies), build_env(args, args.eval_copies)
    env.set_seed(args.seed)
    policy, critic = build_policy(env, args), build_critic(env, args)
    before = evaluate(test_env, policy, seed=10_000 + args.seed)
    train(env, policy, critic, args)
    after = evaluate(test_env, policy, seed=10_000 + args.seed)
    print(f"before: {before}\nafter:  {after}")
    return before, after


if __name__ == "__main__":
    main()
