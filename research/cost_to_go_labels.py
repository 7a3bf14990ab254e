"""What a cost-to-go run's labels say: each action's return against holding, at the priced states.

A cost-to-go run (``python -m branch_gym.training.imitation --cost-to-go-states K``) prices K
sampled states of every episode by taking each distinct action once and rolling the episode out
to its end (``branch_gym/training/imitation/cost_to_go.py``). This study reads the labels a run
kept (``round_K.npz``) and prints, per action, its advantage over holding (the return of the
action minus that of action 0, in found branches at the episode's price of scan time): mean,
median, and the shares of states where it gains or loses more than half a branch; then the same
for the expert's own action where the expert rotates.

    python research/cost_to_go_labels.py runs/aggrevate_orchard     # configs/aggrevate_orchard.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from branch_gym.env.config import DISCRETE_ANGLES_DEG
from branch_gym.env.versions import env_version
from branch_gym.training.imitation.config import CONFIG_FILE, ImitationConfig
from branch_gym.training.imitation.data import RoundData

# Our choice: half a found branch separates a gain or a loss from the price of the turn itself.
CLEAR_MARGIN = 0.5


def summarise(data: RoundData) -> dict[str, object]:
    """Per-action advantages over holding at the priced states of ``data``."""
    priced = data.priced()
    if len(priced) == 0:
        raise ValueError("these labels hold no priced states (a run without cost-to-go)")
    values = data.action_values[priced]
    advantage = values - values[:, :1]
    expert = data.expert_actions[priced]
    rotates = expert != 0
    best_rotation = advantage[:, 1:].max(axis=1)
    return {
        "priced_states": len(priced),
        "mean": advantage.mean(axis=0),
        "median": np.median(advantage, axis=0),
        "gains": (advantage > CLEAR_MARGIN).mean(axis=0),
        "losses": (advantage < -CLEAR_MARGIN).mean(axis=0),
        "best_rotation_gains": float((best_rotation > CLEAR_MARGIN).mean()),
        "expert_rotations": int(rotates.sum()),
        "expert_rotation_advantage": advantage[rotates, expert[rotates]],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a run folder (or record) with round_K.npz")
    args = parser.parse_args()
    config = ImitationConfig.from_dict(json.loads((args.run / CONFIG_FILE).read_text()))
    rounds = sorted(int(p.stem.split("_")[1]) for p in args.run.glob("round_*.npz"))
    data = RoundData.load_rounds(args.run, rounds)
    if env_version(config.train.env_id).action_type != "discrete_hold":
        raise ValueError(f"{config.train.env_id}: expected a discrete id with a hold action")
    names = ["hold"] + [f"{angle:+g} deg" for angle in DISCRETE_ANGLES_DEG]
    s = summarise(data)
    print(f"{args.run}: {s['priced_states']} priced states, rounds {rounds}\n")
    print("| action | mean advantage | median | gains > 0.5 | loses > 0.5 |")
    print("|---|---|---|---|---|")
    for k, name in enumerate(names[1:], start=1):
        print(
            f"| {name} | {s['mean'][k]:+.2f} | {s['median'][k]:+.2f} | "
            f"{100 * s['gains'][k]:.0f} % | {100 * s['losses'][k]:.0f} % |"
        )
    print(
        f"\nSome rotation gains more than {CLEAR_MARGIN} branch over holding in "
        f"{100 * s['best_rotation_gains']:.0f} % of the priced states."
    )
    expert = s["expert_rotation_advantage"]
    if len(expert):
        clear = 100 * np.mean(abs(expert) > CLEAR_MARGIN)
        print(
            f"Where the expert rotates ({s['expert_rotations']} states), its action's advantage: "
            f"mean {expert.mean():+.2f}, from {expert.min():+.2f} to {expert.max():+.2f}, "
            f"more than {CLEAR_MARGIN} either way in {clear:.0f} % of them."
        )


if __name__ == "__main__":
    main()
