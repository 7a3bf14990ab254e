"""One evaluation trial played through the Gymnasium environment.

``eval.py`` scores policies the way a learning agent meets the task: an agent's
``predict(obs, state, episode_start)`` acts in :class:`branch_gym.env.BranchScanEnv` until the
episode ends. The env wraps the same :class:`branch_gym.scan.ScanSession` as
:func:`branch_gym.scan.run_scan`, so for the same seed and policy both give the same numbers
(tests/test_env_slow.py checks it).
"""

from __future__ import annotations

from branch_gym.env import BranchScanEnv
from branch_gym.scan import ScanConfig, ScanResult

_ENVS: dict[tuple[ScanConfig, str], BranchScanEnv] = {}
_ACTION_TYPES: dict[str, str] = {}  # "ppo:PATH" -> the action type its model acts with


def run_scan_in_env(seed: int, policy_spec: str, config: ScanConfig) -> ScanResult:
    """Scan the tree of ``seed`` with the agent of ``policy_spec`` acting in the env.

    The env is built directly (no step limit: a scan ends at its end height, on a failure or
    at the scan's own time limit) and reused across trials of one configuration. Baselines act
    in the continuous env; a trained model in the env of its action space (a model trained on
    ``BranchScanTrigger-v0`` gets a trigger env): the scan is the same either way.
    """
    from agents.baselines import make_agent

    action_type = policy_action_type(policy_spec)
    env = _ENVS.get((config, action_type))
    if env is None:
        env = _ENVS[config, action_type] = BranchScanEnv(scan=config, action_type=action_type)
    agent = make_agent(policy_spec, env)
    observation, _ = env.reset(seed=seed)
    episode_start, done = True, False
    while not done:
        action, _ = agent.predict(observation, episode_start=episode_start)
        observation, _, terminated, truncated, _ = env.step(action)
        episode_start, done = False, terminated or truncated
    return env.session.result(policy_spec)


def policy_action_type(policy_spec: str) -> str:
    """The env action type a policy acts in: a model's own, "continuous" for the baselines."""
    if not policy_spec.startswith("ppo:"):
        return "continuous"
    if policy_spec not in _ACTION_TYPES:
        from branch_gym.training.policy import action_type_of, check_ppo_spec, load_model

        model = load_model(check_ppo_spec(policy_spec))
        _ACTION_TYPES[policy_spec] = action_type_of(model.action_space)
    return _ACTION_TYPES[policy_spec]
