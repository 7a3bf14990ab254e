"""CLI: ``python -m branch_gym.segmenter_training generate|train|evaluate|export|export-onnx|...``.

Examples::

    python -m branch_gym.segmenter_training generate --out runs/segmenter/data --seed 0
    python -m branch_gym.segmenter_training train --data runs/segmenter/data \
        --run runs/segmenter/run --seed 0 --export runs/segmenter.pt
    python -m branch_gym.segmenter_training evaluate \
        --weights recon/segmentation/weights/rgb_clean.pt
    python -m branch_gym.segmenter_training export-onnx recon/segmentation/weights/orchard_flow.pt
    python -m branch_gym.segmenter_training score-real --data ../shared/data/real_dev \
        --weights learned --out results.json --figure real.png

Every command is resumable: ``generate`` skips finished shards, ``train`` continues from the
run folder's checkpoint.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from branch_gym.segmenter_training.config import (
    NEARER_NEGATIVE_FLOW_RATIO,
    SKELETON_TARGETS,
    FlowAugmentConfig,
    GenerateConfig,
    OrchardAugmentConfig,
    TrainConfig,
)
from branch_gym.segmenter_training.evaluate import EvaluateConfig, evaluate_segmenters
from branch_gym.segmenter_training.generate import (
    EVAL_PRESETS,
    generate_shard,
    shard_count,
    shard_path,
    write_shard,
)
from branch_gym.segmenter_training.onnx_export import export_onnx
from branch_gym.segmenter_training.orchard_pairs import (
    ARCHITECTURES,
    OrchardPairsConfig,
    generate_orchard_shard,
    load_orchard_shards,
)
from branch_gym.segmenter_training.real_frames import (
    DEFAULT_SIZE,
    RealScoreConfig,
    draw_score_figure,
    format_scores,
    frames_from_renders,
    load_real_frames,
    score_hand_masks,
    score_report,
    score_segmenter,
)
from branch_gym.segmenter_training.train import export_checkpoint, pair_iou, train
from branch_gym.sim.world import WORLDS
from recon.curve2d.types import Curve2DConfig
from recon.segmentation import load_segmenter
from recon.segmentation.network import ENCODERS, LITE0_ENCODER, LITE0_WIDTHS, SMALL_ENCODER

logger = logging.getLogger("branch_gym.segmenter_training")


def _generate(args: argparse.Namespace) -> None:
    config = GenerateConfig(trees=args.trees, pairs_per_tree=args.pairs_per_tree,
                            trees_per_shard=args.trees_per_shard)  # fmt: skip
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "generate_config.json").write_text(
        json.dumps({"seed": args.seed, **config.to_dict()}, indent=2)
    )
    todo = [i for i in range(shard_count(config)) if not shard_path(out, i).exists()]
    for index in tqdm(todo, desc="shards", unit="shard"):
        write_shard(shard_path(out, index), generate_shard(config, args.seed, index))


def _architecture_weights(
    architectures: list[str], weights: list[float] | None
) -> tuple[float, ...]:
    """``--architecture-weights``, or its default: the config's for all presets, else equal."""
    if weights is not None:
        return tuple(weights)
    if tuple(architectures) == ARCHITECTURES:
        return OrchardPairsConfig.architecture_weights
    return (1.0,) * len(architectures)


def _generate_orchard(args: argparse.Namespace) -> None:
    config = OrchardPairsConfig(
        trees=args.trees,
        pairs_per_tree=args.pairs_per_tree,
        world=args.world,
        baseline_range_m=tuple(args.baseline_range_m),
        pitch_range_deg=tuple(args.pitch_range_deg),
        architectures=tuple(args.architectures),
        architecture_weights=_architecture_weights(args.architectures, args.architecture_weights),
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "generate_config.json").write_text(
        json.dumps(
            {
                "seed": args.seed,
                "world": "orchard",
                "evaluation": args.evaluation,
                **config.to_dict(),
            },
            indent=2,
        )
    )
    todo = [i for i in range(config.shards) if not shard_path(out, i).exists()]
    for index in tqdm(todo, desc="shards", unit="shard"):
        shard = generate_orchard_shard(config, args.seed, index, evaluation=args.evaluation)
        write_shard(shard_path(out, index), shard)


