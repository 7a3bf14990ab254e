"""The configuration of a DAgger run (:class:`ImitationConfig`) and the files of its folder."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from branch_gym.config_utils import check_keys
from branch_gym.env.versions import env_version
from branch_gym.privileged import HOME_SPEC, parse_privileged_spec
from branch_gym.privileged import SPEC_KIND as PRIVILEGED_SPEC
from branch_gym.sim.validation import require_int, require_non_negative, require_positive
from branch_gym.training.config import PPOConfig, TrainConfig
from branch_gym.training.imitation.cost_to_go import ROLLOUTS
from branch_gym.training.seeds import train_seed_range

ROUNDS_LOG = "rounds.jsonl"
CONFIG_FILE = "imitation_config.json"
FINAL_MODEL = "model.zip"
# Settings a resumed run may change: the number of rounds and how the labels are fitted.
RESUMABLE_CHANGES = (
    "rounds", "epochs", "batch_size", "learning_rate", "weight_decay", "validation_fraction",
    "from_scratch", "rotation_weight", "reference_value_s", "expert_label_weight",
    "cost_to_go_weight", "price_samples_s",
)  # fmt: skip
# A student is a classifier of the expert's action: the env must offer a few actions.
DISCRETE_ACTION_TYPES = ("discrete", "discrete_hold")


def student_train_config() -> TrainConfig:
    """The student's env and network unless a recipe says otherwise.

    The current discrete id (``BranchScanDiscrete-v2``), the depth-oracle tracker with only the
    modeling frames rendered (fast: ~1.5 s per scan; every evaluation uses LK) and an image CNN
    of 64 features (every shipped student's; a 1 MB model file).
    """
    return TrainConfig(
        env_id="BranchScanDiscrete-v2",
        tracker="oracle",
        render_tracking_frames=False,
        ppo=PPOConfig(cnn_output_dim=64),
    )


@dataclass(frozen=True)
class ImitationConfig:
    """A DAgger run.

    Attributes:
        train: The env and network settings (its ``env_id``, tracker, segmenter, tree preset,
            ``render_tracking_frames``, ``seed``, ``recurrent`` and ``ppo`` network shape are
            used; the PPO schedule is not). Default :func:`student_train_config`.
        rounds: DAgger rounds (our choice: 8, the shipped students'; round 0 plays the expert).
        episodes: Episodes (trees) per round (our choice: 96, ~4 400 labelled steps, ~2 min on
            2 cores with the oracle tracker).
        epochs: Most passes over all labels after each round (our choice: 10; early stopping
            on the held-out labels keeps the best epoch).
        batch_size: Minibatch size of the fit (our choice: 256).
        learning_rate: Adam step size of the fit (our choice: 3e-4, SB3's PPO default; at BC's
            usual 1e-3 some fits of the v2 students collapsed: the image CNN's features grew
            until the policy MLP's tanh units saturated and the student output the same action
            probabilities for every observation, ranking the expert's rotations no better than
            chance even on the labels it was fitted on; see :func:`rotation_auc`).
        weight_decay: AdamW's decoupled weight decay (our choice: 1e-4, a light regulariser:
            without it our students fitted 99 % of the labels and agreed with the expert on
            89 % of a new round's).
        validation_fraction: Share of the labels held out for early stopping (our choice: 0.1).
        from_scratch: Fit a freshly initialised network after each round (DAgger as Ross et
            al. state it: a new policy on all labels so far), instead of going on from the
            previous round's weights (which sees the first rounds' labels ever more often).
        rotation_weight: Loss weight of a label that rotates (action != 0) relative to "hold"
            (our choice: 1.0, plain behaviour cloning; > 1 makes the student rotate where it is
            unsure).
        reference_value_s: Price conditioning (module docstring): rotation labels weigh
            ``rotation_weight * V / reference_value_s`` for the episode's branch value V
            (needs a v1 env, whose observation shows V); None weighs every episode alike.
            Our choice for the price-conditioned student: 100 s, the v0 reward's price.
        tree_offset: Skip this many of the run's training trees (so a DAgger run and a PPO run
            of the same seed can use different trees).
        cost_to_go_states: States of each played episode priced by cost-to-go branches (every
            distinct action taken once, then rolled out to the episode's end:
            :mod:`~branch_gym.training.imitation.cost_to_go`); 0: plain DAgger. Each costs
            about as many episodes as there are distinct actions (5 in the v2 env).
        rollout: Who plays after a branch's action: "student" (the round's student; in round 0,
            a policy that never turns the camera) or "expert" (AggreVaTe as published). Our choice:
            "student": under the expert's roll-outs a blind rotation is worth no more than
            holding, since the expert finds a hidden branch one step later anyway.
        expert_label_weight: Weight of the expert labels' cross-entropy in the fit (1: DAgger;
            0: the priced states alone).
        cost_to_go_weight: Weight of the expected regret on the priced states
            (:func:`~branch_gym.training.imitation.cost_to_go.expected_regret`, in units of
            the env's return: a found branch is 1). Our choice: 10; the regret's gradient is
            about 1 / n_actions of the cross-entropy's at an undecided policy: fitted on 300
            priced states alone (``tests/test_cost_to_go.py``), weight 1 left a regret of 0.46
            branch per state after 30 epochs, weight 10 0.03.
        price_samples_s: Branch values (s) at which every priced state is priced again, from
            its branches' logged outcomes (scan time, counts, failure: ``action_outcomes``), its
            observation showing that price: the expected regret averages over the state's own
            price and these. Without them each state teaches one price, the one its episode
            drew, and a student may ignore its price input (issue 34, part 4). The roll-outs
            after a branch's action stay those played at the episode's own price. Our choice:
            () (off); the orchard recipe's 25, 50, 100, 200, 400, the env's range.
        expert: The labelling expert's policy spec: ``privileged`` (holds where nothing is
            pending, the shipped students') or ``privileged:home`` (turns back to 0 then:
            :class:`branch_gym.privileged.PrivilegedConfig`).

    With ``train.recurrent`` the student is an sb3-contrib ``RecurrentPPO`` (the same features
    followed by an LSTM, ``MultiInputLstmPolicy``): it plays with its LSTM state carried through
    the episode and is fitted on whole episodes, the state run from each episode's first step
    (:func:`fit_student`); ``validation_fraction`` then holds out whole episodes.
    """

    train: TrainConfig = field(default_factory=lambda: student_train_config())
    rounds: int = 8
    episodes: int = 96
    epochs: int = 10
    batch_size: int = 256
    learning_rate: float = 3e-4
    weight_decay: float = 1e-4
    validation_fraction: float = 0.1
    from_scratch: bool = True
    rotation_weight: float = 1.0
    reference_value_s: float | None = None
    tree_offset: int = 0
    cost_to_go_states: int = 0
    rollout: str = "student"
    expert_label_weight: float = 1.0
    cost_to_go_weight: float = 10.0
    expert: str = PRIVILEGED_SPEC
    price_samples_s: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "price_samples_s", tuple(float(v) for v in self.price_samples_s))
        if any(not math.isfinite(v) or v <= 0.0 for v in self.price_samples_s):
            raise ValueError(
                "ImitationConfig.price_samples_s must be positive branch values (s), got "
                f"{self.price_samples_s}"
            )
        if parse_privileged_spec(self.expert) is None:
            raise ValueError(
                f"ImitationConfig.expert must be {PRIVILEGED_SPEC!r} or {HOME_SPEC!r}, "
                f"got {self.expert!r}"
            )
        require_int(self, "rounds", "episodes", "epochs", "batch_size", minimum=1)
        require_int(self, "tree_offset", "cost_to_go_states", minimum=0)
        require_non_negative(self, "expert_label_weight", "cost_to_go_weight")
        if self.rollout not in ROLLOUTS:
            raise ValueError(
                f"ImitationConfig.rollout must be one of {ROLLOUTS}, got {self.rollout!r}"
            )
        if self.cost_to_go_states and self.train.recurrent:
            raise ValueError(
                "ImitationConfig.cost_to_go_states needs a feed-forward student (train.recurrent "
                "False): a branch's roll-out carries no LSTM state"
            )
        require_positive(self, "learning_rate", "rotation_weight")
        require_non_negative(self, "weight_decay")
        if not 0.0 <= self.validation_fraction < 1.0:
            raise ValueError(
                "ImitationConfig.validation_fraction must be in [0, 1), got "
                f"{self.validation_fraction}"
            )
        if self.reference_value_s is not None:
            require_positive(self, "reference_value_s")
        if env_version(self.train.env_id).action_type not in DISCRETE_ACTION_TYPES:
            raise ValueError(
                f"imitation needs a discrete env (BranchScanDiscrete-*), got {self.train.env_id!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict of every field (``train`` nested)."""
        data = asdict(self)
        data["train"] = self.train.to_dict()
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ImitationConfig:
        """The inverse of :meth:`to_dict`; missing fields keep their defaults (a recipe file).

        A partial ``train`` updates :func:`student_train_config`, not ``TrainConfig()``.

        Raises:
            ValueError: unknown keys (named) or bad values.
        """
        check_keys(cls, data)
        values = dict(data)
        base = student_train_config().to_dict()
        train = values.get("train", {})
        base_ppo = base.pop("ppo")
        merged = {**base, **train, "ppo": {**base_ppo, **train.get("ppo", {})}}
        values["train"] = TrainConfig.from_dict(merged)
        return cls(**values)

    def tree_seed(self, round_index: int, episode: int) -> int:
        """The training tree of one episode of one round."""
        seeds = train_seed_range(self.train.seed)
        seed = seeds.start + self.tree_offset + round_index * self.episodes + episode
        if seed >= seeds.stop:
            raise ValueError(f"imitation run uses more trees than the seed's range {seeds}")
        return seed
