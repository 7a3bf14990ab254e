"""The configuration of a training run: frozen dataclasses, validated, saved as ``config.json``.

:class:`TrainConfig` holds everything that determines a run (environment, seeds, schedule,
PPO hyper-parameters); where the run is written (``--out``) and whether it resumes are arguments
of :func:`branch_gym.training.train.train`, not configuration.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from gymnasium import spaces

from branch_gym import ENV_ID_V0, ENV_IDS
from branch_gym.config_utils import check_keys, flatten_dict, is_number
from branch_gym.env.config import env_config_from_kwargs, price_range
from branch_gym.env.reward import RewardConfig
from branch_gym.env.versions import env_version
from branch_gym.sim.validation import (
    require_finite,
    require_int,
    require_non_negative,
    require_positive,
)
from branch_gym.training.seeds import MAX_EVAL_TREES, MAX_RUN_SEEDS

# Fields a resumed run may change: the step target and the checkpoint and evaluation periods.
RESUMABLE_CHANGES = ("timesteps", "checkpoint_every", "eval_every")


@dataclass(frozen=True)
class PPOConfig:
    """stable-baselines3 PPO hyper-parameters (SB3's defaults unless noted; RecurrentPPO's too).

    Attributes:
        n_steps: Steps per environment per rollout (our choice: SB3's 2048 would be ~40 full
            scans of ~50 steps per update; 256 updates every ~5 scans per environment).
        batch_size: Minibatch size (SB3 default 64).
        n_epochs: Passes over each rollout (SB3 default 10).
        learning_rate: Adam step size (SB3 default 3e-4).
        gamma: Discount (SB3 default 0.99: a horizon of ~100 steps, about two scans).
        gae_lambda: GAE lambda (SB3 default 0.95).
        clip_range: PPO clip (SB3 default 0.2).
        ent_coef: Entropy bonus (SB3 default 0.0).
        vf_coef: Value loss weight (SB3 default 0.5).
        max_grad_norm: Gradient clipping (SB3 default 0.5).
        target_kl: Stop an update's epochs early once the approximate KL divergence from the
            rollout's policy exceeds 1.5x this (SB3 default None: no limit). Our trigger runs
            without it took KL steps of 0.1 (clip fraction 0.4) and drifted into rotating until
            the scan-time limit; 0.02 keeps each update small.
        log_std_init: Initial log std of the continuous action (SB3 default 0.0: std 1, i.e.
            +-45 deg, clipped, so nearly every exploration step is a long rotation costing ~1 s
            of wall time; -1.0 (std 0.37) explores ~+-17 deg and trains faster). Unused by
            the discrete env.
        first_action_logit_init: Added to the initial logit of action 0 of a discrete action
            space (0: SB3's uniform start). On ``BranchScanTrigger-v0`` action 0 holds the
            angle: 3.0 starts at p(hold) = e^3 / (e^3 + 2) = 0.91, ~4 rotations per scan like
            the paper's periodic settings, instead of a rotation at 2 of 3 steps (each ~1 s of
            wall time, the bulk of early training time). Unused by continuous envs.
        cnn_output_dim: Features the image CNN of a Dict observation outputs (SB3's
            ``CombinedExtractor`` default 256; with 64 the 60x80 image's linear layer shrinks
            from 393k to 98k weights and a checkpoint from 6.5 to ~1.5 MB, small enough to
            commit). Unused by flat (Box) observations.
    """

    n_steps: int = 256
    batch_size: int = 64
    n_epochs: int = 10
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = None
    log_std_init: float = 0.0
    first_action_logit_init: float = 0.0
    cnn_output_dim: int = 256

    def __post_init__(self) -> None:
        require_int(self, "n_steps", "batch_size", "n_epochs", "cnn_output_dim", minimum=1)
        require_positive(self, "learning_rate", "clip_range", "max_grad_norm")
        require_non_negative(self, "ent_coef", "vf_coef")
        if self.target_kl is not None:
            require_positive(self, "target_kl")
        for name in ("gamma", "gae_lambda"):
            value = getattr(self, name)
            if not (is_number(value) and 0.0 < value <= 1.0):
                raise ValueError(f"PPOConfig.{name} must be in (0, 1], got {value!r}")
        require_finite(self, "log_std_init", "first_action_logit_init")

    def sb3_kwargs(self, observation_space: spaces.Space | None = None) -> dict[str, Any]:
        """Keyword arguments of ``stable_baselines3.PPO`` (and of sb3-contrib's RecurrentPPO).

        Args:
            observation_space: The env's; a Dict gets ``cnn_output_dim`` (its image CNN).
        """
        kwargs = asdict(self)
        kwargs["policy_kwargs"] = {"log_std_init": kwargs.pop("log_std_init")}
        cnn_output_dim = kwargs.pop("cnn_output_dim")
        if isinstance(observation_space, spaces.Dict):
            kwargs["policy_kwargs"]["features_extractor_kwargs"] = {
                "cnn_output_dim": cnn_output_dim
            }
        kwargs.pop("first_action_logit_init")  # applied to the built policy (train.py)
        return kwargs


@dataclass(frozen=True)
class TrainConfig:
    """One PPO training run on a ``BranchScan`` environment.

    Attributes:
        env_id: A registered id (``branch_gym.ENV_IDS``; default ``BranchScan-v0``, the id the
            recipes before v1 ran; ``configs/*.json`` name theirs); Dict observations get SB3's
            ``MultiInputPolicy``, the flat one ``MlpPolicy`` (``MultiInputLstmPolicy`` and
            ``MlpLstmPolicy`` when ``recurrent``).
        timesteps: Total environment steps to reach (a resumed run counts the steps done
            before; PPO stops at the first whole rollout past it).
        n_envs: Environments stepped in parallel (``SubprocVecEnv`` when > 1).
        seed: The run's seed: tree seeds of the training episodes (``seeds.py``), PPO's
            network initialisation and action sampling. In ``[0, MAX_RUN_SEEDS)``.
        tracker: "lk" or "oracle" (exact tracks: faster training).
        segmenter: "gt", "noisy:mild" | "noisy:moderate" | "noisy:severe", or "learned[:PATH]"
            (from pixels).
        tree: Tree distribution preset: "paper", "cluttered", "hard", "tall_spindle" or "ufo".
        world: "clean" (the paper's world) or "orchard" (sky, row, trellis, camera model).
        end_height_m: Scan end height (m); None keeps the scan default (0.75 m, paper V-A).
        speed_mps: Scan speed (m/s); None keeps the scan default (0.025 m/s).
        max_scan_time_s: Simulated time limit of a scan (s); None keeps the scan default
            (100 s). A run fine-tuned for a benchmark takes the benchmark's (``orchard-v2``:
            160 s): at 100 s, 7-21 % of the student's sampled scans at the dear prices failed
            (``research/records/ppo_ft_orchard_v2e``).
        render_tracking_frames: Render every tracking frame (the scan default). False renders
            only the frames a modeling iteration runs on (oracle tracker only; ~2.5x more
            steps per second, identical results on the trees we compared).
        checkpoint_every: Save a checkpoint every this many environment steps (our choice:
            10k steps, ~15 min of training at ~10 steps/s: a killed run loses at most that).
        eval_every: Evaluate on the held-out trees every this many steps; 0 never (our
            choice: as often as the checkpoints).
        eval_trees: Held-out trees per evaluation (our choice: 10, ~1 min with LK tracking).
        time_penalty_per_s: Penalty per second of scan time
            (:class:`branch_gym.env.reward.RewardConfig`); None keeps the env's 0.01, which
            values a found branch at 100 s of scan time.
        spurious_penalty: Reward per spurious side branch (``RewardConfig``); None keeps the
            env's 0.5 (half a found branch). The orchard recipes lower it: issue 34's
            must-shows count missed branches first and allow a spurious point, and from pixels
            a turn adds ~3 false branches per branch it finds (docs/results/learned_policies.md).
        duplicate_penalty: Reward per duplicate of a matched branch; None keeps the env's 0.5.
        normalize: Wrap the training envs in ``VecNormalize`` (running mean/std of the
            observation vector and of the return). Our choice: off, the observation is
            already scaled to about [0, 1] and the rewards are O(1).
        recurrent: Train sb3-contrib's ``RecurrentPPO`` (an LSTM between the features and the
            policy and value heads, its state carried through each episode) instead of PPO, with
            the same hyper-parameters. Our choice (issue 17, a recurrent variant if memory
            helps): off; the v1 envs' coverage map is already an explicit memory. A resumed run
            cannot switch it.
        worker_rollouts: Each env process plays whole rollouts under a copy of the policy
            (:mod:`branch_gym.training.worker_rollouts`) instead of SB3's lockstep, where every
            step waits for the slowest env (a rotation costs ~8x a plain step). The same PPO;
            its sampled actions differ from a lockstep run's. Not with ``normalize`` or
            ``recurrent``; a resumed run cannot switch it. Our choice: off by default (older
            runs resume unchanged); the recipes (``configs/``) and the bench use it.
        init_model: A model file whose policy weights a new run starts from instead of a
            random initialisation (a PPO model of the same env and ``ppo`` network shape, e.g.
            a DAgger student of :mod:`branch_gym.training.imitation`); None starts fresh.
        init_logit_scale: Multiplies the action logits of ``init_model``'s policy (its action
            head's weights and bias): a discrete policy fitted as a classifier (a DAgger student)
            samples at temperature ``1 / init_logit_scale``, its argmax unchanged. 1: as fitted.
            Our choice for the v2 student's fine-tuning: 3 (sampled at temperature 1 it rotated
            9 times per scan, against 1.7 by argmax, and 30 % of those scans failed).
        value_warmup_steps: Env steps at the start of the run during which only the value
            function learns (:class:`~branch_gym.training.callbacks.ValueWarmupCallback`): a
            policy from ``init_model`` comes without a trained critic. 0: off (our default).
        value_warmup_learning_rate: Adam step size during the value warm-up
            (:class:`~branch_gym.training.callbacks.WarmupLearningRate`); None: the PPO
            ``learning_rate`` throughout. Our choice for fine-tuning a student: SB3's default
            3e-4, where the fine-tuning itself steps at 1e-5: at 1e-5 throughout, the critic of
            ``research/records/ppo_ft_orchard_v2b`` explained none of the returns after 16384
            warm-up steps (explained variance -0.13 to +0.11).
        learning_rate_ramp_steps: Env steps after the value warm-up over which the learning
            rate rises linearly from 0 to ``ppo.learning_rate`` (needs
            ``value_warmup_learning_rate``). Our choice for fine-tuning a student: 8192 (8
            updates): Adam's first step on the policy's parameters, without moments after the
            warm-up, moves each by the full step (the sign of its gradient); at 1e-5 that first
            step moved the student of ``research/records/ppo_ft_orchard_v2c`` by KL ~0.7 and it
            never turned again. 0: no ramp (our default).
        privileged_critic: Train with a privileged critic (issue 63): the training envs'
            observations gain the ground truth's ``privileged`` entry
            (:class:`~branch_gym.training.privileged_state.PrivilegedStateWrapper`: scored side
            branches matched, pending in view with their headings, passed, not yet seen, the
            scan's progress) and the policy is
            :class:`~branch_gym.training.privileged_critic.PrivilegedCriticPolicy`: the actor
            reads the plain observation only, the critic that entry too. With ``init_model``
            the actor starts as that model's policy and the critic as its critic (zero weights
            on the privileged entry). The run's files hold the privileged model (resumable);
            ``load_model`` and so ``ppo:PATH`` play them as the plain policy of the actor, and
            the held-out evaluation plays the actor in the plain env. Needs a Dict-observation
            env id and ``recurrent=False``; a resumed run cannot switch it. Our choice: off.
        train_branch_value_s: (low, high) seconds: each training episode's branch value drawn
            log-uniformly from this sub-range of the env's ``branch_value_s``
            (:class:`~branch_gym.training.prices.PriceRangeWrapper`; the observation still reads
            the price against the env's range, and the held-out evaluation keeps the env's own
            draw). None: the env's own draw over its whole range (our default). Needs a priced
            env id. Our choice for the student's fine-tuning (issue 63): (200, 400), the dear
            prices, where turning pays: over the whole range (half its episodes at <= 100 s,
            where never turning costs the student about as much as its turns)
            ``research/records/ppo_ft_orchard_v2d`` learned never to turn.
        view_shaping_weight: Reward units of potential-based shaping
            (:class:`~branch_gym.training.shaping.ViewShapingWrapper`): a turn that brings an
            unmatched scored side branch into a good view earns this at once, and matching it
            (or leaving it behind) takes it back, so the optimal policies stay the env's. Needs
            ``privileged_critic`` (the critic must see what the potential reads: the pending
            branches and their headings). 0: off (our default).
        ppo: PPO hyper-parameters.
    """

    env_id: str = ENV_ID_V0
    timesteps: int = 100_000
    n_envs: int = 1
    seed: int = 0
    tracker: str = "lk"
    segmenter: str = "gt"
    tree: str = "paper"
    world: str = "clean"
    end_height_m: float | None = None
    speed_mps: float | None = None
    max_scan_time_s: float | None = None
    render_tracking_frames: bool = True
    checkpoint_every: int = 10_000
    eval_every: int = 10_000
    eval_trees: int = 10
    time_penalty_per_s: float | None = None
    spurious_penalty: float | None = None
    duplicate_penalty: float | None = None
    normalize: bool = False
    recurrent: bool = False
    worker_rollouts: bool = False
    init_model: str | None = None
    init_logit_scale: float = 1.0
    value_warmup_steps: int = 0
    value_warmup_learning_rate: float | None = None
    learning_rate_ramp_steps: int = 0
    privileged_critic: bool = False
    train_branch_value_s: tuple[float, float] | None = None
    view_shaping_weight: float = 0.0
    ppo: PPOConfig = field(default_factory=PPOConfig)

    def __post_init__(self) -> None:
        if self.env_id not in ENV_IDS:
            raise ValueError(f"TrainConfig.env_id must be one of {ENV_IDS}, got {self.env_id!r}")
        require_int(self, "timesteps", "n_envs", minimum=1)
        require_int(self, "seed", minimum=0, maximum=MAX_RUN_SEEDS - 1)
        require_int(self, "checkpoint_every", minimum=1)
        require_int(self, "value_warmup_steps", minimum=0)
        require_positive(self, "init_logit_scale")
        if self.init_logit_scale != 1.0 and self.init_model is None:
            raise ValueError("TrainConfig.init_logit_scale applies to an init_model only")
        require_int(self, "eval_every", minimum=0)
        require_int(self, "eval_trees", minimum=1, maximum=MAX_EVAL_TREES)
        for name in (
            "render_tracking_frames",
            "normalize",
            "recurrent",
            "worker_rollouts",
            "privileged_critic",
        ):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"TrainConfig.{name} must be a bool, got {getattr(self, name)!r}")
        if self.worker_rollouts and (self.normalize or self.recurrent):
            raise ValueError(
                "TrainConfig.worker_rollouts works with plain PPO only: the workers act on raw "
                "observations (normalize=False) without an LSTM state (recurrent=False)"
            )
        if self.privileged_critic and self.recurrent:
            raise ValueError("TrainConfig.privileged_critic needs recurrent=False")
        if self.privileged_critic and env_version(self.env_id).env_kwargs().get("flatten"):
            raise ValueError(
                "TrainConfig.privileged_critic needs an env id with Dict observations, "
                f"not {self.env_id!r}"
            )
        if self.value_warmup_learning_rate is not None:
            require_positive(self, "value_warmup_learning_rate")
            if not self.value_warmup_steps:
                raise ValueError("TrainConfig.value_warmup_learning_rate needs value_warmup_steps")
        require_int(self, "learning_rate_ramp_steps", minimum=0)
        if self.learning_rate_ramp_steps and self.value_warmup_learning_rate is None:
            raise ValueError(
                "TrainConfig.learning_rate_ramp_steps needs value_warmup_learning_rate"
            )
        weight = self.view_shaping_weight
        if not (is_number(weight) and math.isfinite(weight) and weight >= 0.0):
            raise ValueError(
                "TrainConfig.view_shaping_weight must be a finite number >= 0, "
                f"got {self.view_shaping_weight!r}"
            )
        if self.view_shaping_weight and not self.privileged_critic:
            raise ValueError(
                "TrainConfig.view_shaping_weight needs privileged_critic: the critic must read "
                "the pending branches the shaping's potential counts"
            )
        if self.train_branch_value_s is not None:
            low, high = price_range(self.train_branch_value_s, "TrainConfig.train_branch_value_s")
            env_range = env_version(self.env_id).env_kwargs().get("branch_value_s")
            if env_range is None:
                raise ValueError(
                    f"TrainConfig.train_branch_value_s needs a priced env id (v1 or later), "
                    f"not {self.env_id!r}, whose episodes have no branch_value_s range"
                )
            if not env_range[0] <= low <= high <= env_range[1]:
                raise ValueError(
                    f"TrainConfig.train_branch_value_s ({low:g}, {high:g}) must lie within the "
                    f"branch_value_s range of {self.env_id}, {tuple(env_range)}"
                )
            object.__setattr__(self, "train_branch_value_s", (low, high))
        if self.value_warmup_steps and self.recurrent:
            raise ValueError("TrainConfig.value_warmup_steps needs recurrent=False")
        if self.init_model is not None and (self.recurrent or not str(self.init_model)):
            raise ValueError("TrainConfig.init_model needs a model file path and recurrent=False")
        if not isinstance(self.ppo, PPOConfig):
            raise ValueError(f"TrainConfig.ppo must be a PPOConfig, got {self.ppo!r}")
        rollout = self.ppo.n_steps * self.n_envs
        if self.ppo.batch_size > rollout:
            raise ValueError(
                f"PPOConfig.batch_size ({self.ppo.batch_size}) must be at most n_steps * n_envs "
                f"({rollout})"
            )
        env_config_from_kwargs(self.env_kwargs())  # ValueError naming a bad scan setting

    def env_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``gymnasium.make(env_id, ...)`` for the training and eval envs."""
        kwargs: dict[str, Any] = {
            "tracker": self.tracker,
            "segmenter": self.segmenter,
            "tree": self.tree,
            "world": self.world,
        }
        for name in ("end_height_m", "speed_mps", "max_scan_time_s"):
            if getattr(self, name) is not None:
                kwargs[name] = getattr(self, name)
        if not self.render_tracking_frames:
            kwargs["render_tracking_frames"] = False
        reward = {
            name: getattr(self, name)
            for name in ("time_penalty_per_s", "spurious_penalty", "duplicate_penalty")
            if getattr(self, name) is not None
        }
        if reward:
            kwargs["reward"] = RewardConfig(**reward)
        return kwargs

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict of every field (``ppo`` nested)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        """The inverse of :meth:`to_dict`.

        Raises:
            ValueError: unknown keys (named) or bad values.
        """
        check_keys(cls, data)
        values = dict(data)
        ppo = values.pop("ppo", {})
        if isinstance(ppo, dict):
            check_keys(PPOConfig, ppo)
            ppo = PPOConfig(**ppo)
        return cls(ppo=ppo, **values)

    def resume_conflicts(self, saved: TrainConfig) -> list[str]:
        """Fields (``ppo.x`` for PPO ones) that differ from a saved run's, beyond the resumable.

        Returns:
            ``"name: saved -> new"`` for each conflicting field; empty when resumable.
        """
        old, new = flatten_dict(saved.to_dict()), flatten_dict(self.to_dict())
        return [
            f"{key}: {old.get(key)!r} -> {new.get(key)!r}"
            for key in sorted(old.keys() | new.keys())
            if key not in RESUMABLE_CHANGES and old.get(key) != new.get(key)
        ]
