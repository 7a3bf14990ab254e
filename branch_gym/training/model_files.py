"""Model files of trained policies: load, the env id they record, the statistics beside them.

A model file holds a stable-baselines3 ``PPO`` or an sb3-contrib ``RecurrentPPO`` (an LSTM
policy, ``TrainConfig.recurrent``); :func:`load_model` tells them apart by the policy class
recorded in the file. Every model records the env id it was trained on
(:data:`ENV_ID_ATTRIBUTE`, one of :data:`branch_gym.env.versions.ENV_IDS`), checked against its
spaces on load; a file saved before ids were recorded gets the id of the registered env whose
spaces are exactly its own (stable-baselines3's space check, no guessing). Training writes these
files (:mod:`branch_gym.training.train`), :class:`PolicyAgent` plays one (held-out evaluation
here, ``ppo:PATH`` specs in ``agents.ppo``). A model trained with a privileged critic
(``TrainConfig.privileged_critic``) records the plain env's id; loaded to play, it is the plain
PPO model of its actor (:func:`branch_gym.training.privileged_critic.actor_model`).
"""

from __future__ import annotations

import json
import logging
import pickle
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from branch_gym.env.actions import ActionCodec
from branch_gym.env.config import EnvConfig
from branch_gym.env.layout import flatten_observation
from branch_gym.env.observation import observation_space
from branch_gym.env.versions import ENV_VERSIONS, EnvVersion, env_version
from branch_gym.training.privileged_state import without_privileged_space

logger = logging.getLogger(__name__)

# The VecNormalize statistics a model was trained with lie beside it: MODEL_vecnormalize.pkl.
NORMALIZER_SUFFIX = "_vecnormalize.pkl"
# The module of sb3-contrib's recurrent policies, as a model file's policy class records it.
RECURRENT_POLICY_MODULE = "sb3_contrib.common.recurrent."
# The model attribute holding its env id: SB3 saves a model's attributes in the file's ``data``
# JSON and restores them on load, so every save carries it.
ENV_ID_ATTRIBUTE = "branch_gym_env_id"

ModelFinder = Callable[[str], Path]
"""A model name (a file path, or a name a package ships, ``ppo_dagger_v2``) -> its file."""


def existing_file(name: str | Path) -> Path:
    """The :data:`ModelFinder` of plain paths: ``name`` itself, which must be a file.

    Raises:
        FileNotFoundError: no such file (named).
    """
    path = Path(name)
    if not path.is_file():
        raise FileNotFoundError(f"model file {path} does not exist")
    return path


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


def _file_data(path: str | Path) -> dict[str, Any]:
    """The ``data`` JSON of an SB3 model file, read without unpickling anything.

    Raises:
        zipfile.BadZipFile, KeyError, ValueError: not an SB3 model file.
    """
    with zipfile.ZipFile(path) as archive:
        return json.loads(archive.read("data"))


def is_recurrent_file(path: str | Path) -> bool:
    """Whether a model file holds a ``RecurrentPPO`` model.

    Read from the module of the policy class in the zip's ``data`` JSON, without unpickling
    anything: ``PPO.load`` would also load a recurrent model, as a PPO that cannot train it.

    Raises:
        zipfile.BadZipFile, KeyError, ValueError: not an SB3 model file.
    """
    module = _file_data(path).get("policy_class", {}).get("__module__", "")
    return str(module).startswith(RECURRENT_POLICY_MODULE)


def saved_env_id(path: str | Path) -> str | None:
    """The env id a model file records (None for a file saved before ids were recorded).

    Raises:
        zipfile.BadZipFile, KeyError, ValueError: not an SB3 model file.
    """
    value = _file_data(path).get(ENV_ID_ATTRIBUTE)
    return None if value is None else str(value)


def version_spaces(version: EnvVersion) -> tuple[spaces.Space, spaces.Space]:
    """The (observation, action) spaces of a registered id with the default env settings."""
    config = EnvConfig(**version.env_kwargs())
    observation = observation_space(
        config.observation,
        config.flatten,
        config.coverage,
        price=config.branch_value_s is not None,
    )
    codec = ActionCodec(
        config.action_type,
        config.theta_max_deg,
        config.discrete_angles_deg,
        config.trigger_angles_deg,
    )
    return observation, codec.space


def env_id_of_spaces(observation: spaces.Space, action: spaces.Space) -> str:
    """The registered id whose spaces are exactly these (for files without a recorded id).

    Raises:
        ValueError: no registered id has them.
    """
    for version in ENV_VERSIONS:
        if version_spaces(version) == (observation, action):
            return version.env_id
    raise ValueError(f"no registered BranchScan env observes {observation} and acts in {action}")


def model_env_id(model: Any, path: str | Path = "<memory>") -> str | None:
    """The env id of a loaded model: the recorded one, checked against its spaces.

    A model without a recorded id (an older file) gets the id whose spaces are its own, or None
    when no registered env has them (a model of another environment). A privileged critic's
    model is compared without the privileged entry of its observation.

    Raises:
        ModelFileError: an unknown recorded id, or spaces that are not that id's (named).
    """
    recorded = getattr(model, ENV_ID_ATTRIBUTE, None)
    observation = without_privileged_space(model.observation_space)
    if recorded is None:
        try:
            return env_id_of_spaces(observation, model.action_space)
        except ValueError:
            return None
    try:
        expected = version_spaces(env_version(recorded))
    except ValueError as exc:
        raise ModelFileError(f"model file {path}: {exc}") from exc
    if expected != (observation, model.action_space):
        raise ModelFileError(
            f"model file {path} records env {recorded!r} but its spaces are not that env's "
            f"({observation}, {model.action_space})"
        )
    return recorded


def load_model(
    path: str | Path, env: Any = None, algorithm: type | None = None, **kwargs: Any
) -> Any:
    """Load a stable-baselines3 PPO or sb3-contrib RecurrentPPO model (on the CPU).

    Args:
        path: The model's ``.zip`` file.
        env: Passed to ``load`` (training envs when resuming).
        algorithm: The class to load it as (a PPO subclass such as the trainer's
            ``WorkerRolloutPPO``), the model as saved (a run resumed); None picks PPO or
            RecurrentPPO from the file, and a privileged critic's model becomes the plain PPO
            model of its actor (to play, or to start another run from).
        **kwargs: More ``load`` arguments (e.g. ``tensorboard_log``).

    Returns:
        The model, its env id in :data:`ENV_ID_ATTRIBUTE` (:func:`model_env_id`; None for a
        model of another environment).

    Raises:
        FileNotFoundError: no such file (named).
        ModelFileError: the file is not a readable PPO or RecurrentPPO model, or records an env
            whose spaces are not its own (named, with the cause).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file {path} does not exist")
    algorithm_given = algorithm is not None
    try:
        if algorithm is None:
            algorithm = algorithm_class(is_recurrent_file(path))
        model = algorithm.load(path, env=env, device="cpu", **kwargs)
    except Exception as exc:  # SB3 raises ValueError, KeyError, pickle and zip errors
        raise ModelFileError(
            f"model file {path} is not a readable stable-baselines3 PPO or sb3-contrib "
            f"RecurrentPPO model ({type(exc).__name__}: {exc})"
        ) from exc
    setattr(model, ENV_ID_ATTRIBUTE, model_env_id(model, path))  # the next save carries it
    if algorithm_given:
        return model
    from branch_gym.training.privileged_critic import actor_model

    return actor_model(model)


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
