"""The training curve of a run: ``training_curve.png`` from its TensorBoard logs and evaluations.

Four panels against environment steps: the episode return (training episodes, and the
deterministic policy on the held-out trees), missed %, rotations per scan and scan time. Training
curves are the per-episode points that :class:`~branch_gym.training.callbacks.ScanMetricsCallback`
writes (``episode/*``), smoothed by a running mean; held-out points come from
``evaluations.jsonl``.

Usage: ``python -m branch_gym.training.curve runs/NAME`` (``train.py`` draws it at the end too).
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np

from branch_gym.training.callbacks import EPISODE_PREFIX
from branch_gym.training.paths import RunPaths

logger = logging.getLogger(__name__)

CURVE_FILE = "training_curve.png"
# Episodes averaged per plotted training point (our choice: ~a rollout of 2 envs x 256 steps).
SMOOTHING_EPISODES = 10
# (TensorBoard tag of the training episodes, evaluations.jsonl key, panel title)
_PANELS = (
    ("rollout/ep_rew_mean", "mean_reward", "episode return"),
    (EPISODE_PREFIX + "missed_pct", "missed_pct", "missed %"),
    (EPISODE_PREFIX + "rotations", "rotations", "rotations per scan"),
    (EPISODE_PREFIX + "scan_time_s", "scan_time_s", "scan time (s)"),
)


def read_scalars(tensorboard_dir: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every scalar of a run's TensorBoard logs (all sub-runs, resumed ones included).

    Returns:
        Tag -> (steps, values), sorted by step.
    """
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    points: dict[str, list[tuple[int, float]]] = {}
    folders = sorted(p for p in Path(tensorboard_dir).iterdir() if p.is_dir())
    for folder in folders:
        events = EventAccumulator(str(folder), size_guidance={"scalars": 0})
        events.Reload()
        for tag in events.Tags().get("scalars", []):
            points.setdefault(tag, []).extend((e.step, e.value) for e in events.Scalars(tag))
    scalars = {}
    for tag, pairs in points.items():
        pairs.sort()
        scalars[tag] = (np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]))
    return scalars


def plot_training_curve(run: str | Path) -> Path:
    """Draw ``training_curve.png`` in the run folder.

    Raises:
        FileNotFoundError: the folder holds no TensorBoard logs (not a run folder).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = RunPaths(Path(run))
    if not paths.tensorboard.is_dir():
        raise FileNotFoundError(f"{paths.out} holds no TensorBoard logs ({paths.tensorboard})")
    scalars = read_scalars(paths.tensorboard)
    evaluations = []
    if paths.evaluations.is_file():
        evaluations = [json.loads(line) for line in paths.evaluations.read_text().splitlines()]
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True)
    for ax, (tag, key, title) in zip(axes.flat, _PANELS, strict=True):
        if tag in scalars:
            steps, values = scalars[tag]
            smooth = tag.startswith(EPISODE_PREFIX)
            ax.plot(steps, _running_mean(values) if smooth else values, label="training episodes")
        held_out = [(e["num_timesteps"], e[key]) for e in evaluations if e.get(key) is not None]
        if held_out:
            ax.plot(*zip(*held_out, strict=True), "o-", label="held-out trees (deterministic)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("environment steps")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"PPO training: {paths.out.name}")
    fig.tight_layout()
    path = paths.out / CURVE_FILE
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _running_mean(values: np.ndarray) -> np.ndarray:
    window = min(SMOOTHING_EPISODES, len(values))
    kernel = np.ones(window) / window
    head = np.cumsum(values[: window - 1]) / np.arange(1, window)  # shorter windows at the start
    return np.concatenate([head, np.convolve(values, kernel, mode="valid")])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("run", type=Path, help="run folder (train.py --out)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    print(plot_training_curve(args.run))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
