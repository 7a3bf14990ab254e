"""Train a PPO rotation policy: new runs, resumed runs, checkpoints, held-out evaluation.

The algorithm is stable-baselines3's ``PPO``, or sb3-contrib's ``RecurrentPPO`` with an LSTM
policy when ``TrainConfig.recurrent``, or PPO with rollouts collected in the env processes
(:class:`~branch_gym.training.worker_rollouts.WorkerRolloutPPO`) when
``TrainConfig.worker_rollouts``. With ``TrainConfig.privileged_critic`` the training envs add the
ground truth's privileged entry to the observation and the policy is
:class:`~branch_gym.training.privileged_critic.PrivilegedCriticPolicy` (its critic reads it).

:func:`train` is what ``train.py`` at the repository root calls. A run lives in one folder
(:class:`branch_gym.training.paths.RunPaths`); ``resume=True`` continues it from its latest
checkpoint with the step count going on (SB3's ``reset_num_timesteps=False``), the training envs
on new trees and the best held-out reward remembered.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from branch_gym.env.versions import same_spaces
from branch_gym.training.callbacks import (
    ScanMetricsCallback,
    TorchThreadsCallback,
    TqdmCallback,
    ValueWarmupCallback,
    WarmupLearningRate,
)
from branch_gym.training.checkpoints import (
    CheckpointCallback,
    read_checkpoint,
    save_model,
    write_checkpoint,
    write_json_atomic,
)
from branch_gym.training.config import RESUMABLE_CHANGES, TrainConfig
from branch_gym.training.curve import plot_training_curve
from branch_gym.training.envs import (
    make_eval_env,
    make_train_env,
    policy_class,
    restore_episode_counts,
)
from branch_gym.training.evaluation import EvalResult, HeldOutEvalCallback
from branch_gym.training.model_files import (
    ENV_ID_ATTRIBUTE,
    ModelFinder,
    algorithm_class,
    existing_file,
    load_model,
    load_normalizer,
)
from branch_gym.training.paths import TB_LOG_NAME, RunPaths
from branch_gym.training.privileged_critic import PrivilegedCriticPolicy, is_privileged_policy
from branch_gym.training.privileged_state import PrivilegedStateWrapper
from branch_gym.training.seeds import eval_tree_seeds, train_seed_range
from branch_gym.training.worker_rollouts import WorkerRolloutPPO

logger = logging.getLogger(__name__)

_TORCH_THREADS = 1  # one thread while the env workers step: the machine's cores run them
# Threads of the gradient update (the workers wait then): our 2-core target machine's cores. A
# fixed count, not the machine's: the update's floating-point sums depend on it (determinism).
UPDATE_TORCH_THREADS = 2


@dataclass(frozen=True)
class TrainResult:
    """What a call of :func:`train` did.

    Attributes:
        out: The run folder.
        final_model: ``OUT/final_model.zip``.
        num_timesteps: Environment steps trained in total (all calls of the run).
        start_timesteps: Steps the run had when this call started (0 for a new run).
        evaluations: The held-out evaluations of this call.
    """

    out: Path
    final_model: Path
    num_timesteps: int
    start_timesteps: int
    evaluations: list[EvalResult] = field(default_factory=list)


def train(
    config: TrainConfig,
    out: str | Path,
    resume: bool = False,
    progress: bool = False,
    find_model: ModelFinder = existing_file,
) -> TrainResult:
    """Train (or go on training) a PPO policy until ``config.timesteps`` environment steps.

    Args:
        config: The run's configuration; when resuming it must equal the saved one except for
            ``RESUMABLE_CHANGES`` (the step target, the checkpoint and evaluation periods).
        out: The run folder.
        resume: Continue from the latest checkpoint in ``out``.
        progress: Show a tqdm progress bar (on stderr).
        find_model: ``config.init_model`` -> its file (``agents.ppo.resolve_model_path`` also
            knows the shipped models' names); plain paths by default.

    Raises:
        FileExistsError: a new run in a folder that already holds one.
        FileNotFoundError: resuming without a checkpoint, or its model file is missing (named).
        ValueError: the config differs from the saved run's; a corrupt config, checkpoint or
            model file (named; ``ModelFileError`` and ``CheckpointError`` are ValueErrors).
    """
    import torch

    torch.set_num_threads(_TORCH_THREADS)
    paths = RunPaths(Path(out))
    checkpoint = _check_run_folder(config, paths, resume)
    model, normalizer, best = None, None, None
    if checkpoint is not None:  # load before starting env processes: bad files fail fast
        # The run's config.json pins ``recurrent`` and ``worker_rollouts`` (resume_conflicts).
        model = load_model(
            paths.checkpoints / checkpoint.model,
            algorithm=training_algorithm(config),
            tensorboard_log=str(paths.tensorboard),
        )
        if checkpoint.vecnormalize is not None:
            normalizer = load_normalizer(paths.checkpoints / checkpoint.vecnormalize)
        best = checkpoint.best_mean_reward
    write_run_config(paths, config)
    venv = make_train_env(
        config, normalizer, PrivilegedStateWrapper if config.privileged_critic else None
    )
    eval_env = make_eval_env(config) if config.eval_every > 0 else None
    try:
        if model is None:
            model = new_model(config, venv, str(paths.tensorboard), find_model)
        else:
            model.set_env(venv)
            model.set_random_seed(_resume_seed(config.seed, checkpoint.num_timesteps))
            restore_episode_counts(venv, checkpoint.episodes)
        if config.value_warmup_learning_rate is not None:  # also on resume: the step target
            model.lr_schedule = WarmupLearningRate(
                config.value_warmup_learning_rate,
                config.ppo.learning_rate,
                config.value_warmup_steps,
                config.timesteps,
                config.learning_rate_ramp_steps,
            )
        start = int(model.num_timesteps)
        evaluator = None
        if eval_env is not None:
            seeds = eval_tree_seeds(config.eval_trees)
            evaluator = HeldOutEvalCallback(eval_env, seeds, config.eval_every, paths, best)

        def best_reward() -> float | None:
            return evaluator.best_mean_reward if evaluator is not None else best

        callbacks: list[Any] = [
            TorchThreadsCallback(_TORCH_THREADS, UPDATE_TORCH_THREADS),
            ScanMetricsCallback(),
            *(
                [ValueWarmupCallback(config.value_warmup_steps)]
                if config.value_warmup_steps
                else []
            ),
            CheckpointCallback(paths, config.checkpoint_every, best_reward),
            *([evaluator] if evaluator is not None else []),
            *([TqdmCallback(config.timesteps)] if progress else []),
        ]
        remaining = config.timesteps - start
        if remaining > 0:
            model.learn(
                total_timesteps=remaining,
                callback=callbacks,
                reset_num_timesteps=checkpoint is None,
                tb_log_name=TB_LOG_NAME,
            )
        else:
            logger.info("%s already has %d >= %d steps", paths.out, start, config.timesteps)
        save_model(model, venv, paths.final_model)
        write_checkpoint(model, venv, paths, best_reward())
        plot_training_curve(paths.out)
    finally:
        venv.close()
        if eval_env is not None:
            eval_env.close()
    return TrainResult(
        out=paths.out,
        final_model=paths.final_model,
        num_timesteps=int(model.num_timesteps),
        start_timesteps=start,
        evaluations=list(evaluator.results) if evaluator is not None else [],
    )


def write_run_config(paths: RunPaths, config: TrainConfig) -> None:
    """``OUT/config.json``: the configuration, the tree seed ranges and library versions."""
    import sb3_contrib
    import stable_baselines3
    import torch

    train_seeds = train_seed_range(config.seed)
    eval_seeds = eval_tree_seeds(config.eval_trees)
    write_json_atomic(
        paths.config,
        {
            "config": config.to_dict(),
            "tree_seeds": {
                "train_first": train_seeds.start,
                "train_last": train_seeds.stop - 1,
                "eval": eval_seeds,
            },
            "versions": {
                "stable_baselines3": stable_baselines3.__version__,
                "sb3_contrib": sb3_contrib.__version__,
                "torch": torch.__version__,
            },
        },
    )


def read_run_config(paths: RunPaths) -> TrainConfig:
    """The configuration saved in ``OUT/config.json``.

    Raises:
        FileNotFoundError: no config file (named).
        ValueError: the file is not a valid run configuration (named).
    """
    if not paths.config.is_file():
        raise FileNotFoundError(f"run config {paths.config} does not exist")
    try:
        return TrainConfig.from_dict(json.loads(paths.config.read_text())["config"])
    except (ValueError, TypeError, KeyError) as exc:
        raise ValueError(f"run config {paths.config} is invalid: {exc}") from exc


def _check_run_folder(config: TrainConfig, paths: RunPaths, resume: bool) -> Any:
    """The checkpoint to resume from (None for a new run), after checking the folder."""
    if not resume:
        if paths.config.exists() or paths.checkpoint.exists():
            raise FileExistsError(
                f"{paths.out} already holds a training run: pass --resume to continue it, or "
                "use another --out"
            )
        return None
    checkpoint = read_checkpoint(paths)
    conflicts = config.resume_conflicts(read_run_config(paths))
    if conflicts:
        raise ValueError(
            f"cannot resume {paths.out} with another configuration (only "
            f"{', '.join(RESUMABLE_CHANGES)} may change): " + "; ".join(conflicts)
        )
    return checkpoint


def new_model(
    config: TrainConfig,
    env: Any,
    tensorboard_log: str | None = None,
    find_model: ModelFinder = existing_file,
) -> Any:
    """A fresh PPO (or RecurrentPPO) model of the run's hyper-parameters on ``env``.

    Its weights come from ``config.init_model`` when set (its policy MLP widths too, e.g. a
    calibrated student's extra unit), else a random initialisation with
    ``first_action_logit_init`` applied. ``config.privileged_critic``: a
    :class:`~branch_gym.training.privileged_critic.PrivilegedCriticPolicy` (``env`` must give
    the privileged entry).

    Args:
        config: The run.
        env: A (vector) env of the run's spaces.
        tensorboard_log: TensorBoard folder, or None for no logs.
        find_model: ``config.init_model`` -> its file.
    """
    init_path = None if config.init_model is None else find_model(config.init_model)
    source = None if init_path is None else load_model(init_path)
    kwargs = config.ppo.sb3_kwargs(env.observation_space)
    if source is not None and "net_arch" in source.policy_kwargs:
        kwargs["policy_kwargs"]["net_arch"] = source.policy_kwargs["net_arch"]
    policy = (
        PrivilegedCriticPolicy
        if config.privileged_critic
        else policy_class(env.observation_space, config.recurrent)
    )
    model = training_algorithm(config)(
        policy,
        env,
        seed=config.seed,
        device="cpu",
        tensorboard_log=tensorboard_log,
        verbose=0,
        **kwargs,
    )
    setattr(model, ENV_ID_ATTRIBUTE, config.env_id)  # every save of the model records it
    if init_path is not None:
        load_policy_weights(model, init_path, source)
        scale_action_logits(model, config.init_logit_scale)
    else:
        apply_first_action_logit(model, config.ppo.first_action_logit_init)
    return model


def training_algorithm(config: TrainConfig) -> type:
    """The run's algorithm class: PPO, RecurrentPPO, or PPO with worker rollouts."""
    if config.worker_rollouts:
        return WorkerRolloutPPO
    return algorithm_class(config.recurrent)


def load_policy_weights(model: Any, path: str | Path, source: Any = None) -> None:
    """Copy the policy (and value) weights of a saved PPO model into ``model``.

    A :class:`~branch_gym.training.privileged_critic.PrivilegedCriticPolicy` takes them with
    :meth:`~branch_gym.training.privileged_critic.PrivilegedCriticPolicy.load_plain_weights`
    (the critic with zero weights on the privileged entry).

    Args:
        model: The new model.
        path: A model file.
        source: ``load_model(path)`` if already loaded; None loads it.

    Raises:
        FileNotFoundError: no such file (named).
        ValueError: not a model file (``ModelFileError``), a model of an env id that observes
            or acts otherwise than ``model``'s (a changed reward is fine), or a network that
            does not fit ``model``'s (named).
    """
    source = load_model(path) if source is None else source
    theirs, ours = getattr(source, ENV_ID_ATTRIBUTE), getattr(model, ENV_ID_ATTRIBUTE, None)
    if None not in (theirs, ours) and not same_spaces(theirs, ours):
        raise ValueError(
            f"init model {path} was trained on {theirs}, the run's env is {ours}: their "
            "observations or actions differ"
        )
    try:
        if is_privileged_policy(model.policy):
            model.policy.load_plain_weights(source.policy)
        else:
            model.policy.load_state_dict(source.policy.state_dict())
    except (RuntimeError, ValueError) as exc:
        raise ValueError(f"init model {path} does not fit the run's network: {exc}") from exc


def scale_action_logits(model: Any, scale: float) -> None:
    """Multiply a policy's action head (weights and bias) by ``scale``.

    For a discrete policy the logits scale: sampling at temperature ``1 / scale`` with the same
    argmax. For a continuous one the action mean scales; only 1 leaves it unchanged.
    """
    import torch

    if scale != 1.0:
        with torch.no_grad():
            model.policy.action_net.weight.mul_(scale)
            model.policy.action_net.bias.mul_(scale)


def apply_first_action_logit(model: Any, bonus: float) -> None:
    """Add ``bonus`` to the initial logit of discrete action 0 (hold): a policy that starts calm.

    No effect on continuous action spaces or with ``bonus`` 0. PPO's and RecurrentPPO's
    policies both end in ``policy.action_net`` (after the MLP, or the LSTM then the MLP).
    """
    import torch
    from gymnasium import spaces

    if bonus and isinstance(model.action_space, spaces.Discrete):
        with torch.no_grad():
            model.policy.action_net.bias[0] += bonus


def _resume_seed(seed: int, num_timesteps: int) -> int:
    """The RNG seed of a run resumed at ``num_timesteps``: a function of the run seed only."""
    return int(np.random.SeedSequence([seed, num_timesteps]).generate_state(1)[0])
