"""Training learned rotation policies: PPO (``train.py``) and DAgger students (``imitation/``).

===================== =========================================================================
``config.py``         ``TrainConfig`` (env, seeds, schedule) and ``PPOConfig``, frozen, validated
``cli.py``            the command line of :func:`train` (``train.py``, ``branch-gym-train``)
``seeds.py``          disjoint tree seed ranges: training, held-out evaluation, ``eval.py`` trees
``envs.py``           training ``VecEnv`` (Subproc / Dummy, Monitor, VecNormalize), evaluation env
``worker_rollouts.py`` PPO whose rollouts the env processes collect (no per-step lockstep)
``callbacks.py``      per-episode scan metrics to TensorBoard, torch threads by phase, tqdm bar
``checkpoints.py``    atomic checkpoints (model, VecNormalize, ``checkpoint.json``) for resuming
``evaluation.py``     held-out evaluation during training, best model
``curve.py``          the training curve figure
``paths.py``          the files of a run folder
``train.py``          ``train(config, out, resume)``
``imitation/``        DAgger students of the privileged policy (``branch-gym-imitate``)
===================== =========================================================================

The shipped recipes are ``configs/*.json`` (``--config``); studies that are not part of a recipe
(checkpoint selection, threshold calibration, the memory probe) live in ``research/``. Importing
this package is light; the modules load stable-baselines3 and torch.
"""
