"""Regenerate the README's frames: docs/frame_<scenario>.png at the start and after 20 s of the
paper's controller (the reference policy behind the safety shield).

    python docs/make_frames.py
"""

from pathlib import Path

import numpy as np
from PIL import Image

from pan1_env import parallel_env
from pan1_env.baselines import ReferencePolicy
from pan1_env.wrappers import SafetyShield

for name in ("paper_pa3_square", "paper_pa_mixed_square"):
    env = SafetyShield(parallel_env(name, render_mode="rgb_array"))
    obs, _ = env.reset(seed=0)
    start = env.render()
    policy = ReferencePolicy(env)
    for _ in range(400):  # 20 s
        obs, *_ = env.step(policy(obs))
    frame = np.concatenate([start, env.render()], axis=1)
    Image.fromarray(frame).save(Path(__file__).with_name(f"frame_{name}.png"), optimize=True)
    env.close()
