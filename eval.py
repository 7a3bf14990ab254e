"""Evaluate rotation policies: a thin wrapper of :func:`agents.commands.evaluate`.

The installed command is ``branch-gym-eval``; ``python eval.py --help`` lists the options
(``--world``, ``--tree``, ``--tracker``, ``--segmenter``, ``--record``, ``--backend ray``, ...).
"""

import sys

from agents.commands import evaluate as main
from agents.commands import evaluation_parser as build_parser
from branch_gym.evaluation.cli import ERROR_LOG, EXIT_INTERRUPTED, EXIT_TRIAL_FAILED, EXIT_USAGE

__all__ = [
    "ERROR_LOG",
    "EXIT_INTERRUPTED",
    "EXIT_TRIAL_FAILED",
    "EXIT_USAGE",
    "build_parser",
    "main",
]

if __name__ == "__main__":
    sys.exit(main())
