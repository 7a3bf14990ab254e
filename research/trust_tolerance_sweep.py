"""Replay recorded scans with changed modeler settings and pool their scores.

The study behind ``ModelerConfig.secondary_trust_tolerance_px``: record scans once with
``eval.py --record DIR``, then replay every recording with the masks it recorded (the
segmenter's output of the live run) under each setting. For schedules that do not read the
model (none, periodic) the camera path does not depend on the modeler, so the replay equals the
live scan with that setting.

    python research/trust_tolerance_sweep.py /root/trust/pxrec/periodic_22.5_1.5 \
        --set secondary_trust_tolerance_px=0 secondary_trust_tolerance_px=4
"""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import replace
from pathlib import Path

from recon.config import ModelerConfig, modeler_overrides
from recon.replay import modeler_settings, replay


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy_folder", type=Path, help="DIR/POLICY of eval.py --record DIR")
    parser.add_argument("--set", nargs="+", default=[""], help="settings, KEY=JSON[,KEY=JSON]")
    args = parser.parse_args()
    folders = sorted(p for p in args.policy_folder.iterdir() if (p / "camera.json").exists())
    for text in args.set:
        overrides = modeler_overrides([item for item in text.split(",") if item])
        totals = {"n_gt": 0, "n_missed": 0, "n_spurious": 0, "n_duplicates": 0, "n_matched": 0}
        per_tree = []
        for folder in folders:
            metadata = json.loads((folder / "metadata.json").read_text())
            seed, config = modeler_settings(metadata, None, None)
            config = replace(config or ModelerConfig(), **overrides)
            with tempfile.TemporaryDirectory() as out:
                result = replay(
                    folder,
                    Path(out) / "replay",
                    truth=folder / "truth.json",
                    segmenter="mask",
                    seed=seed,
                    modeler_config=config,
                    progress=False,
                )
            m = result.metrics
            for key in totals:
                totals[key] += getattr(m, key)
            per_tree.append(m.n_missed)
        pct = {key: 100 * value / max(totals["n_gt"], 1) for key, value in totals.items()}
        print(
            f"{text or 'recorded'}: {len(folders)} scans, missed {pct['n_missed']:.1f} % "
            f"({totals['n_missed']}/{totals['n_gt']}), spurious {pct['n_spurious']:.1f} %, "
            f"duplicates {pct['n_duplicates']:.1f} %; missed per scan {per_tree}",
            flush=True,
        )


if __name__ == "__main__":
    main()
