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

The cost of a turn against a branch's value falls with the price of scan time, and so does the
Bayes threshold: ``--top-price-shift S1`` makes the shift a function of the observed price,
``s(p) = s0 + (S1 - s0) p`` with ``s0`` the ``--hold-logit-shift`` and ``p`` the env's price
feature (0 at the lowest price, 1 at the highest, linear in its logarithm:
``branch_gym.env.layout.price_feature``). One network then answers every price with its own
threshold: :func:`add_price_slope` widens the policy's MLP by one unit that carries ``p`` to the
action layer (module notes there), so that the file stays an ordinary SB3 model.

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

import numpy as np

from agents.ppo import resolve_model_path
from branch_gym.env.layout import DISCRETE_ANGLES_DEG, PRICE_KEY
from branch_gym.env.versions import env_version
from branch_gym.files import write_json_atomic
from branch_gym.training.model_files import load_model, model_env_id
from branch_gym.training.train import apply_first_action_logit

CALIBRATION_SUFFIX = ".calibration.json"


def calibration_path(model_path: str | Path) -> Path:
    """The provenance file of a calibrated model: ``MODEL.calibration.json`` beside it."""
    model_path = Path(model_path)
    return model_path.with_name(model_path.stem + CALIBRATION_SUFFIX)


def shift_hold_logit(
    source: str | Path,
    shift: float,
    out: str | Path,
    return_too: bool = False,
    top_price_shift: float | None = None,
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
        top_price_shift: The shift at the top of the price range; ``shift`` is then the one at
            its bottom and the shift between follows the price feature (module docstring).
            None: ``shift`` at every price.

    Returns:
        ``out``.

    Raises:
        FileNotFoundError: ``source`` does not exist.
        branch_gym.training.model_files.ModelFileError: ``source`` is not a readable model.
        ValueError: a non-finite shift, a continuous-action model, or ``out`` equal to
            ``source``; with ``top_price_shift``, a model without the price input.
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
    if top_price_shift is not None:
        add_price_slope(model, top_price_shift - shift, return_too)
    out.parent.mkdir(parents=True, exist_ok=True)
    model.save(out)
    provenance = {"source_model": str(source), "hold_logit_shift": float(shift)}
    if return_too:
        provenance["return_logit_shift"] = float(shift)
    if top_price_shift is not None:
        provenance["top_price_shift"] = float(top_price_shift)
    write_json_atomic(calibration_path(out), provenance)
    return out


def _shift_return_logit(model: Any, shift: float) -> None:
    """Add ``shift`` to the logit of a ``discrete_hold`` model's turn back to 0 degrees."""
    import torch

    with torch.no_grad():
        model.policy.action_net.bias[_return_action(model)] += shift


# The carrying unit passes gain * p through tanh once per layer; tanh(tanh(x)) = x (1 - 2 x^2 / 3
# + ...), so at this gain the added logit is off by under 1e-6 of the slope (ours).
_PASS_THROUGH_GAIN = 1e-3


def add_price_slope(model: Any, slope: float, return_too: bool = False) -> None:
    """Add ``slope * p`` to the hold logit (and the turn back to 0 with ``return_too``), in place.

    ``p`` is the observation's price feature. The policy's MLP (``mlp_extractor.policy_net``:
    Linear, activation, ..., Linear, activation) gains one unit per layer: the first layer's
    reads ``gain * p`` and each later one its predecessor alone (weight 1), so it carries
    ``tanh(...tanh(gain * p))``, which equals ``gain * p`` to ~1e-9; ``action_net`` reads it
    with weight ``slope / gain`` on the shifted rows. Every other weight is copied, so every
    other logit, and the value, are unchanged. The model's ``policy_kwargs`` get the widened
    ``net_arch``, so that ``PPO.load`` rebuilds it.

    Args:
        model: A loaded discrete-action SB3 PPO whose observation holds the price
            (``branch_gym.env.layout.PRICE_KEY``) and whose MLP activation is Tanh.
        slope: Logits added at the top price (p = 1); finite.
        return_too: Shift the turn back to 0 degrees as well (a ``discrete_hold`` model).

    Raises:
        ValueError: A non-finite slope, no price in the observation, or another MLP.
    """
    import torch
    from torch import nn

    if not math.isfinite(slope):
        raise ValueError(f"the price slope must be finite, got {slope}")
    policy = model.policy
    price_index = _price_feature_index(policy)
    linears = _policy_linears(policy)
    activations = [m for m in policy.mlp_extractor.policy_net if not isinstance(m, nn.Linear)]
    if not linears or any(not isinstance(m, nn.Tanh) for m in activations):
        raise ValueError("a price slope needs a policy MLP of Linear and Tanh layers")
    kwargs = dict(model.policy_kwargs)
    value_sizes = [
        m.out_features for m in policy.mlp_extractor.value_net if isinstance(m, nn.Linear)
    ]
    kwargs["net_arch"] = {"pi": [m.out_features + 1 for m in linears], "vf": value_sizes}
    widened = type(policy)(model.observation_space, model.action_space, model.lr_schedule, **kwargs)
    widened.to(policy.device)
    old, new = policy.state_dict(), widened.state_dict()
    rows = [0]
    if return_too:
        rows.append(_return_action(model))
    with torch.no_grad():
        for name, tensor in new.items():
            source = old[name]
            if tensor.shape == source.shape:
                tensor.copy_(source)
                continue
            tensor.zero_()  # the widened layers: the old block, then the carrying unit
            tensor[tuple(slice(0, n) for n in source.shape)] = source
        for k, layer in enumerate(_policy_linears(widened)):
            if k == 0:
                layer.weight[-1, price_index] = _PASS_THROUGH_GAIN
            else:
                layer.weight[-1, -1] = 1.0
        for row in rows:
            widened.action_net.weight[row, -1] = slope / _PASS_THROUGH_GAIN
    widened.set_training_mode(False)
    model.policy = widened
    model.policy_kwargs = kwargs


def _policy_linears(policy: Any) -> list[Any]:
    """The Linear layers of a policy's actor MLP, in order."""
    from torch import nn

    return [m for m in policy.mlp_extractor.policy_net if isinstance(m, nn.Linear)]


def _price_feature_index(policy: Any) -> int:
    """Where the price sits in the policy's features (the one feature that moves with it)."""
    import torch
    from gymnasium import spaces

    space = policy.observation_space
    if not isinstance(space, spaces.Dict) or PRICE_KEY not in space.spaces:
        raise ValueError(f"a price slope needs a {PRICE_KEY!r} entry in the observation")
    extractor = getattr(policy, "pi_features_extractor", policy.features_extractor)
    observation = {
        key: torch.zeros((1, *part.shape), dtype=torch.float32, device=policy.device)
        for key, part in space.spaces.items()
    }
    with torch.no_grad():
        low = policy.extract_features(observation, extractor).cpu().numpy()[0]
        observation[PRICE_KEY] = torch.ones_like(observation[PRICE_KEY])
        high = policy.extract_features(observation, extractor).cpu().numpy()[0]
    moved = np.flatnonzero(low != high)
    if len(moved) != 1:
        raise ValueError(f"the price should move one policy feature, it moves {len(moved)}")
    return int(moved[0])


def _return_action(model: Any) -> int:
    """The action index of a ``discrete_hold`` model's turn back to 0 degrees."""
    env_id = model_env_id(model)
    kwargs = env_version(env_id).env_kwargs() if env_id else {}
    if kwargs.get("action_type") != "discrete_hold":
        raise ValueError(f"a return-logit shift needs a discrete_hold model, not {env_id!r}")
    angles = list(kwargs.get("discrete_angles_deg", DISCRETE_ANGLES_DEG))
    return 1 + angles.index(0.0)


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
    parser.add_argument(
        "--top-price-shift",
        type=float,
        help="the shift at the highest price (--hold-logit-shift: at the lowest), linear in "
        "the price feature between them",
    )
    args = parser.parse_args(argv)
    try:
        written = shift_hold_logit(
            args.model, args.hold_logit_shift, args.out, args.return_too, args.top_price_shift
        )
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {written}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
