"""A compact PPO in plain PyTorch over ``gymnasium.vector``, training on ``BranchScanFlat-v0``.

No stable-baselines3 anywhere: the environment needs only gymnasium's API. The algorithm is PPO
with a clipped surrogate objective and GAE (Schulman et al. 2017, "Proximal Policy Optimization
Algorithms"; the defaults below are that paper's MuJoCo settings, scaled down to a short run).

Usage::

    python examples/torch_ppo.py --updates 5 --num-envs 2 --steps 64 --seed 0 [--async]

One line per update: env steps so far, the mean return of the episodes that ended in the update,
and the losses. Scans use the depth-oracle tracker in its fast mode (only the frames the modeler
runs on are rendered) and end at 0.4 m by default (an episode is ~18 steps); ``--tracker lk
--end-height 0.75`` gives the full task (Lucas-Kanade on every rendered frame).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import gymnasium
import numpy as np
import torch
from gymnasium.vector import AutoresetMode
from torch import nn

import branch_gym

# Fast episodes: exact tracks from the rendered depth, rendering only the frames the modeler
# runs on (the oracle's fast mode), ending just above the 0.275 m start height.
FAST_ENV = {"tracker": "oracle", "end_height_m": 0.4, "render_tracking_frames": False}


@dataclass(frozen=True)
class PPOConfig:
    """One training run.

    Defaults: Schulman et al. 2017, Table 3 (MuJoCo) with a shorter rollout; value coefficient
    and gradient clipping as in OpenAI baselines' ppo2.

    Attributes:
        env_id: A registered id with a flat Box observation and a Box action.
        env_kwargs: Keywords for ``gymnasium.make_vec`` (the env's own arguments).
        num_envs: Environments stepped side by side.
        vectorization: "sync" (one process) or "async" (a process per env).
        steps_per_env: Rollout length per env and update (env steps).
        updates: Number of rollout + optimisation rounds.
        epochs: Passes over each rollout.
        minibatch_size: Transitions per gradient step.
        learning_rate: Adam step size.
        gamma: Discount per env step (one modeling iteration, ~10 mm of travel).
        gae_lambda: GAE's lambda.
        clip: PPO's ratio clip.
        value_coef: Weight of the value loss.
        entropy_coef: Weight of the entropy bonus.
        max_grad_norm: Gradient clipping (global norm).
        hidden: Units of the two hidden layers of actor and critic.
        init_log_std: Initial log standard deviation of the actions (normalised to [-1, 1]).
            Our choice: std 0.37, rotations of ~17 deg; every rotation is camera motion that
            costs scan time and simulation, so a unit std (actions mostly at +-45 deg) makes
            steps 2-4x slower.
        seed: Seeds the environments, the network and every sample.
    """

    env_id: str = branch_gym.FLAT_ENV_ID
    env_kwargs: dict = field(default_factory=lambda: dict(FAST_ENV))
    num_envs: int = 2
    vectorization: str = "sync"
    steps_per_env: int = 64
    updates: int = 5
    epochs: int = 10
    minibatch_size: int = 64
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip: float = 0.2
    value_coef: float = 0.5
    entropy_coef: float = 0.0
    max_grad_norm: float = 0.5
    hidden: int = 64
    init_log_std: float = -1.0
    seed: int = 0


@dataclass(frozen=True)
class UpdateStats:
    """What one update did (losses averaged over its gradient steps)."""

    update: int
    env_steps: int
    episodes: int
    mean_return: float  # NaN when no episode ended during the rollout
    policy_loss: float
    value_loss: float
    entropy: float
    approx_kl: float


def _mlp(inputs: int, hidden: int, outputs: int, out_gain: float) -> nn.Sequential:
    """Two tanh hidden layers, orthogonal init (gain sqrt(2) hidden, ``out_gain`` output)."""
    layers = [nn.Linear(inputs, hidden), nn.Linear(hidden, hidden), nn.Linear(hidden, outputs)]
    for layer, gain in zip(layers, (math.sqrt(2), math.sqrt(2), out_gain), strict=True):
        nn.init.orthogonal_(layer.weight, gain)
        nn.init.zeros_(layer.bias)
    return nn.Sequential(layers[0], nn.Tanh(), layers[1], nn.Tanh(), layers[2])


class ActorCritic(nn.Module):
    """Gaussian policy (state-independent std) and value function, separate MLPs."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: int, init_log_std: float) -> None:
        super().__init__()
        self.actor = _mlp(obs_dim, hidden, act_dim, out_gain=0.01)  # near-zero initial mean
        self.critic = _mlp(obs_dim, hidden, 1, out_gain=1.0)
        self.log_std = nn.Parameter(torch.full((act_dim,), init_log_std))

    @classmethod
    def for_env(cls, envs: gymnasium.vector.VectorEnv, config: PPOConfig) -> ActorCritic:
        """A network sized for the vector env's flat observation and Box action."""
        obs_dim = envs.single_observation_space.shape[0]
        act_dim = envs.single_action_space.shape[0]
        return cls(obs_dim, act_dim, config.hidden, config.init_log_std)

    def dist(self, obs: torch.Tensor) -> torch.distributions.Normal:
        return torch.distributions.Normal(self.actor(obs), self.log_std.exp())

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        return self.critic(obs).squeeze(-1)


def make_envs(config: PPOConfig) -> gymnasium.vector.VectorEnv:
    """The vector env; SAME_STEP autoreset: every stored step is a real transition."""
    return gymnasium.make_vec(
        config.env_id,
        num_envs=config.num_envs,
        vectorization_mode=config.vectorization,
        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP},
        **config.env_kwargs,
    )


