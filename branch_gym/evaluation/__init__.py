"""Evaluation of rotation policies over many simulated trees (paper Table I).

Modules: :mod:`~branch_gym.evaluation.episodes` (the one episode loop), :mod:`.trials` (one saved
trial), :mod:`.runner` (process pool, resume), :mod:`.report` (summary, table, CSV),
:mod:`.statistics` (bootstrap intervals, paired comparisons), :mod:`.paper` (the paper's
numbers), :mod:`.plots` (figures), :mod:`.pipeline` (all of it in order), :mod:`.cli` (the
command line: ``eval.py``, ``branch-gym-eval``).
"""
