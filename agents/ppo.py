"""Loading trained policies: SB3 PPO models as agents with ``predict``, clear errors on bad files.

A model file holds a stable-baselines3 ``PPO`` or an sb3-contrib ``RecurrentPPO`` (an LSTM
policy, ``TrainConfig.recurrent``); :func:`load_model` tells them apart by the policy class
recorded in the file. Every model records the env id it was trained on
(:data:`ENV_ID_ATTRIBUTE`, one of :data:`branch_gym.env.versions.ENV_IDS`), checked against its
spaces on load; a file saved before ids were recorded gets the id of the registered env whose
spaces are exactly its own (stable-baselines3's space check, no guessing). The shipped models
(:data:`SHIPPED_MODELS_DIR`, each with a card) are found by name: ``ppo:ppo_dagger_v2`` (also
``ppo:models/ppo_dagger_v2.zip``, their former place in the repository).

:func:`load_policy` returns a :class:`PolicyAgent`: the model's ``predict(obs, state,
episode_start, deterministic)`` (the LSTM state of a recurrent model is returned and passed back
in) with ``deterministic=True`` by default (evaluation must not sample), the ``VecNormalize``
statistics saved beside the model applied to the observation, and, for a model trained on
``BranchScanFlat-v0`` acting in a Dict-observation env, the observation flattened the way the
env flattens it. ``agents.factory.make_agent("ppo:PATH", env)`` uses it.

>>> split_price("ppo:ppo_dagger_v2@100")
('ppo:ppo_dagger_v2', 100.0)
>>> resolve_model_path("ppo_dagger_v2") == SHIPPED_MODELS_DIR / "ppo_dagger_v2.zip"
True
>>> saved_env_id(resolve_model_path("ppo_dagger_v2"))
'BranchScanDiscrete-v2'
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

from branch_gym.env.actions import ActionCodec
from branch_gym.env.config import EnvConfig
from branch_gym.env.layout import flatten_observation
from branch_gym.env.observation import flat_space, observation_space
from branch_gym.env.versions import ENV_VERSIONS, EnvVersion, env_version

logger = logging.getLogger(__name__)

PPO_SPEC_PREFIX = "ppo:"  # policy spec "ppo:PATH" (eval.py --policies, make_agent)
# "ppo:PATH@VALUE" evaluates a price-conditioned (v1) policy at VALUE seconds per found branch.
PRICE_SEPARATOR = "@"
# The VecNormalize statistics a model was trained with lie beside it: MODEL_vecnormalize.pkl.
NORMALIZER_SUFFIX = "_vecnormalize.pkl"
# The module of sb3-contrib's recurrent policies, as a model file's policy class records it.
RECURRENT_POLICY_MODULE = "sb3_contrib.common.recurrent."
# The model attribute holding its env id: SB3 saves a model's attributes in the file's ``data``
# JSON and restores them on load, so every save carries it.
ENV_ID_ATTRIBUTE = "branch_gym_env_id"
# The shipped models (package data), each with a card ``NAME.md`` beside it.
SHIPPED_MODELS_DIR = Path(__file__).resolve().parent / "models"
# Where the shipped models lay in the repository before they became package data.
_FORMER_MODELS_DIR = Path("models")


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
    when no registered env has them (a model of another environment).

    Raises:
        ModelFileError: an unknown recorded id, or spaces that are not that id's (named).
    """
    recorded = getattr(model, ENV_ID_ATTRIBUTE, None)
    if recorded is None:
        try:
            return env_id_of_spaces(model.observation_space, model.action_space)
        except ValueError:
            return None
    try:
        expected = version_spaces(env_version(recorded))
    except ValueError as exc:
        raise ModelFileError(f"model file {path}: {exc}") from exc
    if expected != (model.observation_space, model.action_space):
        raise ModelFileError(
            f"model file {path} records env {recorded!r} but its spaces are not that env's "
            f"({model.observation_space}, {model.action_space})"
        )
    return recorded


def resolve_model_path(name: str | Path) -> Path:
    """The model file of a ``ppo:`` spec: a path, or a shipped model's name.

    Args:
        name: A file path; or ``NAME`` / ``NAME.zip`` / ``models/NAME.zip`` of a shipped model
            (:func:`shipped_models`) when no such file exists.

    Raises:
        FileNotFoundError: neither a file nor a shipped model (named, with the shipped ones).
    """
    path = Path(name)
    if path.is_file():
        return path
    if path.parent in (Path("."), _FORMER_MODELS_DIR) and path.suffix in ("", ".zip"):
        shipped = SHIPPED_MODELS_DIR / (path.stem + ".zip")
        if shipped.is_file():
            return shipped
    raise FileNotFoundError(
        f"model file {path} does not exist (shipped models: {', '.join(shipped_models())})"
    )


def shipped_models() -> list[str]:
    """The names of the shipped models (``ppo:NAME`` plays one)."""
    return sorted(p.stem for p in SHIPPED_MODELS_DIR.glob("*.zip"))


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
    return model


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

    Returns:
        The model file (:func:`resolve_model_path`: a shipped model may be named).

    Raises:
        ValueError: not a ``ppo:`` spec, or an empty path.
        FileNotFoundError: the model file does not exist (named).
    """
    spec, _ = split_price(spec)
    if not spec.startswith(PPO_SPEC_PREFIX) or not spec[len(PPO_SPEC_PREFIX) :]:
        raise ValueError(f"expected a policy spec 'ppo:PATH_TO_MODEL.zip[@SECONDS]', got {spec!r}")
    try:
        return resolve_model_path(spec[len(PPO_SPEC_PREFIX) :])
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"policy spec {spec!r}: {exc}") from None


def spec_env_id(spec: str) -> str:
    """The env id of a ``ppo:`` spec's model: recorded in the file, else from its spaces.

    Raises:
        FileNotFoundError, ModelFileError: a model that cannot be read.
    """
    path = check_ppo_spec(spec)
    try:
        recorded = saved_env_id(path)
    except Exception:  # an unreadable file: load_model names the cause
        recorded = None
    if recorded is not None and recorded in {v.env_id for v in ENV_VERSIONS}:
        return recorded
    env_id = getattr(load_model(path), ENV_ID_ATTRIBUTE)
    if env_id is None:
        raise ModelFileError(f"model file {path} was not trained on a BranchScan env")
    return env_id


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


def _check_spaces(path: Path, model: Any, env: Any) -> bool:
    """Raise unless ``model`` can act in ``env``; True when Dict observations need flattening."""
    env_obs = env.observation_space
    env_actions = env.action_space
    if env_actions != model.action_space:
        raise ValueError(
            f"model {path} acts in {model.action_space}, the env in {env_actions}"
            f"{_env_ids_note(model, env)}: train on the env id the evaluation uses"
        )
    if env_obs == model.observation_space:
        return False
    if isinstance(env_obs, spaces.Dict) and model.observation_space == flat_space(env_obs.spaces):
        logger.debug("model %s takes flat observations: flattening the env's Dict", path)
        return True
    raise ValueError(
        f"model {path} observes {model.observation_space}, the env gives {env_obs}"
        f"{_env_ids_note(model, env)}"
    )


def _env_ids_note(model: Any, env: Any) -> str:
    """`` (the model was trained on A, the env is B)`` where both ids are known, else ''."""
    env_id = getattr(getattr(env, "spec", None), "id", None)
    model_id = getattr(model, ENV_ID_ATTRIBUTE, None)
    if env_id is None or model_id is None or env_id == model_id:
        return ""
    return f" (the model was trained on {model_id}, the env is {env_id})"
