"""Training callbacks: the scan metrics of every finished episode, torch threads, a progress bar.

:class:`ScanMetricsCallback` reads ``info["final_metrics"]`` (the scan's final row, scored
against the ground truth) when an episode ends and logs ``SCAN_METRICS``:

- ``scan/<name>``: the mean over the episodes finished since the last log write (SB3's
  ``logger.record_mean``; next to ``rollout/ep_rew_mean``), plus ``scan/episodes``;
- ``episode/<name>``: one TensorBoard point per episode, at the step it ended.

Undefined values (``missed_pct`` of a tree without secondaries is None) are skipped. Episodes
cut by the env's step limit have no final row and are not counted.

:class:`TorchThreadsCallback` gives the learner's torch one thread while the env workers step
(the policy's forward pass is ~1 ms; more threads only compete with the workers for the cores)
and every core during the update, when the workers wait.

:class:`ValueWarmupCallback` lets only the value function learn during a run's first steps: a
run started from a policy fitted elsewhere (a DAgger student, ``TrainConfig.init_model``) has an
untrained critic, whose advantages would otherwise push the policy in random directions.
:class:`WarmupLearningRate` is the learning-rate schedule that goes with it: the critic may warm
up at a larger step than the fine-tuning's.
"""

from __future__ import annotations

from typing import Any

import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import TensorBoardOutputFormat

FINAL_METRICS_KEY = "final_metrics"
SCAN_PREFIX = "scan/"
EPISODE_PREFIX = "episode/"
FAILED = "failed"  # 1 when the scan failed (singularity, joint limit, lost branch, ...)
# Columns of ScanResult.to_row() logged per episode, in this order.
SCAN_METRICS = (
    "missed_pct",
    "spurious_pct",
    "duplicate_pct",
    "n_matched",
    "rotations",
    "scan_time_s",
    FAILED,
)


def scan_metrics(final: dict[str, Any]) -> dict[str, float]:
    """The logged metrics of one finished scan (undefined ones left out).

    Args:
        final: ``info["final_metrics"]`` of the episode's last step.
    """
    values = dict(final)
    values[FAILED] = 1.0 if final.get("failure") else 0.0
    return {
        name: float(values[name])
        for name in SCAN_METRICS
        if isinstance(values.get(name), (int, float))
    }


