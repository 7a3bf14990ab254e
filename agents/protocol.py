"""What every decision maker here is: anything with stable-baselines3's ``predict``."""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Agent(Protocol):
    """A rotation policy acting in a ``BranchScan`` env (SB3's ``BasePolicy.predict`` signature).

    SB3 models, the paper's controllers (:mod:`agents.baselines`), the disagreement heuristic
    (:mod:`agents.disagreement`) and loaded PPO policies (:mod:`agents.ppo`) all satisfy it, so
    one episode loop (:func:`branch_gym.evaluation.episodes.run_episode`) serves them all.
    """

    def predict(
        self,
        observation: dict | np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | bool | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """The action(s) for one observation or a batch, and the agent's next state.

        Args:
            observation: One observation or a batch (Dict or flat, as the env gives them).
            state: The recurrent state returned by the previous call (None at the start).
            episode_start: (N,) bools, True where an episode starts with this observation.
            deterministic: Take the most likely action (evaluation) instead of sampling.
        """
        ...
