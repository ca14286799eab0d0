"""The shipped PPO agent's residual actions on the 16 validation drops of rig-randomized: percentiles."""
import numpy as np, torch
from stable_baselines3 import PPO
from agents.train import make_config, _vec_env
from agents.callbacks import FixedSeeds
torch.set_num_threads(1)
cfg = make_config("ppo")
env = FixedSeeds(_vec_env(cfg, 16, evaluation=True), 900000)
model = PPO.load("agents/models/best/model.zip", device="cpu")
obs = env.reset(); acts = []
for _ in range(1000):
    a, _ = model.predict(obs, deterministic=True)
    acts.append(a.ravel().copy()); obs, r, d, i = env.step(a)
acts = np.concatenate(acts)
print("residual action percentiles (fraction of 200 N):", {q: round(float(np.percentile(acts, q)), 3) for q in (0.5, 2.5, 50, 97.5, 99.5)},
      "max |a|", round(float(np.abs(acts).max()), 3), "share |a|>0.25:", round(float(np.mean(np.abs(acts) > 0.25)), 4))
