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
``privileged``             :class:`agents.privileged.PrivilegedAgent`: reads the ground truth
                           (simulation only), the upper bound of a policy
``privileged:home``        the same, turning back to 0 once nothing is pending (an expert)
=========================  =====================================================================
"""

from __future__ import annotations

from typing import Any

from agents.baselines import NO_ROTATION_SPEC, NoRotationAgent, PeriodicAgent, parse_periodic_spec
from agents.disagreement import SPEC_KIND as DISAGREEMENT_KIND
from agents.disagreement import DisagreementAgent, parse_disagreement_spec
from agents.ftl import SPEC_KIND as FTL_KIND
from agents.ftl import FtlAgent, parse_ftl_spec
from agents.ppo import PPO_SPEC_PREFIX, check_ppo_spec, load_policy, spec_env_id, split_price
from agents.privileged import PrivilegedAgent, parse_privileged_spec
from agents.protocol import Agent
from branch_gym.env.versions import env_version

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
        FileNotFoundError, agents.ppo.ModelFileError: a ``ppo:`` model that cannot be loaded.
    """
    if not spec.startswith(PPO_SPEC_PREFIX):
        return {"action_type": "continuous"}
    return env_version(spec_env_id(spec)).env_kwargs()


def spec_reset_options(spec: str) -> dict[str, Any] | None:
    """``reset`` options of a spec: the fixed price of ``ppo:PATH@SECONDS``, else None."""
    _, price = split_price(spec)
    return None if price is None else {"branch_value_s": price}


def make_agent(spec: str, env: Any) -> Agent:
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
