"""One factory from a policy spec string to an agent (``eval.py --policies``, the demo, tests).

=========================  =====================================================================
spec                       agent
=========================  =====================================================================
``none``                   :class:`agents.baselines.NoRotationAgent` (paper Table I, 0 / 0)
``periodic:ANGLE:FREQ``    :class:`agents.baselines.PeriodicAgent`, the paper's controller
``ftl:ANGLE:FREQ``         :class:`agents.ftl.FtlAgent`, the authors' code: a stage every FoV /
                           (2 FREQ), targets away from model branches pointing at the camera
``disagreement[:ANGLE]``   :class:`agents.disagreement.DisagreementAgent`
``ppo:PATH[@SECONDS]``     a trained SB3 PPO model (:func:`agents.ppo.load_policy`; PATH may
                           name a shipped model, ``ppo:ppo_dagger_v2``); a model conditioned on
                           the price of scan time (v1, v2) acts at SECONDS per found branch
``privileged``             :class:`branch_gym.privileged.PrivilegedAgent`: reads the ground truth
                           (simulation only), the upper bound of a policy
``privileged:home``        the same, turning back to 0 once nothing is pending (an expert)
=========================  =====================================================================

:data:`AGENTS` is the :class:`branch_gym.policy.PolicyFactory` of these specs that the commands
(:mod:`agents.commands`) hand to the evaluation: the gym itself does not import ``agents``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.baselines import NO_ROTATION_SPEC, NoRotationAgent, PeriodicAgent, parse_periodic_spec
from agents.disagreement import SPEC_KIND as DISAGREEMENT_KIND
from agents.disagreement import DisagreementAgent, parse_disagreement_spec
from agents.ftl import SPEC_KIND as FTL_KIND
from agents.ftl import FtlAgent, parse_ftl_spec
from agents.ppo import (
    PPO_SPEC_PREFIX,
    PRICE_SEPARATOR,
    check_ppo_spec,
    load_policy,
    shipped_models,
    spec_env_id,
    split_price,
)
from branch_gym.env.versions import env_version
from branch_gym.policy import Policy
from branch_gym.privileged import PrivilegedAgent, parse_privileged_spec
from branch_gym.training.model_files import normalizer_path

SPEC_FORMS = (
    "'none', 'periodic:ANGLE_DEG:FREQ', 'ftl:ANGLE_DEG:FREQ', 'disagreement[:ANGLE_DEG]', "
    "'privileged[:home]' or 'ppo:PATH'"
)


def check_spec(spec: str) -> None:
    """Validate a spec without building anything (a ``ppo:`` model file must exist).

    Raises:
        ValueError: an unknown or malformed spec (naming the valid forms), or a ``ppo:`` spec
            whose model file does not exist.
    """
    if spec.startswith(PPO_SPEC_PREFIX):
        try:
            check_ppo_spec(spec)
        except FileNotFoundError as exc:
            raise ValueError(str(exc)) from exc
    elif spec.split(":")[0] == DISAGREEMENT_KIND:
        parse_disagreement_spec(spec)
    elif spec.split(":")[0] == FTL_KIND:
        parse_ftl_spec(spec)
    elif (
        spec != NO_ROTATION_SPEC
        and parse_privileged_spec(spec) is None
        and parse_periodic_spec(spec) is None
    ):
        raise ValueError(f"unknown policy spec {spec!r}: expected {SPEC_FORMS}")


def spec_env_kwargs(spec: str) -> dict[str, Any]:
    """The ``BranchScanEnv`` settings an agent of ``spec`` acts in.

    The baselines decide target angles and encode them for any action type; the continuous v0
    env represents every angle exactly, so they act there. A ``ppo:`` model acts in the env it
    was trained on: the row of its recorded env id (:mod:`branch_gym.env.versions`).

    Raises:
        FileNotFoundError, branch_gym.training.model_files.ModelFileError: a ``ppo:`` model
            that cannot be loaded.
    """
    if not spec.startswith(PPO_SPEC_PREFIX):
        return {"action_type": "continuous"}
    return env_version(spec_env_id(spec)).env_kwargs()


def spec_reset_options(spec: str) -> dict[str, Any] | None:
    """``reset`` options of a spec: the fixed price of ``ppo:PATH@SECONDS``, else None."""
    _, price = split_price(spec)
    return None if price is None else {"branch_value_s": price}


def make_agent(spec: str, env: Any) -> Policy:
    """The agent of a policy spec, set up for ``env``'s action space.

    Args:
        spec: A policy spec (see the module docstring).
        env: A ``BranchScan`` env, possibly wrapped or vectorised.

    Raises:
        ValueError: an unknown or malformed spec, or a model that does not fit ``env``.
        FileNotFoundError: a ``ppo:`` model file that does not exist.
    """
    if spec.startswith(PPO_SPEC_PREFIX):
        return load_policy(check_ppo_spec(spec), env)
    if spec.split(":")[0] == DISAGREEMENT_KIND:
        return DisagreementAgent.for_env(env, parse_disagreement_spec(spec))
    ftl = parse_ftl_spec(spec)
    if ftl is not None:
        return FtlAgent.for_env(env, ftl)
    if spec == NO_ROTATION_SPEC:
        return NoRotationAgent.for_env(env)
    privileged = parse_privileged_spec(spec)
    if privileged is not None:
        return PrivilegedAgent.for_env(env, privileged)
    periodic = parse_periodic_spec(spec)
    if periodic is None:
        raise ValueError(f"unknown policy spec {spec!r}: expected {SPEC_FORMS}")
    return PeriodicAgent.for_env(env, *periodic)


def model_files(spec: str) -> tuple[Path, ...]:
    """The files of a ``ppo:`` spec's model (the model, its statistics if any); () otherwise.

    Raises:
        FileNotFoundError: a ``ppo:`` model file that does not exist.
    """
    if not spec.startswith(PPO_SPEC_PREFIX):
        return ()
    model = check_ppo_spec(spec)
    stats = normalizer_path(model)
    return (model, stats) if stats.is_file() else (model,)


def short_label(spec: str) -> str:
    """A policy spec as the figures name it: a model path shortened to its file's stem.

    >>> short_label("ppo:research/records/run/refit.zip@400")
    'ppo:refit@400'
    >>> short_label("periodic:22.5:1.5")
    'periodic:22.5:1.5'
    """
    if not spec.startswith(PPO_SPEC_PREFIX):
        return spec
    path, separator, price = spec[len(PPO_SPEC_PREFIX) :].partition(PRICE_SEPARATOR)
    return f"{PPO_SPEC_PREFIX}{Path(path).stem}{separator}{price}"


@dataclass(frozen=True)
class AgentFactory:
    """The specs of this module as a :class:`branch_gym.policy.PolicyFactory` (picklable)."""

    @property
    def spec_forms(self) -> str:
        """The spec forms, with the shipped models' names, for ``--help``."""
        return (
            "none | periodic:ANGLE_DEG:FREQ | ftl:ANGLE_DEG:PAN_FREQ | disagreement[:ANGLE_DEG] "
            "| privileged | ppo:PATH_OR_SHIPPED_NAME[@SECONDS] (shipped: "
            f"{', '.join(shipped_models())})"
        )

    def check(self, spec: str) -> None:
        """See :func:`check_spec`."""
        check_spec(spec)

    def make(self, spec: str, env: Any) -> Policy:
        """See :func:`make_agent`."""
        return make_agent(spec, env)

    def env_kwargs(self, spec: str) -> dict[str, Any]:
        """See :func:`spec_env_kwargs`."""
        return spec_env_kwargs(spec)

    def reset_options(self, spec: str) -> dict[str, Any] | None:
        """See :func:`spec_reset_options`."""
        return spec_reset_options(spec)

    def files(self, spec: str) -> tuple[Path, ...]:
        """See :func:`model_files`."""
        return model_files(spec)

    def is_learned(self, spec: str) -> bool:
        """A ``ppo:`` model."""
        return spec.startswith(PPO_SPEC_PREFIX)

    def label(self, spec: str) -> str:
        """See :func:`short_label`."""
        return short_label(spec)


AGENTS = AgentFactory()
