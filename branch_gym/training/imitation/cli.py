"""The command line of a DAgger run (``python -m branch_gym.training.imitation``).

Settings come from three layers: the defaults of :class:`ImitationConfig` (the one place they are
set), a recipe file (``--config configs/dagger_v2.json``: the fields that differ), then the
options given here.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from branch_gym.cli_options import add_scan_options, scan_changes
from branch_gym.config_utils import load_config, with_overrides
from branch_gym.env.versions import ENV_IDS
from branch_gym.evaluation.ray_backend import add_backend_arguments
from branch_gym.privileged import HOME_SPEC
from branch_gym.privileged import SPEC_KIND as PRIVILEGED_SPEC
from branch_gym.training.imitation.config import ImitationConfig
from branch_gym.training.imitation.cost_to_go import ROLLOUTS
from branch_gym.training.imitation.rounds import imitate
from branch_gym.training.model_files import ModelFinder, existing_file

EXIT_USAGE = 2


def build_parser() -> argparse.ArgumentParser:
    """The options; every setting's default is the recipe's, else ``ImitationConfig``'s."""
    parser = argparse.ArgumentParser(
        description="DAgger students of the privileged policy (an SB3 PPO network)",
        epilog="An interrupted run resumes with the same command and --resume.",
    )
    parser.add_argument("--config", type=Path, help="a recipe file (configs/dagger_*.json)")
    parser.add_argument("--out", type=Path, required=True, help="run folder")
    add_backend_arguments(parser, 2, "labelling processes, or CPUs of a private local Ray instance")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out")
    parser.add_argument("--env", choices=ENV_IDS, help="a discrete env id")
    add_scan_options(parser, ("tracker", "segmenter", "world", "tree"))
    parser.add_argument(
        "--init-model", help="start the students from this model's weights (same env and network)"
    )
    parser.add_argument(
        "--all-tracking-frames",
        action="store_true",
        help="render every tracking frame (the default renders only the modeling frames with "
        "the oracle tracker)",
    )
    parser.add_argument("--cnn-output-dim", type=int, help="image features of the network")
    parser.add_argument(
        "--recurrent",
        action="store_true",
        help="an LSTM student (sb3-contrib RecurrentPPO), fitted on whole episodes",
    )
    parser.add_argument("--seed", type=int, help="run seed (training trees, network init)")
    parser.add_argument("--rounds", type=int)
    parser.add_argument("--episodes", type=int, help="episodes (trees) per round")
    parser.add_argument("--epochs", type=int, help="most passes over the labels per fit")
    parser.add_argument("--batch-size", type=int)
    parser.add_argument("--learning-rate", type=float)
    parser.add_argument("--weight-decay", type=float)
    parser.add_argument(
        "--validation-fraction",
        type=float,
        help="labels held out for early stopping (0: none, every epoch runs)",
    )
    parser.add_argument(
        "--continue-weights",
        action="store_true",
        help="fit each round from the previous round's weights, not from a fresh network",
    )
    parser.add_argument("--rotation-weight", type=float, help="loss weight of a rotation label")
    parser.add_argument(
        "--reference-value",
        type=float,
        metavar="S",
        help="price-conditioned fit: rotation labels weigh rotation-weight * value / S",
    )
    parser.add_argument("--tree-offset", type=int, help="skip this many training trees")
    parser.add_argument(
        "--cost-to-go-states",
        type=int,
        metavar="K",
        help="price K states of each episode by cost-to-go branches (0: plain DAgger)",
    )
    parser.add_argument(
        "--rollout", choices=ROLLOUTS, help="who plays after a branch's action (default student)"
    )
    parser.add_argument("--expert-label-weight", type=float, help="weight of the expert labels")
    parser.add_argument("--cost-to-go-weight", type=float, help="weight of the expected regret")
    parser.add_argument(
        "--expert",
        choices=(PRIVILEGED_SPEC, HOME_SPEC),
        help="the labelling expert (default privileged; privileged:home turns back to 0)",
    )
    return parser


def config_from_args(args: argparse.Namespace) -> ImitationConfig:
    """The run's configuration: defaults, then the recipe file, then the options given.

    Raises:
        FileNotFoundError: no such recipe file.
        ValueError: a bad recipe or value (named).
    """
    config = load_config(ImitationConfig, args.config)
    tracker = args.tracker or config.train.tracker
    train_changes = {
        "env_id": args.env,
        **scan_changes(args),
        "init_model": args.init_model,
        "seed": args.seed,
        "recurrent": True if args.recurrent else None,
        # pose-only tracking frames need the oracle tracker
        "render_tracking_frames": True if args.all_tracking_frames or tracker != "oracle" else None,
    }
    changes = {
        "train": {**train_changes, "ppo": {"cnn_output_dim": args.cnn_output_dim}},
        "rounds": args.rounds,
        "episodes": args.episodes,
        "epochs": args.epochs,
        "batch_size": args.batch_size,
        "learning_rate": args.learning_rate,
        "weight_decay": args.weight_decay,
        "validation_fraction": args.validation_fraction,
        "from_scratch": False if args.continue_weights else None,
        "rotation_weight": args.rotation_weight,
        "reference_value_s": args.reference_value,
        "tree_offset": args.tree_offset,
        "cost_to_go_states": args.cost_to_go_states,
        "rollout": args.rollout,
        "expert_label_weight": args.expert_label_weight,
        "cost_to_go_weight": args.cost_to_go_weight,
        "expert": args.expert,
    }
    return with_overrides(config, changes)


def main(argv: list[str] | None = None, find_model: ModelFinder = existing_file) -> int:
    """Run the command line; returns the exit status.

    Args:
        argv: The arguments (None: ``sys.argv[1:]``).
        find_model: ``--init-model`` -> its file; ``agents.commands`` (``branch-gym-imitate``)
            hands in ``agents.ppo.resolve_model_path``, which also knows the shipped models'
            names.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        config = config_from_args(args)
        final = imitate(
            config,
            args.out,
            args.resume,
            args.workers,
            True,
            args.backend,
            args.address,
            find_model,
        )
    except (FileExistsError, FileNotFoundError, ValueError, ImportError) as exc:
        logging.getLogger(__name__).error("%s", exc)
        return EXIT_USAGE
    print(f"wrote {final}")
    return 0