class ScanMetricsCallback(BaseCallback):
    """Log the scan metrics of every episode that ends (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__()
        self.episodes = 0  # episodes logged by this callback

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", ()):
            final = info.get(FINAL_METRICS_KEY)
            if final is None:
                continue
            self.episodes += 1
            metrics = scan_metrics(final)
            for name, value in metrics.items():
                self.logger.record_mean(SCAN_PREFIX + name, value)
            self.logger.record(SCAN_PREFIX + "episodes", self.episodes)
            for writer in self._tensorboard_writers():
                for name, value in metrics.items():
                    writer.add_scalar(EPISODE_PREFIX + name, value, self.num_timesteps)
        return True

    def _tensorboard_writers(self) -> list[Any]:
        return [
            fmt.writer
            for fmt in self.logger.output_formats
            if isinstance(fmt, TensorBoardOutputFormat)
        ]


class TorchThreadsCallback(BaseCallback):
    """Torch intra-op threads by phase: few while the env workers step, many in the update.

    Measured on 2 cores (training mode, 2 env processes, 512 steps and one update): 2 threads
    throughout 33.5 steps/s, 1 throughout 36.4, 1 in rollouts and 2 in the update 37.0 (the
    forward passes' threads took ~5 ms of each vector step from the workers; the update ran in
    1.0 s on 2 threads, 1.6 s on 1).

    Args:
        rollout_threads: Threads while collecting rollouts.
        update_threads: Threads during the gradient update.
    """

    def __init__(self, rollout_threads: int, update_threads: int) -> None:
        super().__init__()
        if rollout_threads < 1 or update_threads < 1:
            raise ValueError(
                f"thread counts must be >= 1, got rollout_threads={rollout_threads}, "
                f"update_threads={update_threads}"
            )
        self.rollout_threads = rollout_threads
        self.update_threads = update_threads
        self._initial: int | None = None

    def _on_training_start(self) -> None:
        self._initial = torch.get_num_threads()

    def _on_rollout_start(self) -> None:
        torch.set_num_threads(self.rollout_threads)

    def _on_rollout_end(self) -> None:
        torch.set_num_threads(self.update_threads)

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        if self._initial is not None:
            torch.set_num_threads(self._initial)


class TqdmCallback(BaseCallback):
    """A tqdm progress bar over environment steps, from the steps done to ``total``.

    Args:
        total: The run's step target (``TrainConfig.timesteps``).
    """

    def __init__(self, total: int) -> None:
        super().__init__()
        self.total = total
        self._bar: Any = None

    def _on_training_start(self) -> None:
        from tqdm import tqdm

        self._bar = tqdm(
            total=self.total,
            initial=self.num_timesteps,
            unit="step",
            desc="training",
            smoothing=0.1,
        )

    def _on_step(self) -> bool:
        self._bar.update(self.training_env.num_envs)
        return True

    def _on_training_end(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class ValueWarmupCallback(BaseCallback):
    """Freeze every policy parameter but the value function's until ``steps`` env steps.

    Before each update (the end of a rollout) the parameters that do not belong to the value
    function (the features extractor shared with the policy, the policy's MLP and its action
    head) get ``requires_grad`` False while ``num_timesteps <= steps``, True afterwards; Adam
    leaves parameters without gradients untouched. A resumed run re-applies it at its next
    update.

    Args:
        steps: Env steps of value-only learning (0: off).
    """

    def __init__(self, steps: int) -> None:
        super().__init__()
        if steps < 0:
            raise ValueError(f"value warm-up steps must be >= 0, got {steps}")
        self.steps = steps

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        warming_up = self.num_timesteps <= self.steps
        for parameter in policy_parameters(self.model.policy):
            parameter.requires_grad_(not warming_up)


class WarmupLearningRate:
    """An SB3 learning-rate schedule: ``warmup_rate`` for the run's first ``warmup_steps`` env
    steps (those of :class:`ValueWarmupCallback`), then ``rate``, reached by a linear ramp from 0
    over ``ramp_steps``.

    The ramp is for Adam: its first step on a parameter without moments (the policy's, frozen
    through the warm-up) is ``rate`` times the sign of the gradient, every parameter moving by
    the full step at once; the ramp keeps those steps small until the moments are estimated.

    SB3 calls it before each update with the progress remaining, ``1 - steps / total_steps``;
    the step count is recovered from it, so a resumed run keeps the same schedule.

    Args:
        warmup_rate: Adam step size while only the value function learns.
        rate: Adam step size afterwards (``PPOConfig.learning_rate``).
        warmup_steps: Env steps of the warm-up.
        total_steps: The run's env steps (``TrainConfig.timesteps``).
        ramp_steps: Env steps of the ramp after the warm-up (0: ``rate`` at once).
    """

    def __init__(
        self,
        warmup_rate: float,
        rate: float,
        warmup_steps: int,
        total_steps: int,
        ramp_steps: int = 0,
    ):
        if not (warmup_rate > 0 and rate > 0 and 0 < warmup_steps and 0 < total_steps):
            raise ValueError(
                "WarmupLearningRate needs positive rates and step counts, got "
                f"{warmup_rate}, {rate}, {warmup_steps}, {total_steps}"
            )
        if ramp_steps < 0:
            raise ValueError(f"WarmupLearningRate ramp_steps must be >= 0, got {ramp_steps}")
        self.warmup_rate = warmup_rate
        self.rate = rate
        self.warmup_steps = warmup_steps
        self.total_steps = total_steps
        self.ramp_steps = ramp_steps

    def __call__(self, progress_remaining: float) -> float:
        steps = round((1.0 - progress_remaining) * self.total_steps)
        if steps <= self.warmup_steps:
            return self.warmup_rate
        if steps - self.warmup_steps >= self.ramp_steps:
            return self.rate
        return self.rate * (steps - self.warmup_steps) / self.ramp_steps


def policy_parameters(policy: Any) -> list[torch.nn.Parameter]:
    """An SB3 actor-critic policy's parameters that are not the value function's."""
    value_modules = [policy.value_net, policy.mlp_extractor.value_net]
    if not policy.share_features_extractor:
        value_modules.append(policy.vf_features_extractor)
    value = {id(p) for module in value_modules for p in module.parameters()}
    return [p for p in policy.parameters() if id(p) not in value]
