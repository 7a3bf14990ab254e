"""Figures of an evaluation: missed branches against scan time, and reconstructions per tree.

Figures are drawn on matplotlib's Agg canvas (no display, no pyplot state), so they work in worker
processes and on headless machines; the 3D panels with :mod:`recon.plot3d`, as the replay's.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (importing it registers "3d")

from branch_gym.evaluation.trials import TrialRecord
from branch_gym.policy import PolicyFactory
from branch_gym.privileged import SPEC_KIND as PRIVILEGED_KIND
from recon.metrics import MetricsConfig
from recon.plot3d import fit_view, plot_branch

TRUTH_COLOR = "0.6"
MODEL_COLOR = "red"
# Height window of the tree figures around the scanned part (m).
BELOW_SCAN_M = 0.05
ABOVE_SCAN_M = 0.10
# View from the camera's side (it looks along +y), a little from above and to the left.
VIEW_ELEVATION_DEG = 15.0
VIEW_AZIMUTH_DEG = -70.0
FIXED_MARKER = "o"
LEARNED_MARKER = "s"
PRIVILEGED_MARKER = "*"
POINT_COLORMAP = "tab20"  # 20 distinct colours: a benchmark compares up to ~17 policies


def write_figures(
    out: Path,
    summary: dict,
    records: Sequence[TrialRecord],
    plot_seeds: Sequence[int],
    factory: PolicyFactory,
) -> list[Path]:
    """Write ``missed_vs_scan_time.png`` and ``tree_<seed>.png`` for each seed to plot.

    Args:
        out: Output folder.
        summary: The evaluation summary (``report.build_summary``).
        records: All trials, policy order then seed.
        plot_seeds: Tree seeds to draw, one figure each (all policies side by side).
        factory: Reads the policy specs (which are learned, how to name them).

    Returns:
        The files written.
    """
    paths = [out / "missed_vs_scan_time.png"]
    plot_missed_vs_scan_time(summary, paths[0], factory)
    for seed in plot_seeds:
        paths.append(out / f"tree_{seed}.png")
        plot_tree([r for r in records if r.seed == seed], paths[-1])
    return paths


def plot_missed_vs_scan_time(summary: dict, path: Path, factory: PolicyFactory) -> None:
    """The Pareto plot: missed % against mean scan time, one point per policy.

    Error bars are the 95 % bootstrap intervals over trees (``missed_pct_ci``,
    ``scan_time_s_ci``; the std of the scan time where an interval is missing). Fixed schedules
    are circles, learned policies (``factory.is_learned``) squares joined by their front
    (:func:`learned_front`), privileged bounds stars; the legend names each point
    (``factory.label``).
    """
    figure = Figure(figsize=(9.0, 5.0))
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    colors = matplotlib.colormaps[POINT_COLORMAP].colors
    learned = []
    for index, (policy, entry) in enumerate(summary["policies"].items()):
        time_s, missed = entry["scan_time_s"], entry["missed_pct"]
        if time_s["mean"] is None or missed is None:
            continue
        x, y = time_s["mean"], missed
        xerr = _error_bar(x, entry.get("scan_time_s_ci"), time_s["std"] or 0.0)
        yerr = _error_bar(y, entry.get("missed_pct_ci"), 0.0)
        is_learned = factory.is_learned(policy)
        if is_learned:
            marker = LEARNED_MARKER
        elif policy.split(":")[0] == PRIVILEGED_KIND:
            marker = PRIVILEGED_MARKER
        else:
            marker = FIXED_MARKER
        axes.errorbar(
            x, y, xerr=xerr, yerr=yerr, fmt=marker, capsize=3, markersize=7,
            color=colors[index % len(colors)], label=factory.label(policy),
        )  # fmt: skip
        if is_learned:
            learned.append((x, y))
    front = learned_front(learned)
    if len(front) > 1:
        xs, ys = zip(*front, strict=True)
        axes.plot(xs, ys, "--", color="0.4", linewidth=1, label="learned front")
    if axes.get_legend_handles_labels()[0]:  # none when no policy has a scan time yet
        axes.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    axes.set_ylim(bottom=0.0)
    axes.set_xlim(left=0.0)
    axes.set_xlabel("scan time (s), mean [95 % CI over trees]")
    axes.set_ylabel("missed secondary branches (%) [95 % CI]")
    axes.set_title("Missed branches against scan time")
    axes.grid(alpha=0.3)
    figure.tight_layout()
    figure.savefig(path, dpi=120)


def learned_front(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """The non-dominated (scan time, missed) points, by scan time: each misses fewer than all
    faster ones.

    >>> learned_front([(30.0, 5.0), (20.0, 8.0), (40.0, 6.0), (50.0, 4.0)])
    [(20.0, 8.0), (30.0, 5.0), (50.0, 4.0)]
    """
    front: list[tuple[float, float]] = []
    for x, y in sorted(points):
        if not front or y < front[-1][1]:
            front.append((x, y))
    return front


def _error_bar(value: float, interval: list[float] | None, fallback: float) -> list[list[float]]:
    """Asymmetric error bar [[below], [above]] of an interval, or the symmetric fallback."""
    if interval is None:
        return [[fallback], [fallback]]
    return [[max(value - interval[0], 0.0)], [max(interval[1] - value, 0.0)]]


def plot_tree(records: Sequence[TrialRecord], path: Path) -> None:
    """One tree's reconstructions (red) over its ground truth (grey), one 3D panel per policy.

    Args:
        records: The trials of one tree seed, one per policy, in column order.
        path: PNG file to write.
    """
    if not records:
        raise ValueError("plot_tree needs at least one trial")
    top_m = max(r.metrics.scanned_top_z_m for r in records)
    # From the lowest reconstructed primary point (where the scans began), else the band's foot.
    lowest = [
        float(np.min(r.model.primary.points[:, 2]))
        for r in records
        if r.model.primary is not None and len(r.model.primary.points)
    ]
    bottom_m = min(lowest) if lowest else MetricsConfig().band_min_z_m
    z_range = (bottom_m - BELOW_SCAN_M, top_m + ABOVE_SCAN_M)
    window = (np.array([-np.inf, -np.inf, z_range[0]]), np.array([np.inf, np.inf, z_range[1]]))
    figure = Figure(figsize=(3.2 * len(records), 6.0))
    FigureCanvasAgg(figure)
    for column, record in enumerate(records, start=1):
        axes = figure.add_subplot(1, len(records), column, projection="3d")
        truth = [record.truth.primary, *record.truth.secondaries]
        model = [b for b in [record.model.primary, *record.model.secondaries] if b is not None]
        for branch in truth:
            plot_branch(axes, branch.points, window, color=TRUTH_COLOR, linewidth=3.0)
        for branch in model:
            plot_branch(axes, branch.points, window, color=MODEL_COLOR, linewidth=1.5)
        fit_view(axes, [b.points for b in truth + model], z_range)
        metrics = record.metrics
        failure = f", {record.failure}" if record.failure else ""
        axes.set_title(
            f"{record.policy}\nmatched {metrics.n_matched}/{metrics.n_gt}, "
            f"spurious {metrics.n_spurious}{failure}",
            fontsize=9,
        )
        axes.set_xlabel("x (m)", fontsize=8)
        axes.set_ylabel("y (m)", fontsize=8)
        axes.set_zlabel("z (m)", fontsize=8)
        axes.tick_params(labelsize=7)
        for axis in (axes.xaxis, axes.yaxis):
            axis.set_major_locator(MaxNLocator(3))
        axes.view_init(elev=VIEW_ELEVATION_DEG, azim=VIEW_AZIMUTH_DEG)
    figure.suptitle(f"Tree seed {records[0].seed}: reconstruction (red) over ground truth (grey)")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
