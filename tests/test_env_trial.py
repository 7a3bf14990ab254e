"""eval.py's trials run through the Gymnasium env give the numbers of the plain scan loop."""

from __future__ import annotations

import pytest

from branch_gym.evaluation.env_trial import run_scan_in_env
from branch_gym.scan import ScanConfig, run_scan

SHORT = ScanConfig(end_height_m=0.42)


@pytest.mark.slow
@pytest.mark.parametrize("policy", ["none", "periodic:22.5:2.5"])
def test_env_trial_equals_run_scan(policy: str) -> None:
    via_env = run_scan_in_env(4, policy, SHORT).to_row()
    direct = run_scan(4, policy, SHORT).to_row()
    for key in (
        "scan_time_s",
        "rotations",
        "n_iterations",
        "stop_reason",
        "n_matched",
        "n_spurious",
        "pb_residual_mean_m",
        "pb_radius_rmse_m",
    ):
        assert via_env[key] == direct[key], key
    assert via_env["policy"] == direct["policy"] == policy


def test_unknown_policy_spec_raises() -> None:
    with pytest.raises(ValueError, match="rotation policy spec"):
        run_scan_in_env(0, "spin:3", SHORT)
