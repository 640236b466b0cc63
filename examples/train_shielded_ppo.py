"""Train PPO behind the safety shield on Section 5.2's team, then check it never collided.

    python examples/train_shielded_ppo.py

Needs the rl extra; install PyTorch's CPU-only wheel first (see the README).
"""

import gymnasium
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env

import pan1_env  # noqa: F401  (registers the ids)
from pan1_env.wrappers import GymSafetyShield

torch.set_num_threads(1)


def make_env():
    return GymSafetyShield(gymnasium.make("pan1_env/PaperMixedPA-v0", max_steps=200))


venv = make_vec_env(make_env, n_envs=2, seed=0)
model = PPO("MlpPolicy", venv, n_steps=512, batch_size=256, seed=0, device="cpu", verbose=0)
model.learn(total_timesteps=4096)

env = make_env()
obs, info = env.reset(seed=123)
cost, done, ret = 0.0, False, 0.0
while not done:
    action, _ = model.predict(obs, deterministic=True)
    obs, reward, terminated, truncated, info = env.step(action)
    cost, ret, done = cost + info["cost"], ret + reward, terminated or truncated
print(f"return {ret:.1f}, cost {cost:g}, final formation error {info['formation_error']:.3f} m")
assert cost == 0.0 and np.isfinite(ret)
