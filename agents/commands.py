"""The commands, composed: the gym's command lines with the policies handed in.

``branch_gym`` does not import ``agents`` (imports run one way, ``agents`` -> ``branch_gym``), so
the commands that need both are put together here: each passes the gym's command line what it
cannot know itself.

=====================  ==============================  ===========================================
command                the gym's command line          handed in
=====================  ==============================  ===========================================
``branch-gym-eval``,   :mod:`branch_gym.evaluation.    the policy specs (:data:`agents.factory.
``eval.py``            cli`                            AGENTS`), the paper's Table I columns
``branch-gym-train``,  :mod:`branch_gym.training.cli`  the shipped models' names for
``train.py``                                           ``--init-model`` (:func:`resolve_model_path`)
``branch-gym-imitate`` :mod:`branch_gym.training.      the same
                       imitation.cli`
``branch-gym-demo``    :mod:`branch_gym.demo`          the policy specs, the paper's columns
(``record``)           :mod:`branch_gym.evaluation.    the policy specs
                       record`
=====================  ==============================  ===========================================

``python -m agents.commands COMMAND [ARGS]`` runs one without installing (``eval``, ``train``,
``imitate``, ``demo``, ``record``: one simulated scan recorded as a scan folder).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from agents.factory import AGENTS
from agents.paper import paper_column
from agents.ppo import resolve_model_path
from branch_gym import demo as demo_command
from branch_gym.evaluation import cli as evaluation_cli
from branch_gym.evaluation import record as record_command
from branch_gym.training import cli as training_cli
from branch_gym.training.imitation import cli as imitation_cli


def evaluate(argv: list[str] | None = None) -> int:
    """``branch-gym-eval`` / ``eval.py``: evaluate policies (returns the exit status)."""
    return evaluation_cli.main(argv, AGENTS, paper_column)


def evaluation_parser() -> argparse.ArgumentParser:
    """The options of :func:`evaluate`."""
    return evaluation_cli.build_parser(AGENTS)


def train(argv: list[str] | None = None) -> int:
    """``branch-gym-train`` / ``train.py``: train a PPO policy (returns the exit status)."""
    return training_cli.main(argv, resolve_model_path)


def imitate(argv: list[str] | None = None) -> int:
    """``branch-gym-imitate``: a DAgger run (returns the exit status)."""
    return imitation_cli.main(argv, resolve_model_path)


def demo(argv: list[str] | None = None) -> int:
    """``branch-gym-demo`` / ``make demo`` (returns the exit status)."""
    return demo_command.main(argv, AGENTS, paper_column)


def record(argv: list[str] | None = None) -> int:
    """Record one simulated scan as a scan folder (returns the exit status)."""
    return record_command.main(argv, AGENTS)


COMMANDS: dict[str, Callable[[list[str] | None], int]] = {
    "eval": evaluate,
    "train": train,
    "imitate": imitate,
    "demo": demo,
    "record": record,
}


def main(argv: list[str] | None = None) -> int:
    """``python -m agents.commands COMMAND [ARGS]``: run one command."""
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in COMMANDS:
        print(f"usage: python -m agents.commands {{{','.join(COMMANDS)}}} [ARGS]", file=sys.stderr)
        return 2
    return COMMANDS[argv[0]](argv[1:])


if __name__ == "__main__":
    sys.exit(main())
