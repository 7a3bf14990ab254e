"""Training learned rotation policies with stable-baselines3 PPO (``train.py`` at the root).

===================  ===========================================================================
``config.py``        ``TrainConfig`` (env, seeds, schedule) and ``PPOConfig``, frozen, validated
``seeds.py``         disjoint tree seed ranges: training, held-out evaluation, ``eval.py`` trees
``envs.py``          training ``VecEnv`` (Subproc / Dummy, Monitor, VecNormalize), evaluation env
``worker_rollouts.py`` PPO whose rollouts the env processes collect (no per-step lockstep)
``callbacks.py``     per-episode scan metrics to TensorBoard, torch threads by phase, tqdm bar
``checkpoints.py``   atomic checkpoints (model, VecNormalize, ``checkpoint.json``) for resuming
``evaluation.py``    held-out evaluation during training, best model
``selection.py``     checkpoint selection with LK tracking on validation trees (a CLI)
``imitation.py``     DAgger students of the privileged policy (a CLI)
``memory_probe.py`` does memory help: feed-forward against LSTM fits of DAgger labels (a CLI)
``calibration.py``   a discrete student's decision threshold: the "hold" logit shifted (a CLI)
``action_mix.py``    a fixed action mix for benchmarks (``bench/bench_train.py``)
``curve.py``         the training curve figure
``paths.py``         the files of a run folder
``train.py``         ``train(config, out, resume)``
===================  ===========================================================================

Importing this package is light; the modules load stable-baselines3 and torch.
"""