def _train(args: argparse.Namespace) -> None:

    base = TrainConfig()
    default_widths = LITE0_WIDTHS if args.encoder == LITE0_ENCODER else base.net.widths
    net = replace(
        base.net, use_flow=args.flow or args.flow_picture, flow_picture=args.flow_picture,
        encoder=args.encoder,
        widths=tuple(args.widths or default_widths),
        decoder_widths=tuple(args.decoder_widths or base.net.decoder_widths),
    )  # fmt: skip
    flow = replace(
        base.orchard.flow, no_flow_probability=args.no_flow_probability,
        near_twig_probability=args.near_twig_probability,
        exact_probability=args.exact_flow_probability,
    )  # fmt: skip
    config = replace(
        base, net=net, steps=args.steps, batch_size=args.batch_size,
        learning_rate=args.learning_rate,
        encoder_learning_rate_scale=args.encoder_learning_rate_scale,
        side_branch_weight=args.side_branch_weight,
        nearer_negative_weight=args.nearer_negative_weight,
        skeleton_weight=args.skeleton_weight, skeleton_target=args.skeleton_target,
        orchard=replace(
            base.orchard, flow=flow, details_as_background=args.details_as_background,
            overcast_probability=args.overcast_probability,
            nearer_negative_flow_ratio=(
                None if args.nearer_negative_weight == 1.0 else args.nearer_negative_flow_ratio
            ),
        ),
    )  # fmt: skip
    train(
        config,
        data_dir=[Path(folder) for folder in args.data],
        run_dir=Path(args.run),
        seed=args.seed,
        validation_dir=Path(args.validation) if args.validation else None,
        export_path=Path(args.export) if args.export else None,
        max_minutes=args.max_minutes,
        init_weights=Path(args.init) if args.init else None,
    )


def _evaluate(args: argparse.Namespace) -> None:
    import cv2
    import torch

    torch.set_num_threads(1)  # one core, as the segment_ms target
    cv2.setNumThreads(1)

    variants = {}
    for index, weights in enumerate(args.weights):
        segmenter = load_segmenter(f"learned:{weights}")
        name = Path(weights).stem if len(args.weights) > 1 else "learned"
        name = name if name not in {n.split("/")[0] for n in variants} else f"{name}_{index}"
        if segmenter.uses_flow:
            variants[f"{name}/flow"] = (segmenter, True)
        variants[f"{name}/rgb_only"] = (segmenter, False)
    config = EvaluateConfig(
        trees=args.trees,
        frames_per_tree=args.frames_per_tree,
        world=args.world,
        orbit_deg=args.orbit_deg,
    )
    results = {}
    for preset in args.presets:
        results[preset] = evaluate_segmenters(variants, preset, config)
        for name, figures in results[preset].items():
            tqdm.write(f"{preset} {name}: {json.dumps(figures)}")
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=2))


