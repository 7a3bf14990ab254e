"""``ppo:PATH[@SECONDS]`` specs: trained policies as agents with ``predict``.

The model files themselves (load, recorded env id, ``VecNormalize`` statistics, clear errors on
bad files) are :mod:`branch_gym.training.model_files`, which training writes. Here: the shipped
models (:data:`SHIPPED_MODELS_DIR`, each with a card) found by name (``ppo:ppo_dagger_v2``, also
``ppo:models/ppo_dagger_v2.zip``, their former place in the repository), the spec's price, and
:func:`load_policy`, which returns a :class:`~branch_gym.training.model_files.PolicyAgent`: the
model's ``predict(obs, state, episode_start, deterministic)`` (the LSTM state of a recurrent
model is returned and passed back in) with ``deterministic=True`` by default (evaluation must
not sample), the ``VecNormalize`` statistics saved beside the model applied to the observation,
and, for a model trained on ``BranchScanFlat-v0`` acting in a Dict-observation env, the
observation flattened the way the env flattens it. ``agents.factory.make_agent("ppo:PATH", env)``
uses it.

>>> split_price("ppo:ppo_dagger_v2@100")
('ppo:ppo_dagger_v2', 100.0)
>>> resolve_model_path("ppo_dagger_v2") == SHIPPED_MODELS_DIR / "ppo_dagger_v2.zip"
True
>>> saved_env_id(resolve_model_path("ppo_dagger_v2"))
'BranchScanDiscrete-v2'
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

from gymnasium import spaces

from branch_gym.env.observation import flat_space
from branch_gym.env.versions import ENV_VERSIONS
from branch_gym.training.model_files import (
    ENV_ID_ATTRIBUTE,
    ModelFileError,
    PolicyAgent,
    load_model,
    load_normalizer,
    normalizer_path,
    saved_env_id,
)

logger = logging.getLogger(__name__)

PPO_SPEC_PREFIX = "ppo:"  # policy spec "ppo:PATH" (eval.py --policies, make_agent)
# "ppo:PATH@VALUE" evaluates a price-conditioned (v1) policy at VALUE seconds per found branch.
PRICE_SEPARATOR = "@"
# The shipped models (package data), each with a card ``NAME.md`` beside it.
SHIPPED_MODELS_DIR = Path(__file__).resolve().parent / "models"
# Where the shipped models lay in the repository before they became package data.
_FORMER_MODELS_DIR = Path("models")


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
