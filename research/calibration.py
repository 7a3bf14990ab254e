"""Decision thresholds of a discrete student: one classifier, several prices of scan time.

(A study: ``python -m research.calibration``; the shipped ``ppo_dagger_v2_shift1`` is
``ppo_dagger_v2`` with ``--hold-logit-shift 1``, its card in ``agents/models/``.)

A DAgger student (:mod:`branch_gym.training.imitation`) is a classifier of the expert's action:
its logits estimate how likely the privileged expert is to rotate, and to where, in the states it
sees. Acting by argmax is the decision of equal costs for every mistake; where a missed branch is
dearer than the seconds a rotation takes, the Bayes decision rotates on weaker evidence, and where
it is cheaper, on stronger. For a softmax policy that decision is a shift of the "hold" logit
(action 0): with the shift ``s`` the policy holds only while ``P(hold) >= exp(-s) * P(k)`` for
every rotation ``k``; ``s < 0`` rotates more readily, ``s > 0`` less.

:func:`shift_hold_logit` writes such a copy of a model (the bias of ``policy.action_net``, the
same place ``train.py --first-action-logit`` sets it); the file is an ordinary SB3 model that
``eval.py --policies ppo:PATH`` plays. The shift is recorded beside it in ``PATH.calibration.json``
with the source model. ``--return-too`` shifts the turn back to 0 degrees with "hold": a student
that returns to the home view once nothing is pending then leaves it less readily but comes back
as readily (a hold shift alone would keep it turned, hiding what the home view shows). Pick
shifts on validation trees (never the benchmark trees), e.g. with ``python -m research.selection``.

Usage::

    python -m research.calibration runs/dagger_v2/model_round_9.zip \\
        --hold-logit-shift -1.0 --out runs/ppo_dagger_v2_eager.zip
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from agents.ppo import load_model, model_env_id, resolve_model_path
from branch_gym.env.layout import DISCRETE_ANGLES_DEG
from branch_gym.env.versions import env_version
from branch_gym.files import write_json_atomic
from branch_gym.training.train import apply_first_action_logit

CALIBRATION_SUFFIX = ".calibration.json"


def calibration_path(model_path: str | Path) -> Path:
    """The provenance file of a calibrated model: ``MODEL.calibration.json`` beside it."""
    model_path = Path(model_path)
    return model_path.with_name(model_path.stem + CALIBRATION_SUFFIX)


def shift_hold_logit(
    source: str | Path, shift: float, out: str | Path, return_too: bool = False
) -> Path:
    """Copy a discrete-action model with ``shift`` added to its "hold" (action 0) logit.

    Args:
        source: The model file (a discrete-action PPO; e.g. a DAgger student).
        shift: Added to the logit of action 0 (negative: rotate more readily).
        out: The new model file (``.zip``); its provenance goes beside it.
        return_too: Add it to the logit of the turn back to 0 degrees as well (a
            ``discrete_hold`` model), so that the shift makes leaving the home view rarer but not
            coming back to it: a student that turns back once nothing is pending (the
            ``privileged:home`` expert's habit) would otherwise stay turned.

    Returns:
        ``out``.

    Raises:
        FileNotFoundError: ``source`` does not exist.
        agents.ppo.ModelFileError: ``source`` is not a readable model.
        ValueError: a non-finite shift, a continuous-action model, or ``out`` equal to
            ``source``.
    """
    if not math.isfinite(shift):
        raise ValueError(f"the hold-logit shift must be finite, got {shift}")
    source, out = resolve_model_path(source), Path(out)
    if source.resolve() == out.resolve():
        raise ValueError(f"--out must differ from the source model {source}")
    model = load_model(source)
    if not hasattr(model.action_space, "n"):
        raise ValueError(f"{source} has a {type(model.action_space).__name__} action space: "
                         "a hold-logit shift needs a discrete one")  # fmt: skip
    apply_first_action_logit(model, shift)
    if return_too:
        _shift_return_logit(model, shift)
    out.parent.mkdir(parents=True, exist_ok=True)
    model.save(out)
    provenance = {"source_model": str(source), "hold_logit_shift": float(shift)}
    if return_too:
        provenance["return_logit_shift"] = float(shift)
    write_json_atomic(calibration_path(out), provenance)
    return out


def _shift_return_logit(model: Any, shift: float) -> None:
    """Add ``shift`` to the logit of a ``discrete_hold`` model's turn back to 0 degrees."""
    import torch

    env_id = model_env_id(model)
    kwargs = env_version(env_id).env_kwargs() if env_id else {}
    if kwargs.get("action_type") != "discrete_hold":
        raise ValueError(f"a return-logit shift needs a discrete_hold model, not {env_id!r}")
    angles = list(kwargs.get("discrete_angles_deg", DISCRETE_ANGLES_DEG))
    with torch.no_grad():
        model.policy.action_net.bias[1 + angles.index(0.0)] += shift


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("model", type=Path, help="a discrete-action model file (.zip)")
    parser.add_argument("--hold-logit-shift", type=float, required=True)
    parser.add_argument("--out", type=Path, required=True, help="the calibrated model (.zip)")
    parser.add_argument(
        "--return-too",
        action="store_true",
        help="shift the turn back to 0 degrees as well (only leaving home gets rarer)",
    )
    args = parser.parse_args(argv)
    try:
        written = shift_hold_logit(args.model, args.hold_logit_shift, args.out, args.return_too)
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {written}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