def _score_real(args: argparse.Namespace) -> None:
    spec = args.weights
    if spec != "learned" and not spec.startswith("learned:"):
        spec = f"learned:{spec}"  # a plain weights path
    if args.renders:
        frames = frames_from_renders(load_orchard_shards(Path(args.data)))
    else:
        frames = load_real_frames(
            Path(args.data), size=tuple(args.size), swap_flow_red_blue=not args.flow_as_stored
        )
    curve2d = replace(Curve2DConfig(), max_primary_turn_deg=args.max_primary_turn_deg)
    config = (
        RealScoreConfig.attached(curve2d)
        if args.rule == "attached"
        else RealScoreConfig(curve2d=curve2d)
    )
    segmenter = load_segmenter(spec)
    use_flow = not args.no_flow and getattr(segmenter, "uses_flow_picture", True)
    if not (use_flow or args.no_flow):
        logger.warning("%s does not read flow pictures: scoring it on RGB only", spec)
    scores = score_segmenter(segmenter, frames, use_flow, config)
    hand = score_hand_masks(frames, config)
    inputs = "RGB + flow picture" if use_flow else "RGB only"
    tqdm.write(format_scores(f"segmenter {spec} ({inputs})", scores))
    tqdm.write(format_scores("hand masks (upper bound of the 2D stage)", hand))
    if args.out:
        results = {"data": str(args.data), "weights": spec, "use_flow_picture": use_flow,
                   "size": list(args.size),
                   "flow_as_stored": args.flow_as_stored, "config": config.to_dict(),
                   "segmenter": score_report(scores), "hand_masks": score_report(hand)}  # fmt: skip
        Path(args.out).write_text(json.dumps(results, indent=2))
    if args.figure:
        draw_score_figure(frames, scores, args.figure, hand_scores=hand)


def _evaluate_pairs(args: argparse.Namespace) -> None:
    import torch

    torch.set_num_threads(1)
    data = load_orchard_shards(Path(args.data))
    results = {}
    for weights in args.weights:
        spec = weights if weights.startswith("learned") else f"learned:{weights}"
        results[weights] = pair_iou(load_segmenter(spec), data)
        tqdm.write(f"{weights}: {json.dumps(results[weights])}")
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=2))


def _export(args: argparse.Namespace) -> None:

    step = export_checkpoint(Path(args.run), Path(args.out))
    tqdm.write(f"exported step {step} of {args.run} to {args.out}")


