"""Loading trained policies: SB3 PPO models as agents with ``predict``, clear errors on bad files.

A model file holds a stable-baselines3 ``PPO`` or an sb3-contrib ``RecurrentPPO`` (an LSTM
policy, ``TrainConfig.recurrent``); :func:`load_model` tells them apart by the policy class
recorded in the file. :func:`load_policy` returns a :class:`PolicyAgent`: the model's
``predict(obs, state, episode_start, deterministic)`` (the LSTM state of a recurrent model is
returned and passed back in) with ``deterministic=True`` by default (evaluation must not
sample), the ``VecNormalize`` statistics saved beside the model applied to the observation, and,
for a model trained on ``BranchScanFlat-v0`` acting in a Dict-observation env, the observation
flattened the way the env flattens it. ``agents.factory.make_agent("ppo:PATH", env)`` uses it.
"""

from __future__ import annotations

import json
import logging
import math
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from branch_gym.env.config import ObservationConfig
from branch_gym.env.coverage import CoverageConfig
from branch_gym.env.layout import (
    COVERAGE_KEY,
    DISCRETE_ANGLES_DEG,
    TRIGGER_ANGLES_DEG,
    flatten_observation,
)
from branch_gym.env.observation import observation_space as observation_space_of

logger = logging.getLogger(__name__)

PPO_SPEC_PREFIX = "ppo:"  # policy spec "ppo:PATH" (eval.py --policies, make_agent)
# "ppo:PATH@VALUE" evaluates a price-conditioned (v1) policy at VALUE seconds per found branch.
PRICE_SEPARATOR = "@"
# The VecNormalize statistics a model was trained with lie beside it: MODEL_vecnormalize.pkl.
NORMALIZER_SUFFIX = "_vecnormalize.pkl"
# The module of sb3-contrib's recurrent policies, as a model file's policy class records it.
RECURRENT_POLICY_MODULE = "sb3_contrib.common.recurrent."


def normalizer_path(model_path: str | Path) -> Path:
    """The ``VecNormalize`` statistics file that belongs to a model file."""
    model_path = Path(model_path)
    return model_path.with_name(model_path.stem + NORMALIZER_SUFFIX)


class ModelFileError(ValueError):
    """A model (or its normalisation statistics) file exists but cannot be loaded."""


def algorithm_class(recurrent: bool) -> type:
    """The algorithm: stable-baselines3's ``PPO``, or sb3-contrib's ``RecurrentPPO`` (LSTM)."""
    if recurrent:
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO
    from stable_baselines3 import PPO

    return PPO


def is_recurrent_file(path: str | Path) -> bool:
    """Whether a model file holds a ``RecurrentPPO`` model.

    Read from the module of the policy class in the zip's ``data`` JSON, without unpickling
    anything: ``PPO.load`` would also load a recurrent model, as a PPO that cannot train it.

    Raises:
        zipfile.BadZipFile, KeyError, ValueError: not an SB3 model file.
    """
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
    module = data.get("policy_class", {}).get("__module__", "")
    return str(module).startswith(RECURRENT_POLICY_MODULE)


