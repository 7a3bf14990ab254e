"""PPO with a privileged critic: the actor reads the observation, the critic the ground truth too.

:class:`PrivilegedCriticPolicy` is an SB3 ``MultiInputActorCriticPolicy`` with separate feature
extractors (``share_features_extractor=False``) on a Dict observation that holds the privileged
entry (:data:`~branch_gym.training.privileged_state.PRIVILEGED_KEY`, added by
:class:`~branch_gym.training.privileged_state.PrivilegedStateWrapper`):

- the actor's extractor (:class:`ActorFeatures`) is SB3's ``CombinedExtractor`` over the space
  without that entry: it never reads it, so the action distribution depends on the plain
  observation only and the policy acts on observations without the entry (evaluation);
- the critic's is a ``CombinedExtractor`` over the whole space, the privileged entry included,
  with its own value MLP input width.

The parameter names are those of a plain ``MultiInputPolicy``'s (``pi_features_extractor``,
``mlp_extractor.policy_net``, ``action_net``, ...), so :meth:`PrivilegedCriticPolicy.
load_plain_weights` starts both halves from a plain policy (a shipped student): the actor
exactly, the critic as the student's critic with zero weights on the privileged inputs (its
values equal the student's until it learns). :func:`actor_model` turns a trained model back
into a plain PPO model holding the actor; :func:`branch_gym.training.model_files.load_model`
does that for every model file it loads to play, so ``ppo:PATH`` plays a privileged-critic run's
files in the plain env.
"""

from __future__ import annotations

from typing import Any

import torch
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy, MultiInputActorCriticPolicy
from stable_baselines3.common.preprocessing import get_flattened_obs_dim
from stable_baselines3.common.torch_layers import CombinedExtractor, MlpExtractor

from branch_gym.training.privileged_state import PRIVILEGED_KEY, without_privileged_space

# Prefixes of the parameters of a plain ActorCriticPolicy that shares its features extractor.
_SHARED_PREFIX = "features_extractor."
_ACTOR_PREFIX = "pi_features_extractor."
_CRITIC_PREFIX = "vf_features_extractor."
_CRITIC_INPUT = "mlp_extractor.value_net.0."
# Parameters of the actor's heads and MLP (copied as they are between the two kinds).
_ACTOR_HEADS = ("mlp_extractor.policy_net.", "action_net.", "log_std")


class ActorFeatures(CombinedExtractor):
    """SB3's ``CombinedExtractor`` over the observation without its privileged entry.

    Its parameters are those of a plain ``CombinedExtractor`` of the env's space; ``forward``
    reads only the keys of that space.
    """

    def __init__(self, observation_space: spaces.Dict, **kwargs: Any) -> None:
        super().__init__(without_privileged_space(observation_space), **kwargs)


