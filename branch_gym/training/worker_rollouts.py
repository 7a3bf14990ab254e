"""Rollouts collected inside the env processes: each steps its env under a copy of the policy.

SB3's PPO steps its envs in lockstep: every vector step waits for the slowest env. Here a step
that rotates costs ~8x one that does not, so with 2 env processes one core idles while the other
finishes a rotation (bench, training mode: the learner at 0.55 of twice the single-core env
rate). With ``TrainConfig.worker_rollouts`` the learner (:class:`WorkerRolloutPPO`) instead sends
the policy's weights to every env process at the start of a rollout; each process
(:class:`PolicyRolloutWorker`, the outermost wrapper of its env) plays ``n_steps`` steps on its
own, sampling actions from its copy, and returns them (:class:`RolloutSegment`). The learner
fills its rollout buffer from the segments, replays the callbacks step by step and updates as
PPO does. The algorithm is PPO's unchanged (the same buffer, GAE and bootstrap of truncated
episodes); what differs is where the forward passes run and how often the processes wait for
each other: once per rollout instead of once per step.

Action sampling in the process of env ``rank`` is seeded by (run seed, rank, steps done when the
rollout starts): a run is reproducible, though its actions differ from a lockstep run's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

# The SB3 VecEnv info keys a worker sets itself (SubprocVecEnv would set them on a plain step).
TRUNCATED_KEY = "TimeLimit.truncated"
TERMINAL_OBSERVATION_KEY = "terminal_observation"
COLLECT_METHOD = "collect_rollout"


@dataclass(frozen=True)
class RolloutRequest:
    """What the learner sends every env process at the start of a rollout.

    Attributes:
        policy_class: The SB3 policy class (e.g. ``MultiInputPolicy``'s class).
        policy_kwargs: Its keyword arguments beyond the spaces (``model.policy_kwargs``).
        observation_space: The learner's observation space.
        action_space: The learner's action space.
        state_dict: The policy's weights (CPU tensors).
        n_steps: Steps to play.
        gamma: Discount, for the value bootstrap of episodes cut by a time limit.
        seed: The rollout's seed; each process mixes in its rank.
    """

    policy_class: type
    policy_kwargs: dict[str, Any]
    observation_space: spaces.Space
    action_space: spaces.Space
    state_dict: dict[str, torch.Tensor]
    n_steps: int
    gamma: float
    seed: int


@dataclass(frozen=True)
class RolloutSegment:
    """``n`` consecutive steps of one env under one policy (what a worker returns).

    Attributes:
        observations: The ``n`` observations acted on (each as the env returns it).
        actions: (n, *action shape) sampled actions, before clipping to a Box.
        rewards: (n,) rewards; a step that hit a time limit has ``gamma * V(final obs)`` added.
        episode_starts: (n,) whether each observation began an episode.
        values: (n,) value estimates of the observations.
        log_probs: (n,) log-probabilities of the actions.
        dones: (n,) whether each step ended its episode.
        infos: The ``n`` step infos (SB3's VecEnv keys added at episode ends).
        last_value: The value estimate of the observation after the last step.
        collect_s: Wall time the worker took (s), policy passes included.
    """

    observations: list[Any]
    actions: np.ndarray
    rewards: np.ndarray
    episode_starts: np.ndarray
    values: np.ndarray
    log_probs: np.ndarray
    dones: np.ndarray
    infos: list[dict[str, Any]]
    last_value: float
    collect_s: float


def _unused_learning_rate(_progress_remaining: float) -> float:
    """A worker's policy copy never steps its optimiser (picklable, unlike a lambda)."""
    return 0.0


class PolicyRolloutWorker(gym.Wrapper):
    """The outermost wrapper of a training env: plays whole rollouts under a policy copy.

    Plain ``reset`` and ``step`` pass through (and remember the current observation), so the env
    also works in an ordinary ``SubprocVecEnv``. :meth:`collect_rollout` is what
    :class:`WorkerRolloutPPO` calls through ``VecEnv.env_method``.

    Args:
        env: The training env (its other wrappers inside this one).
        rank: The env's index in the vector env (mixed into the action-sampling seed).
    """

    def __init__(self, env: gym.Env, rank: int) -> None:
        super().__init__(env)
        self.rank = int(rank)
        self._observation: Any = None
        self._episode_start = True
        self._policy: Any = None
        self._policy_class: type | None = None

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        self._observation, self._episode_start = observation, True
        return observation, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        self._observation, self._episode_start = observation, terminated or truncated
        return observation, reward, terminated, truncated, info

    def collect_rollout(self, request: RolloutRequest) -> RolloutSegment:
        """Play ``request.n_steps`` steps, resetting at episode ends, like one env of PPO.

        Raises:
            RuntimeError: the env has not been reset.
        """
        if self._observation is None:
            raise RuntimeError("PolicyRolloutWorker.collect_rollout before the env was reset")
        start = time.perf_counter()
        policy = self._policy_copy(request)
        torch.manual_seed(
            int(np.random.SeedSequence([request.seed, self.rank]).generate_state(1)[0])
        )
        observations, actions, infos = [], [], []
        rewards, starts, values, log_probs, dones = [], [], [], [], []
        for _ in range(request.n_steps):
            with torch.no_grad():
                observation_tensor, _ = policy.obs_to_tensor(self._observation)
                action, value, log_prob = policy(observation_tensor)
            action = action.cpu().numpy()[0]
            env_action = action
            if isinstance(request.action_space, spaces.Box):
                env_action = np.clip(action, request.action_space.low, request.action_space.high)
            observation, reward, terminated, truncated, info = self.env.step(env_action)
            done = bool(terminated or truncated)
            if done:
                info[TRUNCATED_KEY] = bool(truncated and not terminated)
                info[TERMINAL_OBSERVATION_KEY] = observation
                if info[TRUNCATED_KEY]:
                    reward = float(reward) + request.gamma * _value(policy, observation)
                observation, _ = self.env.reset()
            observations.append(self._observation)
            actions.append(action)
            infos.append(info)
            rewards.append(float(reward))
            starts.append(self._episode_start)
            values.append(float(value.item()))
            log_probs.append(float(log_prob.item()))
            dones.append(done)
            self._observation, self._episode_start = observation, done
        return RolloutSegment(
            observations=observations,
            actions=np.asarray(actions),
            rewards=np.asarray(rewards, np.float32),
            episode_starts=np.asarray(starts, np.float32),
            values=np.asarray(values, np.float32),
            log_probs=np.asarray(log_probs, np.float32),
            dones=np.asarray(dones, bool),
            infos=infos,
            last_value=_value(policy, self._observation),
            collect_s=time.perf_counter() - start,
        )

    def _policy_copy(self, request: RolloutRequest) -> Any:
        """This process's policy (built on the first request) with the request's weights."""
        if self._policy is None or self._policy_class is not request.policy_class:
            self._policy = request.policy_class(
                request.observation_space,
                request.action_space,
                _unused_learning_rate,
                **request.policy_kwargs,
            )
            self._policy_class = request.policy_class
        self._policy.load_state_dict(request.state_dict)
        self._policy.set_training_mode(False)
        return self._policy


def _value(policy: Any, observation: Any) -> float:
    """The policy's value estimate of one observation."""
    with torch.no_grad():
        observation_tensor, _ = policy.obs_to_tensor(observation)
        return float(policy.predict_values(observation_tensor).item())


def _stack(observations: list[Any]) -> Any:
    """One observation per env -> the batch a VecEnv returns (a dict of arrays for Dict obs)."""
    if isinstance(observations[0], dict):
        return {key: np.stack([obs[key] for obs in observations]) for key in observations[0]}
    return np.stack(observations)


class WorkerRolloutPPO(PPO):
    """stable-baselines3 PPO whose rollouts the env processes collect (module docstring).

    The training env must be a VecEnv whose envs are wrapped (outermost) in
    :class:`PolicyRolloutWorker`, with no VecEnv wrapper that changes observations or rewards
    (``VecNormalize``, ``VecTransposeImage``): the workers act on the raw observations. Saved
    models are ordinary PPO model files.
    """

    def collect_rollouts(
        self, env: VecEnv, callback: Any, rollout_buffer: Any, n_rollout_steps: int
    ) -> bool:
        """Fill ``rollout_buffer`` with ``n_rollout_steps`` steps of every env (SB3's contract).

        Returns:
            False when a callback stopped training, else True.

        Raises:
            ValueError: ``env`` is wrapped, or its envs are not ``PolicyRolloutWorker``s.
        """
        if isinstance(env, VecEnvWrapper):
            raise ValueError(
                f"WorkerRolloutPPO needs the workers' own observations; the env is wrapped in "
                f"{type(env).__name__} (worker rollouts cannot normalise or transpose)"
            )
        if not env.has_attr(COLLECT_METHOD):
            raise ValueError("WorkerRolloutPPO needs envs wrapped in PolicyRolloutWorker")
        self.policy.set_training_mode(False)
        rollout_buffer.reset()
        callback.on_rollout_start()
        request = RolloutRequest(
            policy_class=self.policy_class,
            policy_kwargs=self.policy_kwargs,
            observation_space=self.observation_space,
            action_space=self.action_space,
            state_dict={k: v.detach().cpu() for k, v in self.policy.state_dict().items()},
            n_steps=n_rollout_steps,
            gamma=self.gamma,
            seed=int(
                np.random.SeedSequence([self.seed or 0, self.num_timesteps]).generate_state(1)[0]
            ),
        )
        segments: list[RolloutSegment] = env.env_method(COLLECT_METHOD, request)
        collect_s = [segment.collect_s for segment in segments]
        # The share of the workers' time spent waiting for the slowest one (lost to imbalance).
        self.logger.record("time/worker_wait_fraction", 1.0 - np.mean(collect_s) / max(collect_s))
        for step in range(n_rollout_steps):
            infos = [segment.infos[step] for segment in segments]
            dones = np.array([segment.dones[step] for segment in segments])
            rewards = np.array([segment.rewards[step] for segment in segments], np.float32)
            actions = np.stack([segment.actions[step] for segment in segments])
            self.num_timesteps += env.num_envs
            callback.update_locals(
                {"infos": infos, "dones": dones, "rewards": rewards, "actions": actions}
            )
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)
            if isinstance(self.action_space, spaces.Discrete):
                actions = actions.reshape(-1, 1)
            rollout_buffer.add(
                _stack([segment.observations[step] for segment in segments]),
                actions,
                rewards,
                np.array([segment.episode_starts[step] for segment in segments], np.float32),
                torch.as_tensor([segment.values[step] for segment in segments]),
                torch.as_tensor([segment.log_probs[step] for segment in segments]),
            )
        self._last_episode_starts = dones  # (the current observations stay in the workers)
        last_values = torch.as_tensor([[segment.last_value] for segment in segments])
        rollout_buffer.compute_returns_and_advantage(last_values=last_values, dones=dones)
        callback.update_locals({"infos": infos, "dones": dones})
        callback.on_rollout_end()
        return True