def load_model(
    path: str | Path, env: Any = None, algorithm: type | None = None, **kwargs: Any
) -> Any:
    """Load a stable-baselines3 PPO or sb3-contrib RecurrentPPO model (on the CPU).

    Args:
        path: The model's ``.zip`` file.
        env: Passed to ``load`` (training envs when resuming).
        algorithm: The class to load it as (a PPO subclass such as the trainer's
            ``WorkerRolloutPPO``); None picks PPO or RecurrentPPO from the file.
        **kwargs: More ``load`` arguments (e.g. ``tensorboard_log``).

    Raises:
        FileNotFoundError: no such file (named).
        ModelFileError: the file is not a readable PPO or RecurrentPPO model (named, with the
            cause).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file {path} does not exist")
    try:
        if algorithm is None:
            algorithm = algorithm_class(is_recurrent_file(path))
        return algorithm.load(path, env=env, device="cpu", **kwargs)
    except Exception as exc:  # SB3 raises ValueError, KeyError, pickle and zip errors
        raise ModelFileError(
            f"model file {path} is not a readable stable-baselines3 PPO or sb3-contrib "
            f"RecurrentPPO model ({type(exc).__name__}: {exc})"
        ) from exc


def load_normalizer(path: str | Path) -> Any:
    """Unpickle ``VecNormalize`` statistics (without an env: for ``normalize_obs`` only).

    Raises:
        FileNotFoundError: no such file (named).
        ModelFileError: the file does not hold ``VecNormalize`` statistics (named).
    """
    from stable_baselines3.common.vec_env import VecNormalize

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"VecNormalize statistics file {path} does not exist")
    try:
        with path.open("rb") as handle:
            normalizer = pickle.load(handle)
    except Exception as exc:
        raise ModelFileError(
            f"VecNormalize statistics file {path} is unreadable ({type(exc).__name__}: {exc})"
        ) from exc
    if not isinstance(normalizer, VecNormalize):
        raise ModelFileError(f"{path} holds a {type(normalizer).__name__}, not VecNormalize stats")
    return normalizer


class PolicyAgent:
    """A trained model acting in a ``BranchScan`` env (SB3's ``predict`` signature).

    Args:
        model: The SB3 model.
        normalizer: ``VecNormalize`` statistics the model was trained with, or None.
        flatten_dict: Flatten Dict observations (vector, then image / 255) for a model trained
            on flat observations.
    """

    def __init__(self, model: Any, normalizer: Any = None, flatten_dict: bool = False) -> None:
        self.model = model
        self.normalizer = normalizer
        self.flatten_dict = flatten_dict

    def predict(
        self,
        observation: dict | np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | bool | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """The model's action(s) for one observation or a batch (deterministic by default).

        Returns:
            The action(s) and the model's next state: a recurrent model's LSTM state, to pass
            back with the next observation (None for PPO).
        """
        if self.flatten_dict and isinstance(observation, dict):
            observation = flatten_observation(observation)
        if self.normalizer is not None:
            observation = self.normalizer.normalize_obs(observation)
        if episode_start is not None:
            episode_start = np.asarray(episode_start, bool).reshape(-1)
        return self.model.predict(
            observation, state=state, episode_start=episode_start, deterministic=deterministic
        )


def load_policy(path: str | Path, env: Any = None) -> PolicyAgent:
    """A trained (Recurrent)PPO model as an agent; ``PATH_vecnormalize.pkl`` beside it applies.

    Args:
        path: The model's ``.zip`` file (e.g. ``runs/NAME/final_model.zip``).
        env: The env the agent will act in (possibly wrapped or vectorised); when given, its
            spaces are checked against the model's.

    Raises:
        FileNotFoundError: the model file does not exist (named).
        ModelFileError: the model or its statistics file is unreadable (named).
        ValueError: the model does not fit ``env``'s observation or action space.
    """
    model = load_model(path)
    stats = normalizer_path(Path(path))
    normalizer = load_normalizer(stats) if stats.exists() else None
    flatten_dict = False
    if env is not None:
        flatten_dict = _check_spaces(Path(path), model, env)
    return PolicyAgent(model, normalizer, flatten_dict)


def check_ppo_spec(spec: str) -> Path:
    """Validate a ``ppo:PATH`` spec without loading the model: the file must exist.

    Raises:
        ValueError: not a ``ppo:`` spec, or an empty path.
        FileNotFoundError: the model file does not exist (named).
    """
    spec, _ = split_price(spec)
    if not spec.startswith(PPO_SPEC_PREFIX) or not spec[len(PPO_SPEC_PREFIX) :]:
        raise ValueError(f"expected a policy spec 'ppo:PATH_TO_MODEL.zip[@SECONDS]', got {spec!r}")
    path = Path(spec[len(PPO_SPEC_PREFIX) :])
    if not path.is_file():
        raise FileNotFoundError(f"model file {path} of policy spec {spec!r} does not exist")
    return path


def observed_coverage(observation_space: spaces.Space) -> CoverageConfig | None:
    """The coverage memory a model observes (v1, or v2 with ``IN_FRONT``), None for v0.

    A Dict space is read by the size of its ``coverage`` entry; a flat Box by its total size.

    Raises:
        ValueError: a ``coverage`` entry of neither the v1 nor the v2 size.
    """
    candidates = (CoverageConfig(), CoverageConfig(in_front_channel=True))
    if isinstance(observation_space, spaces.Dict):
        if COVERAGE_KEY not in observation_space.spaces:
            return None
        size = observation_space.spaces[COVERAGE_KEY].shape[0]
        for coverage in candidates:
            if size == coverage.height_bins * coverage.n_channels:
                return coverage
        raise ValueError(f"a coverage memory of {size} entries is neither v1's nor v2's")
    for coverage in candidates:
        flat = observation_space_of(ObservationConfig(), True, coverage, True)
        if observation_space.shape == flat.shape:
            return coverage
    return None


def split_price(spec: str) -> tuple[str, float | None]:
    """``"ppo:PATH@100"`` -> ``("ppo:PATH", 100.0)``; a spec without a price -> ``(spec, None)``.

    Raises:
        ValueError: a price that is not a positive number of seconds.
    """
    head, separator, price = spec.rpartition(PRICE_SEPARATOR)
    if not separator or not spec.startswith(PPO_SPEC_PREFIX):
        return spec, None
    try:
        value = float(price)
    except ValueError:
        raise ValueError(f"policy spec {spec!r}: the price after '@' must be seconds") from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"policy spec {spec!r}: the price must be positive seconds, got {value}")
    return head, value


def action_type_of(action_space: spaces.Space) -> str:
    """The ``EnvConfig.action_type`` of the registered envs with this action space.

    ``Box`` is "continuous"; ``Discrete(5)`` "discrete" (``DISCRETE_ANGLES_DEG``);
    ``Discrete(6)`` "discrete_hold" (hold + ``DISCRETE_ANGLES_DEG``); ``Discrete(3)`` "trigger"
    (hold + ``TRIGGER_ANGLES_DEG``).

    Raises:
        ValueError: a space no registered env has.
    """
    if isinstance(action_space, spaces.Box):
        return "continuous"
    if isinstance(action_space, spaces.Discrete):
        if action_space.n == 1 + len(TRIGGER_ANGLES_DEG):
            return "trigger"
        if action_space.n == len(DISCRETE_ANGLES_DEG):
            return "discrete"
        if action_space.n == 1 + len(DISCRETE_ANGLES_DEG):
            return "discrete_hold"
    raise ValueError(f"no BranchScan env acts in {action_space}")


def _check_spaces(path: Path, model: Any, env: Any) -> bool:
    """Raise unless ``model`` can act in ``env``; True when Dict observations need flattening."""
    env_obs = env.observation_space
    env_actions = env.action_space
    if env_actions != model.action_space:
        raise ValueError(
            f"model {path} acts in {model.action_space}, the env in {env_actions}: "
            "train on the env id the evaluation uses"
        )
    if env_obs == model.observation_space:
        return False
    if isinstance(env_obs, spaces.Dict) and isinstance(model.observation_space, spaces.Box):
        size = sum(int(np.prod(space.shape)) for space in env_obs.spaces.values())
        if model.observation_space.shape == (size,):
            logger.debug("model %s takes flat observations: flattening the env's Dict", path)
            return True
    raise ValueError(f"model {path} observes {model.observation_space}, the env gives {env_obs}")
