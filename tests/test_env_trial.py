"""One evaluation trial: the agent of a policy spec plays one episode (the one episode loop)."""

from __future__ import annotations

import pytest

from agents.baselines import PeriodicAgent
from agents.factory import AGENTS
from branch_gym.evaluation.episodes import run_scan, run_trial
from branch_gym.scan import ScanConfig

SHORT = ScanConfig(end_height_m=0.42)


@pytest.mark.slow
def test_a_trial_from_a_spec_equals_a_scan_with_the_agent() -> None:
    via_spec = run_trial(4, "periodic:22.5:2.5", SHORT, AGENTS).to_row()
    via_agent = run_scan(4, PeriodicAgent(22.5, 2.5), SHORT, policy="periodic:22.5:2.5").to_row()
    assert via_spec["rotations"] >= 1
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
        assert via_spec[key] == via_agent[key], key
    assert via_spec["policy"] == via_agent["policy"] == "periodic:22.5:2.5"


@pytest.mark.parametrize("spec", ["spin:3", "periodic:x:1", "none:1", ""])
def test_unknown_policy_spec_raises_naming_the_forms(spec: str) -> None:
    with pytest.raises(ValueError, match="periodic:ANGLE_DEG:FREQ"):
        run_trial(0, spec, SHORT, AGENTS)
