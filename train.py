"""Train a PPO rotation policy: a thin wrapper of :func:`agents.commands.train`.

The installed command is ``branch-gym-train``; ``python train.py --help`` lists the options.
"""

import sys

from agents.commands import train as main
from branch_gym.training.cli import EXIT_INTERRUPTED, EXIT_USAGE, build_parser

__all__ = ["EXIT_INTERRUPTED", "EXIT_USAGE", "build_parser", "main"]

if __name__ == "__main__":
    sys.exit(main())
