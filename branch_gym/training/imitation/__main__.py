"""``python -m branch_gym.training.imitation``: see :mod:`branch_gym.training.imitation.cli`."""

import sys

from branch_gym.training.imitation.cli import main

sys.exit(main())
