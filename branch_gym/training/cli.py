"""Train a PPO rotation policy on the BranchScan environment (stable-baselines3).

The command line of :func:`branch_gym.training.train.train` (``train.py`` at the repository root
and the installed ``branch-gym-train``). Settings come from ``TrainConfig``'s defaults, then a
recipe file (``--config configs/ppo_v2_finetune.json``), then the options given.

Usage::

    python train.py --out runs/NAME [--config configs/NAME.json] [--env BranchScan-v0] \\
        [--timesteps 200000] [--n-envs 2] [--seed 0] [--resume] [--tracker lk|oracle] \\
        [--segmenter gt|noisy:mild|...] [--tree paper] \\
        [--end-height 0.75] [--speed 0.025] [--checkpoint-every 10000] [--eval-every 10000] \\
        [--eval-trees 10] [--normalize] [--n-steps 256] [--batch-size 64] [--n-epochs 10] \\
        [--learning-rate 3e-4] [--log-std-init 0] [--recurrent] [--init-model MODEL.zip] \\
        [--init-logit-scale 3] [--value-warmup 16384] [--worker-rollouts]

OUT then holds config.json, TensorBoard logs (tensorboard --logdir OUT/tb), checkpoints/,
best_model.zip, evaluations.jsonl and final_model.zip. Evaluate a model with
``python eval.py --policies none ppo:OUT/final_model.zip ...``. Training trees, the held-out
evaluation trees and eval.py's trees never overlap (branch_gym/training/seeds.py).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from branch_gym.cli_options import add_scan_options, scan_changes
from branch_gym.config_utils import load_config
from branch_gym.env.versions import ENV_IDS
from branch_gym.training.config import TrainConfig
from branch_gym.training.model_files import ModelFinder, existing_file
from branch_gym.training.train import train

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n", 1)[0],
        epilog="A killed run loses at most --checkpoint-every steps: re-run the same command "
        "with --resume (--timesteps, --checkpoint-every and --eval-every may change).",
    )
    parser.add_argument("--config", type=Path, help="a recipe file (configs/ppo_*.json)")
    parser.add_argument("--env", choices=ENV_IDS, help="environment id")
    parser.add_argument("--timesteps", type=int, help="total environment steps")
    parser.add_argument("--n-envs", type=int, help="parallel envs")
    parser.add_argument("--seed", type=int, help="run seed")
    parser.add_argument("--out", type=Path, required=True, help="run folder")
    parser.add_argument("--resume", action="store_true", help="continue from the last checkpoint")
    add_scan_options(parser, ("tracker", "segmenter", "tree", "end_height", "speed"))
    parser.add_argument("--checkpoint-every", type=int, metavar="STEPS", help="checkpoint period")
    parser.add_argument("--eval-every", type=int, metavar="STEPS", help="evaluation period; 0 off")
    parser.add_argument("--eval-trees", type=int, metavar="N", help="held-out trees per evaluation")
    parser.add_argument("--normalize", action="store_true", help="VecNormalize obs vector + reward")
    parser.add_argument(
        "--recurrent", action="store_true", help="sb3-contrib RecurrentPPO with an LSTM policy"
    )
    parser.add_argument(
        "--worker-rollouts",
        action="store_true",
        help="each env process plays whole rollouts under a policy copy (no lockstep; faster)",
    )
    parser.add_argument(
        "--init-model",
        type=Path,
        help="start a new run from this model's weights (e.g. a DAgger student)",
    )
    parser.add_argument(
        "--init-logit-scale",
        type=float,
        metavar="K",
        help="multiply the init model's action logits by K (sampling temperature 1/K)",
    )
    parser.add_argument(
        "--value-warmup",
        type=int,
        metavar="STEPS",
        help="first steps in which only the value function learns (for --init-model)",
    )
    parser.add_argument(
        "--value-warmup-learning-rate",
        type=float,
        metavar="LR",
        help="learning rate during --value-warmup (default: --learning-rate throughout)",
    )
    parser.add_argument(
        "--learning-rate-ramp",
        type=int,
        metavar="STEPS",
        help="steps after --value-warmup over which the learning rate rises from 0",
    )
    parser.add_argument("--n-steps", type=int, help="PPO steps per env per rollout")
    parser.add_argument("--batch-size", type=int, help="PPO minibatch size")
    parser.add_argument("--n-epochs", type=int, help="PPO epochs per rollout")
    parser.add_argument("--learning-rate", type=float, help="PPO learning rate")
    parser.add_argument("--log-std-init", type=float, help="initial log std of the action")
    parser.add_argument("--ent-coef", type=float, help="PPO entropy bonus")
    parser.add_argument(
        "--first-action-logit", type=float, help="initial logit bonus of discrete action 0 (hold)"
    )
    parser.add_argument("--gamma", type=float, help="PPO discount")
    parser.add_argument(
        "--cnn-output-dim", type=int, help="image features of a Dict observation (default 256)"
    )
    parser.add_argument(
        "--time-penalty", type=float, metavar="PER_S", help="reward per second of scan time"
    )
    parser.add_argument(
        "--privileged-critic",
        action="store_true",
        help="the critic also reads the ground truth (unseen branches, progress); the actor "
        "only the observation (TrainConfig.privileged_critic)",
    )
    parser.add_argument(
        "--train-branch-value",
        type=float,
        nargs=2,
        metavar=("LOW_S", "HIGH_S"),
        help="draw the training episodes' branch value from this sub-range of the env's "
        "(TrainConfig.train_branch_value_s)",
    )
    parser.add_argument(
        "--view-shaping",
        type=float,
        metavar="WEIGHT",
        help="reward a turn that shows a pending side branch at once, potential-based "
        "(TrainConfig.view_shaping_weight; needs --privileged-critic)",
    )
    parser.add_argument(
        "--target-kl", type=float, help="PPO: stop an update's epochs past this KL divergence"
    )
    parser.add_argument(
        "--pose-only-tracking-frames",
        action="store_true",
        help="render only the frames modeling iterations run on (needs --tracker oracle; faster)",
    )
    return parser


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """The run's configuration: ``TrainConfig``'s defaults, the recipe file, the options given.

    Raises:
        FileNotFoundError: no such recipe file.
        ValueError: a bad recipe or value (named).
    """
    ppo = {
        "n_steps": args.n_steps,
        "batch_size": args.batch_size,
        "n_epochs": args.n_epochs,
        "learning_rate": args.learning_rate,
        "log_std_init": args.log_std_init,
        "ent_coef": args.ent_coef,
        "first_action_logit_init": args.first_action_logit,
        "gamma": args.gamma,
        "target_kl": args.target_kl,
        "cnn_output_dim": args.cnn_output_dim,
    }
    run = {
        "env_id": args.env,
        "timesteps": args.timesteps,
        "n_envs": args.n_envs,
        "seed": args.seed,
        **scan_changes(args),
        "checkpoint_every": args.checkpoint_every,
        "eval_every": args.eval_every,
        "eval_trees": args.eval_trees,
        "time_penalty_per_s": args.time_penalty,
        "value_warmup_steps": args.value_warmup,
        "value_warmup_learning_rate": args.value_warmup_learning_rate,
        "learning_rate_ramp_steps": args.learning_rate_ramp,
        "init_logit_scale": args.init_logit_scale,
        "init_model": None if args.init_model is None else str(args.init_model),
        "normalize": args.normalize or None,
        "recurrent": args.recurrent or None,
        "worker_rollouts": args.worker_rollouts or None,
        "privileged_critic": args.privileged_critic or None,
        "train_branch_value_s": args.train_branch_value,
        "view_shaping_weight": args.view_shaping,
        "render_tracking_frames": False if args.pose_only_tracking_frames else None,
    }
    return load_config(TrainConfig, args.config, {"ppo": ppo, **run})


def main(argv: list[str] | None = None, find_model: ModelFinder = existing_file) -> int:
    """Run the command line; returns the exit status.

    Args:
        argv: The arguments (None: ``sys.argv[1:]``).
        find_model: ``--init-model`` -> its file; ``agents.commands`` (``train.py``,
            ``branch-gym-train``) hands in ``agents.ppo.resolve_model_path``, which also knows
            the shipped models' names.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        config = config_from_args(args)
    except (FileNotFoundError, ValueError, TypeError) as exc:
        parser.error(str(exc))
    try:
        result = train(config, args.out, resume=args.resume, progress=True, find_model=find_model)
    except (FileExistsError, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(
            f"\ninterrupted: re-run the same command with --resume to continue from the last "
            f"checkpoint in {args.out / 'checkpoints'}",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    print(f"trained {result.start_timesteps} -> {result.num_timesteps} steps")
    for evaluation in result.evaluations[-1:]:
        print(
            f"last held-out evaluation ({evaluation.episodes} trees): mean reward "
            f"{evaluation.mean_reward:.3f}, missed {evaluation.missed_pct:.1f} %, scan time "
            f"{evaluation.scan_time_s:.1f} s"
        )
    print(f"wrote {result.final_model}")
    return 0