def _export_onnx(args: argparse.Namespace) -> None:
    for weights in args.weights:
        tqdm.write(f"wrote {export_onnx(weights)}")


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and run one command."""
    parser = argparse.ArgumentParser(prog="python -m branch_gym.segmenter_training")
    sub = parser.add_subparsers(dest="command", required=True)

    gen = sub.add_parser("generate", help="render training frame pairs into shards")
    gen.add_argument("--out", required=True)
    gen.add_argument("--seed", type=int, default=0)
    gen.add_argument("--trees", type=int, default=GenerateConfig.trees)
    gen.add_argument("--pairs-per-tree", type=int, default=GenerateConfig.pairs_per_tree)
    gen.add_argument("--trees-per-shard", type=int, default=GenerateConfig.trees_per_shard)

    gor = sub.add_parser(
        "generate-orchard", help="render orchard-world frame pairs with exact flow into shards"
    )
    gor.add_argument("--out", required=True)
    gor.add_argument("--seed", type=int, default=0)
    gor.add_argument("--trees", type=int, default=OrchardPairsConfig.trees)
    gor.add_argument("--pairs-per-tree", type=int, default=OrchardPairsConfig.pairs_per_tree)
    gor.add_argument("--world", default="orchard", choices=("orchard", "clean"))
    gor.add_argument(
        "--baseline-range-m", nargs=2, type=float, metavar=("LOW", "HIGH"),
        default=OrchardPairsConfig.baseline_range_m, help="camera motion between a pair's frames",
    )  # fmt: skip
    gor.add_argument(
        "--pitch-range-deg", nargs=2, type=float, metavar=("LOW", "HIGH"),
        default=OrchardPairsConfig.pitch_range_deg, help="camera tilt up before the pairs",
    )  # fmt: skip
    gor.add_argument(
        "--architectures", nargs="+", choices=ARCHITECTURES, default=ARCHITECTURES,
        help="tree presets drawn from (default: all)",
    )  # fmt: skip
    gor.add_argument(
        "--architecture-weights", nargs="+", type=float, metavar="W",
        help="their probabilities, one per --architectures entry (default: "
        f"{dict(zip(ARCHITECTURES, OrchardPairsConfig.architecture_weights, strict=True))} "
        "for all, equal for a choice)",
    )  # fmt: skip
    gor.add_argument(
        "--evaluation", action="store_true", help="trees of seeds 0..trees-1 (held out)"
    )

    tr = sub.add_parser("train", help="train (resumes from --run)")
    tr.add_argument("--data", required=True, nargs="+", help="shard folder(s)")
    tr.add_argument("--run", required=True)
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--validation", default=None, help="shard folder for validation IoU")
    tr.add_argument("--steps", type=int, default=TrainConfig.steps)
    tr.add_argument("--batch-size", type=int, default=TrainConfig.batch_size)
    tr.add_argument("--learning-rate", type=float, default=TrainConfig.learning_rate)
    tr.add_argument("--widths", type=int, nargs="+", default=None,
                    help="encoder channels per level (default: SegmenterNetConfig's)")  # fmt: skip
    tr.add_argument("--decoder-widths", type=int, nargs="+", default=None,
                    help="decoder channels, one fewer than --widths")  # fmt: skip
    tr.add_argument("--encoder-learning-rate-scale", type=float,
                    default=TrainConfig.encoder_learning_rate_scale,
                    help="the encoder's learning rate as a share of --learning-rate")  # fmt: skip
    tr.add_argument("--encoder", choices=ENCODERS, default=SMALL_ENCODER,
                    help=f"the network's encoder ({LITE0_ENCODER}: its first four stages, "
                    "starting from the ImageNet weights)")  # fmt: skip
    tr.add_argument("--side-branch-weight", type=float, default=TrainConfig.side_branch_weight,
                    help="weight of side-branch pixels in the cross-entropy")  # fmt: skip
    tr.add_argument(
        "--no-flow-probability", type=float,
        default=FlowAugmentConfig.no_flow_probability,
        help="share of orchard training frames seen without a flow picture (colour alone)",
    )  # fmt: skip
    tr.add_argument("--skeleton-weight", type=float, default=TrainConfig.skeleton_weight,
                    help="weight of the soft-skeleton term beside BCE + Dice")  # fmt: skip
    tr.add_argument("--skeleton-target", choices=SKELETON_TARGETS,
                    default=TrainConfig.skeleton_target,
                    help="the term on every branch pixel (all: clDice) or the side branches' "
                    "skeleton recall alone (side)")  # fmt: skip
    tr.add_argument(
        "--exact-flow-probability", type=float, default=FlowAugmentConfig.exact_probability,
        help="share of orchard training pictures from the exact flow corrupted as flow networks "
        "err (the rest: OpenCV's DIS, the flow a scan computes)",
    )  # fmt: skip
    tr.add_argument(
        "--near-twig-probability", type=float, default=FlowAugmentConfig.near_twig_probability,
        help="share of orchard training frames with a near twig setting the flow picture's scale",
    )  # fmt: skip
    tr.add_argument(
        "--details-as-background", action="store_true",
        help="the target leaves out the tree's spurs, stubs and buds, as real hand masks do",
    )  # fmt: skip
    tr.add_argument(
        "--nearer-negative-weight", type=float, default=TrainConfig.nearer_negative_weight,
        help="weight of the pixels of other objects in front of the tree (orchard pairs)",
    )  # fmt: skip
    tr.add_argument(
        "--nearer-negative-flow-ratio", type=float, default=NEARER_NEGATIVE_FLOW_RATIO,
        help="their flow over the tree's median flow (with --nearer-negative-weight)",
    )  # fmt: skip
    tr.add_argument(
        "--overcast-probability", type=float,
        default=OrchardAugmentConfig.overcast_probability,
        help="share of orchard training pairs under an overcast sky, the tree backlit",
    )  # fmt: skip
    tr.add_argument("--flow", action="store_true", help="RGB + optical flow input (ablation)")
    tr.add_argument(
        "--flow-picture", action="store_true",
        help="RGB + the paper's flow picture, on orchard pairs (generate-orchard data)",
    )  # fmt: skip
    tr.add_argument("--export", default=None, help="write final weights here (+ .config.json)")
    tr.add_argument("--init", default=None, help="start from these weights (fine-tuning)")
    tr.add_argument("--max-minutes", type=float, default=None, help="stop (resumably) after")

    ev = sub.add_parser("evaluate", help="IoU on unseen trees (seeds 0..trees-1), same frames")
    ev.add_argument("--weights", nargs="+", required=True, help="weights files to compare")
    ev.add_argument("--trees", type=int, default=20)
    ev.add_argument("--frames-per-tree", type=int, default=6)
    ev.add_argument("--presets", nargs="+", default=["paper", "cluttered", "hard"],
                    choices=EVAL_PRESETS)  # fmt: skip
    ev.add_argument("--world", default="clean", choices=WORLDS)
    ev.add_argument(
        "--orbit-deg", type=float, default=0.0, help="orbit about the primary first (degrees)"
    )
    ev.add_argument("--out", default=None, help="write the results as JSON")

    ep = sub.add_parser(
        "evaluate-pairs", help="IoU of flow-picture segmenters on generate-orchard pairs"
    )
    ep.add_argument("--weights", nargs="+", required=True, help="'learned' or weights files")
    ep.add_argument("--data", required=True, help="shards of generate-orchard --evaluation")
    ep.add_argument("--out", default=None, help="write the results as JSON")

    ex = sub.add_parser("export", help="export a run's newest checkpoint as weights")
    ex.add_argument("--run", required=True)
    ex.add_argument("--out", required=True)

    eo = sub.add_parser("export-onnx", help="write WEIGHTS.onnx beside each weights file")
    eo.add_argument("weights", nargs="+", help="weights files (.pt)")

    sr = sub.add_parser("score-real", help="score on real frames with hand masks (issue 15)")
    sr.add_argument("--data", required=True, help="folder of N.png, N_flow.png, N_trunk_K.png ...")
    sr.add_argument("--weights", default="learned", help="'learned', 'learned:PATH' or a PATH")
    sr.add_argument("--no-flow", action="store_true", help="RGB only: no flow picture input")
    sr.add_argument("--flow-as-stored", action="store_true",
                    help="do not exchange red and blue of the recorded flow pictures")  # fmt: skip
    sr.add_argument(
        "--size", nargs=2, type=int, metavar=("W", "H"), default=DEFAULT_SIZE,
        help="size the frames and hand masks are resized to (default: the pipeline's camera, "
        "320x240; the development frames' own: 640 480)",
    )  # fmt: skip
    sr.add_argument(
        "--rule", choices=("attached", "coverage"), default="attached",
        help="attached: the kept-aside frames' rule (the data's README.md: attached side "
        "branches, the 2D stage's samples); coverage: issue 15's rule (every side branch)",
    )  # fmt: skip
    sr.add_argument(
        "--renders", action="store_true",
        help="--data is a generate-orchard --evaluation folder: score its renders alike "
        "(labels as hand masks, the exact flow's picture)",
    )  # fmt: skip
    sr.add_argument(
        "--max-primary-turn-deg", type=float, default=Curve2DConfig.max_primary_turn_deg,
        help="the 2D stage's Curve2DConfig.max_primary_turn_deg (default inf: the paper's rule)",
    )  # fmt: skip
    sr.add_argument("--out", default=None, help="write the results as JSON")
    sr.add_argument("--figure", default=None, help="write a picture grid of the results")

    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    commands = {
        "generate": _generate,
        "generate-orchard": _generate_orchard,
        "train": _train,
        "evaluate": _evaluate,
        "evaluate-pairs": _evaluate_pairs,
        "export": _export,
        "export-onnx": _export_onnx,
        "score-real": _score_real,
    }
    commands[args.command](args)
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
