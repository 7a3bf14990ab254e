"""Evaluate rotation policies: a thin wrapper of :mod:`branch_gym.evaluation.cli`.

The installed command is ``branch-gym-eval``; ``python eval.py --help`` lists the options
(``--world``, ``--tree``, ``--tracker``, ``--segmenter``, ``--record``, ``--backend ray``, ...).
"""

import sys

from branch_gym.evaluation.cli import (
    ERROR_LOG,
    EXIT_INTERRUPTED,
    EXIT_TRIAL_FAILED,
    EXIT_USAGE,
    build_parser,
    main,
)

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