class PrivilegedCriticPolicy(MultiInputActorCriticPolicy):
    """An actor on the plain observation, a critic on it and the privileged entry (module doc).

    Takes ``MultiInputActorCriticPolicy``'s arguments; ``share_features_extractor`` must be
    False (the default here) and the extractors are ``CombinedExtractor``s
    (``features_extractor_kwargs`` apply to both).

    Raises:
        ValueError: an observation space without the privileged entry, a shared extractor or
            another extractor class.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Any,
        **kwargs: Any,
    ) -> None:
        spaces_ = getattr(observation_space, "spaces", None)
        if not isinstance(observation_space, spaces.Dict) or PRIVILEGED_KEY not in spaces_:
            raise ValueError(
                f"PrivilegedCriticPolicy needs a Dict observation with a {PRIVILEGED_KEY!r} entry "
                f"(PrivilegedStateWrapper), got {observation_space}"
            )
        if kwargs.setdefault("share_features_extractor", False):
            raise ValueError("PrivilegedCriticPolicy needs share_features_extractor=False")
        extractor = kwargs.setdefault("features_extractor_class", CombinedExtractor)
        if extractor is not CombinedExtractor:
            raise ValueError(f"PrivilegedCriticPolicy builds its own extractors, got {extractor}")
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build(self, lr_schedule: Any) -> None:
        """Replace the two extractors SB3 made (both over the whole space), then build."""
        kwargs = self.features_extractor_kwargs
        self.features_extractor = ActorFeatures(self.observation_space, **kwargs)
        self.pi_features_extractor = self.features_extractor
        self.features_dim = self.features_extractor.features_dim
        self.vf_features_extractor = CombinedExtractor(self.observation_space, **kwargs)
        super()._build(lr_schedule)

    def _build_mlp_extractor(self) -> None:
        """SB3's MLP extractor, its value MLP as wide as the critic's features."""
        super()._build_mlp_extractor()
        critic = MlpExtractor(
            self.vf_features_extractor.features_dim,
            net_arch=self.net_arch,
            activation_fn=self.activation_fn,
            device=self.device,
        )
        self.mlp_extractor.value_net = critic.value_net

    def load_plain_weights(self, plain: BasePolicy) -> None:
        """Start from a plain ``MultiInputPolicy`` of the same env and network shape.

        The actor takes its weights as they are; the critic its extractor (for the keys they
        share) and value MLP, with zero weights on the privileged features, so its values
        equal ``plain``'s on every observation until training changes them.

        Raises:
            ValueError: a policy with a privileged entry of its own, or of another shape
                (named).
        """
        if is_privileged_policy(plain):
            raise ValueError("load_plain_weights takes a plain policy, not a privileged critic's")
        theirs, ours = plain.state_dict(), self.state_dict()
        new: dict[str, torch.Tensor] = {}
        for key, value in theirs.items():
            if key.startswith(_SHARED_PREFIX):  # the actor's and the critic's extractors
                rest = key[len(_SHARED_PREFIX) :]
                for prefix in (_SHARED_PREFIX, _ACTOR_PREFIX, _CRITIC_PREFIX):
                    new[prefix + rest] = value
            elif key.startswith(_CRITIC_INPUT + "weight"):
                new[key] = self._critic_input_weight(value, ours[key])
            elif not key.startswith((_ACTOR_PREFIX, _CRITIC_PREFIX)):
                new[key] = value
        missing = sorted(set(ours) - set(new))
        if missing:
            raise ValueError(f"the plain policy lacks {missing}: another network shape")
        try:
            self.load_state_dict(new)
        except RuntimeError as exc:
            raise ValueError(f"the plain policy does not fit: {exc}") from exc

    def actor_state_dict(self) -> dict[str, torch.Tensor]:
        """The actor's parameters under a plain shared-extractor policy's names (no critic)."""
        state: dict[str, torch.Tensor] = {}
        for key, value in self.state_dict().items():
            if key.startswith(_ACTOR_PREFIX):
                rest = key[len(_ACTOR_PREFIX) :]
                for prefix in (_SHARED_PREFIX, _ACTOR_PREFIX, _CRITIC_PREFIX):
                    state[prefix + rest] = value
            elif key.startswith(_ACTOR_HEADS):
                state[key] = value
        return state

    def _critic_input_weight(self, plain: torch.Tensor, ours: torch.Tensor) -> torch.Tensor:
        """The value MLP's first weight: ``plain``'s columns per key, zeros for the privileged."""
        space = self.observation_space
        columns = _feature_columns(self.pi_features_extractor, without_privileged_space(space))
        ours_columns = _feature_columns(self.vf_features_extractor, space)
        expected = (ours.shape[0], sum(width for _, width in columns.values()))
        if tuple(plain.shape) != expected:
            raise ValueError(
                f"the plain critic's first layer is {tuple(plain.shape)}, this one's takes "
                f"{expected} without the privileged entry: another network shape"
            )
        weight = torch.zeros_like(ours)
        for key, (start, width) in columns.items():
            to = ours_columns[key][0]
            weight[:, to : to + width] = plain[:, start : start + width]
        return weight


def _feature_columns(
    extractor: CombinedExtractor, space: spaces.Dict
) -> dict[str, tuple[int, int]]:
    """Per observation key, (first column, width) of its features in the output of
    ``extractor``, a ``CombinedExtractor`` of ``space``."""
    columns, start = {}, 0
    for key, module in extractor.extractors.items():
        width = getattr(module, "features_dim", None)
        if width is None:  # a Flatten
            width = get_flattened_obs_dim(space[key])
        columns[key] = (start, int(width))
        start += int(width)
    return columns


def is_privileged_policy(policy: Any) -> bool:
    """Whether a policy (or a policy class) is a :class:`PrivilegedCriticPolicy`."""
    if isinstance(policy, type):
        return issubclass(policy, PrivilegedCriticPolicy)
    return isinstance(policy, PrivilegedCriticPolicy)


def actor_model(model: Any) -> Any:
    """Turn a PPO model with a :class:`PrivilegedCriticPolicy` into a plain one, in place.

    The model gets SB3's ``MultiInputPolicy`` on the observation without the privileged entry,
    holding the actor's weights; its critic is freshly initialised (seeded by the model's seed):
    what it plays is the actor's, but warm its value (``value_warmup_steps``) before fine-tuning
    it. A model of another policy is returned unchanged.

    Returns:
        ``model``.
    """
    policy = model.policy
    if not is_privileged_policy(policy):
        return model
    kwargs = {
        key: value
        for key, value in model.policy_kwargs.items()
        if key not in ("share_features_extractor", "features_extractor_class")
    }
    model.policy_class = MultiInputActorCriticPolicy
    model.policy_kwargs = kwargs
    model.observation_space = without_privileged_space(model.observation_space)
    model._setup_model()  # the plain policy and rollout buffer, as SB3's load builds them
    state = model.policy.state_dict()
    state.update(policy.actor_state_dict())
    model.policy.load_state_dict(state)
    return model