def train(
    config: PPOConfig,
    log: Callable[[UpdateStats], None] | None = None,
    model: ActorCritic | None = None,
) -> tuple[ActorCritic, list[UpdateStats]]:
    """Train a policy (a new one, or ``model`` further); returns it and per-update statistics."""
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed)
    envs = make_envs(config)
    obs_dim = envs.single_observation_space.shape[0]
    space = envs.single_action_space
    low, high = space.low, space.high
    model = model if model is not None else ActorCritic.for_env(envs, config)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate, eps=1e-5)
    n, t_max = config.num_envs, config.steps_per_env
    obs = torch.as_tensor(envs.reset(seed=config.seed)[0])
    running_return, history = np.zeros(n), []
    for update in range(1, config.updates + 1):
        buf_obs = torch.zeros(t_max, n, obs_dim)
        buf_act = torch.zeros(t_max, n, space.shape[0])
        buf_logp, buf_val, buf_rew, buf_done = (torch.zeros(t_max, n) for _ in range(4))
        returns: list[float] = []
        for t in range(t_max):  # ------------------------------------------------ rollout
            with torch.no_grad():
                dist = model.dist(obs)
                action = dist.mean + dist.stddev * torch.randn(dist.mean.shape, generator=generator)
                buf_logp[t], buf_val[t] = dist.log_prob(action).sum(-1), model.value(obs)
            next_obs, reward, terminated, truncated, info = envs.step(
                np.clip(action.numpy(), low, high)
            )
            running_return += reward
            for i in np.flatnonzero(terminated | truncated):
                returns.append(float(running_return[i]))
                running_return[i] = 0.0
            reward = torch.as_tensor(reward, dtype=torch.float32)
            for i in np.flatnonzero(truncated & ~terminated):  # time limit: bootstrap V(s_T)
                final = torch.as_tensor(info["final_obs"][i])
                with torch.no_grad():
                    reward[i] += config.gamma * model.value(final)
            buf_obs[t], buf_act[t], buf_rew[t] = obs, action, reward
            buf_done[t] = torch.as_tensor(terminated | truncated, dtype=torch.float32)
            obs = torch.as_tensor(next_obs)
        with torch.no_grad():  # ------------------------------------------------- GAE
            next_value, advantage = model.value(obs), torch.zeros(n)
            advantages = torch.zeros(t_max, n)
            for t in reversed(range(t_max)):
                alive = 1.0 - buf_done[t]
                delta = buf_rew[t] + config.gamma * next_value * alive - buf_val[t]
                advantage = delta + config.gamma * config.gae_lambda * alive * advantage
                advantages[t], next_value = advantage, buf_val[t]
            targets = advantages + buf_val
        stats = _optimise(
            model,
            optimiser,
            config,
            generator,
            (buf_obs, buf_act, buf_logp, advantages, targets),
        )
        mean_return = float(np.mean(returns)) if returns else math.nan
        history.append(UpdateStats(update, update * t_max * n, len(returns), mean_return, *stats))
        if log is not None:
            log(history[-1])
    envs.close()
    return model, history


