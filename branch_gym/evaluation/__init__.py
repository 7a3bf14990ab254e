"""Evaluation of rotation policies over many simulated trees (paper Table I); ``eval.py`` is its
command line.

Modules: :mod:`~branch_gym.evaluation.trials` (one saved trial), :mod:`.runner` (process pool,
resume), :mod:`.report` (summary, table, CSV), :mod:`.paper` (the paper's numbers),
:mod:`.plots` (figures), :mod:`.pipeline` (all of it in order).
"""
