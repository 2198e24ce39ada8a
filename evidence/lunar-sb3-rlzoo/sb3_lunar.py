
import json, sys, time
import torch
torch.set_num_threads(1)  # 2 (bench_atari's) spin on 2 busy cores: 12x slower here
import gymnasium as gym
import stable_baselines3
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.env_util import make_vec_env

algo, total, episodes = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
if algo == "ppo":  # hyperparams/ppo.yml's LunarLander: SB3's defaults elsewhere (lr 3e-4, clip 0.2)
    env = make_vec_env("LunarLander-v3", n_envs=16, seed=0)
    model = PPO("MlpPolicy", env, n_steps=1024, batch_size=64, n_epochs=4, gae_lambda=0.98, gamma=0.999,
                ent_coef=0.01, seed=0, verbose=0, device="cpu")
else:  # hyperparams/dqn.yml's LunarLander
    env = make_vec_env("LunarLander-v3", n_envs=1, seed=0)
    model = DQN("MlpPolicy", env, learning_rate=6.3e-4, batch_size=128, buffer_size=50_000,
                learning_starts=0, gamma=0.99, target_update_interval=250, train_freq=4, gradient_steps=-1,
                exploration_fraction=0.12, exploration_final_eps=0.1,
                policy_kwargs=dict(net_arch=[256, 256]), seed=0, verbose=0, device="cpu")
start = time.perf_counter()
model.learn(total_timesteps=total)
seconds = time.perf_counter() - start
eval_env, returns = gym.make("LunarLander-v3"), []
for seed in range(1, episodes + 1):
    obs, _ = eval_env.reset(seed=seed)
    done, total_reward = False, 0.0
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, _ = eval_env.step(action)
        total_reward, done = total_reward + reward, terminated or truncated
    returns.append(total_reward)
mean = sum(returns) / len(returns)
std = (sum((r - mean) ** 2 for r in returns) / len(returns)) ** 0.5
print(json.dumps({"steps": total, "seconds": seconds, "mean": mean, "std": std, "torch": torch.__version__,
                  "sb3": stable_baselines3.__version__}))