def _optimise(
    model: ActorCritic,
    optimiser: torch.optim.Optimizer,
    config: PPOConfig,
    generator: torch.Generator,
    rollout: tuple[torch.Tensor, ...],
) -> tuple[float, float, float, float]:
    """PPO epochs over one rollout; returns mean (policy loss, value loss, entropy, approx KL)."""
    obs, act, old_logp, adv, targets = (x.flatten(0, 1) for x in rollout)
    sums, steps = np.zeros(4), 0
    for _ in range(config.epochs):
        order = torch.randperm(len(obs), generator=generator)
        for batch in order.split(config.minibatch_size):
            dist = model.dist(obs[batch])
            logp = dist.log_prob(act[batch]).sum(-1)
            log_ratio = logp - old_logp[batch]
            ratio = log_ratio.exp()
            a = adv[batch]
            a = (a - a.mean()) / (a.std(unbiased=False) + 1e-8)
            clipped = ratio.clamp(1.0 - config.clip, 1.0 + config.clip)
            policy_loss = -torch.min(ratio * a, clipped * a).mean()
            value_loss = 0.5 * (model.value(obs[batch]) - targets[batch]).pow(2).mean()
            entropy = dist.entropy().sum(-1).mean()
            loss = policy_loss + config.value_coef * value_loss - config.entropy_coef * entropy
            optimiser.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(model.parameters(), config.max_grad_norm)
            optimiser.step()
            with torch.no_grad():  # Schulman's low-variance KL estimator
                kl = ((ratio - 1.0) - log_ratio).mean()
            sums += [policy_loss.item(), value_loss.item(), entropy.item(), kl.item()]
            steps += 1
    return tuple(float(x) for x in sums / steps)  # type: ignore[return-value]


def main(argv: list[str] | None = None) -> list[UpdateStats]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--updates", type=int, default=PPOConfig.updates)
    parser.add_argument("--num-envs", type=int, default=PPOConfig.num_envs)
    parser.add_argument("--steps", type=int, default=PPOConfig.steps_per_env, help="per env")
    parser.add_argument("--epochs", type=int, default=PPOConfig.epochs)
    parser.add_argument("--seed", type=int, default=PPOConfig.seed)
    parser.add_argument("--async", dest="vectorization", action="store_const", const="async")
    parser.add_argument("--tracker", default=FAST_ENV["tracker"], choices=("lk", "oracle"))
    parser.add_argument("--end-height", type=float, default=FAST_ENV["end_height_m"])
    args = parser.parse_args(argv)
    torch.set_num_threads(1)  # a small network on small batches: threads only add overhead
    config = PPOConfig(
        env_kwargs={
            "tracker": args.tracker,
            "end_height_m": args.end_height,
            "render_tracking_frames": args.tracker == "lk",  # fast mode: oracle tracks only
        },
        num_envs=args.num_envs,
        vectorization=args.vectorization or "sync",
        steps_per_env=args.steps,
        updates=args.updates,
        epochs=args.epochs,
        seed=args.seed,
    )
    print(f"PPO on {config.env_id} {config.env_kwargs}, {config.num_envs} {config.vectorization}")

    def log(s: UpdateStats) -> None:
        print(
            f"update {s.update:3d}  steps {s.env_steps:5d}  episodes {s.episodes:2d}  "
            f"return {s.mean_return:7.3f}  policy {s.policy_loss:+.4f}  value {s.value_loss:.4f}  "
            f"entropy {s.entropy:.3f}  kl {s.approx_kl:.5f}"
        )

    return train(config, log)[1]


if __name__ == "__main__":
    main()
