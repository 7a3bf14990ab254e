"""Why does a turn lose? Replay a kept run's round-0 cost-to-go branches and show their ends.

Round 0 of a cost-to-go run rolls every branch out with
:class:`~branch_gym.training.imitation.cost_to_go.HoldAgent` (no student yet), so its branches
replay exactly from the kept labels: the episode's actions are read back from the recorded
observations (``VectorField.PREVIOUS_ACTION``), the replay is checked against the recorded
observation at the sampled step, and each branch is played to its end. For every branch whose
turn lost more than ``LOSS_MARGIN`` branch against holding, this prints both ends: the return
(checked against ``branches.jsonl``), the failure, matched, spurious and duplicate branches, scan
time.

    python research/cost_to_go_replay.py runs/aggrevate_orchard --cases 12   # a cost-to-go run
"""

from __future__ import annotations

import argparse
import json
from itertools import pairwise
from pathlib import Path

import gymnasium as gym
import numpy as np

import branch_gym  # noqa: F401  (registers the env ids)
from branch_gym.env.layout import DISCRETE_ANGLES_DEG, VECTOR_KEY, VectorField
from branch_gym.training.imitation.config import CONFIG_FILE, ImitationConfig
from branch_gym.training.imitation.cost_to_go import (
    BranchTask,
    HoldAgent,
    branch_outcome,
    play_branch,
)
from branch_gym.training.imitation.data import (
    RoundData,
    branch_log_path,
    episode_slices,
    round_path,
)

LOSS_MARGIN = 0.5  # our choice: half a found branch, as research/cost_to_go_labels.py
RETURN_TOLERANCE = 1e-6  # a replay reproduces the logged return to float rounding


def losing_branches(run: Path, config: ImitationConfig) -> list[dict]:
    """Round 0's branches whose turn lost more than ``LOSS_MARGIN`` against holding."""
    data = RoundData.load(round_path(run, 0))
    logged = {}
    log = branch_log_path(run, 0)  # runs from 2026-12-05; the v2-v5 records: one branches.jsonl
    for line in (log if log.exists() else run / "branches.jsonl").read_text().splitlines():
        row = json.loads(line)
        logged[(row["tree_seed"], row["step"], row["action"])] = row["return"]
    cases = []
    for episode, part in enumerate(episode_slices(data)):
        seed = config.tree_seed(0, episode)
        vectors = data.observations[VECTOR_KEY][part]
        targets = np.round(vectors[:, VectorField.PREVIOUS_ACTION] * DISCRETE_ANGLES_DEG[-1], 1)
        # A step whose target did not change held (action 0): the expert holds at its angle, and
        # "go to the angle it is at" is not the same action where the rotation left it a little
        # short of its target.
        actions = [
            0 if angle == before else 1 + DISCRETE_ANGLES_DEG.index(float(angle))
            for before, angle in pairwise(targets)
        ]
        for (tree, step, action), value in sorted(logged.items()):
            held = logged.get((tree, step, 0))
            if tree != seed or action == 0 or held is None or value >= held - LOSS_MARGIN:
                continue
            cases.append(
                {"seed": seed, "step": step, "action": action, "prefix": actions[:step],
                 "expected": vectors[step], "hold_return": held, "turn_return": value}
            )  # fmt: skip
    return cases


def play(env: gym.Env, agent: HoldAgent, case: dict, action: int) -> dict:
    """One branch to its end (:func:`play_branch`): return, failure, matched, spurious and
    duplicate branches, scan time."""
    task = BranchTask(case["seed"], tuple(case["prefix"]), case["expected"], action, None)
    outcome = branch_outcome(*play_branch(env, task, agent))
    return {
        "return": outcome["return"],
        "failure": outcome["failure"] or "-",
        "matched": outcome["n_matched"],
        "spurious": outcome["n_spurious"],
        "duplicates": outcome["n_duplicates"],
        "scan_time_s": outcome["scan_time_s"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a cost-to-go run folder (or kept record)")
    parser.add_argument("--cases", type=int, default=12, help="losing branches to replay")
    args = parser.parse_args()
    config = ImitationConfig.from_dict(json.loads((args.run / CONFIG_FILE).read_text()))
    cases = losing_branches(args.run, config)
    print(f"{len(cases)} round-0 branches lost more than {LOSS_MARGIN} branch to holding\n")
    print("Each end: return / failure / matched / spurious / duplicates / scan time s\n")
    print("| tree | step | turn to | holding | turning |")
    print("|---|---|---|---|---|")
    env = gym.make(config.train.env_id, **config.train.env_kwargs())
    agent = HoldAgent.for_env(env)
    try:
        for case in cases[: args.cases]:
            ends = [play(env, agent, case, action) for action in (0, case["action"])]
            for end, logged in zip(ends, (case["hold_return"], case["turn_return"]), strict=True):
                if abs(end["return"] - logged) > RETURN_TOLERANCE:
                    raise RuntimeError(f"tree {case['seed']}: return {end['return']} != {logged}")
            cells = [
                f"{e['return']:+.2f} / {e['failure']} / {e['matched']} / {e['spurious']} / "
                f"{e['duplicates']} / {e['scan_time_s']:.1f}"
                for e in ends
            ]
            angle = DISCRETE_ANGLES_DEG[case["action"] - 1]
            print(f"| {case['seed']} | {case['step']} | {angle:+g} deg | {cells[0]} | {cells[1]} |")
    finally:
        env.close()


if __name__ == "__main__":
    main()
