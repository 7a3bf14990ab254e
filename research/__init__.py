"""Studies behind the shipped recipes: run from the repository root, not installed.

* ``calibration.py``: a discrete student's decision threshold, its "hold" logit shifted (made
  ``ppo_dagger_v2_shift1`` from ``ppo_dagger_v2``);
* ``selection.py``: score candidate models with LK tracking on validation trees, keep the best;
* ``memory_probe.py``: does memory help, feed-forward against LSTM fits of a DAgger run's labels;
* ``orchard_ablation.py``: the orchard world with one of its parts taken away (``docs/worlds.md``).

Each is a command (``python -m research.calibration --help``); what they found is in
``docs/results/``. They use the library (``branch_gym``, ``agents``) and nothing uses them.
"""
