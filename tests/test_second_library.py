"""A second RL implementation besides stable-baselines3 trains on the env: examples/torch_ppo.py.

The run happens in a fresh interpreter so that the test can check that nothing imported
stable-baselines3 along the way (the env depends on gymnasium only).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# A short run: 2 envs x 32 steps x 2 updates = 128 env steps of ~0.1 s (the oracle's fast mode,
# scans ending at 0.35 m after ~7 steps, small exploratory rotations), then 2 epochs of 2
# minibatches: ~15 s in all.
SCRIPT = """
import json, importlib.util, sys
import torch
spec = importlib.util.spec_from_file_location("torch_ppo", sys.argv[1])
ppo = importlib.util.module_from_spec(spec)
sys.modules["torch_ppo"] = ppo  # dataclasses resolve their module by name
spec.loader.exec_module(ppo)
config = ppo.PPOConfig(
    env_kwargs={"tracker": "oracle", "end_height_m": 0.35, "render_tracking_frames": False},
    num_envs=2, steps_per_env=32, updates=2, epochs=2, minibatch_size=32,
    init_log_std=-2.0, seed=0,
)
envs = ppo.make_envs(config)
model = ppo.ActorCritic.for_env(envs, config)
envs.close()
before = {k: v.clone() for k, v in model.state_dict().items()}
model, history = ppo.train(config, model=model)
changed = sorted(k for k, v in model.state_dict().items() if not torch.equal(v, before[k]))
print(json.dumps({
    "history": [s.__dict__ for s in history],
    "changed": changed,
    "parameters": sorted(before),
    "sb3_imported": any(m.startswith("stable_baselines3") for m in sys.modules),
}))
"""


@pytest.mark.slow
def test_torch_ppo_trains_with_finite_losses_without_sb3() -> None:
    run = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(ROOT / "examples" / "torch_ppo.py")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(run.stdout.strip().splitlines()[-1])
    assert not result["sb3_imported"]
    history = result["history"]
    assert [s["update"] for s in history] == [1, 2]
    assert [s["env_steps"] for s in history] == [64, 128]
    for stats in history:
        for key in ("policy_loss", "value_loss", "entropy", "approx_kl"):
            assert math.isfinite(stats[key]), (key, stats)
        assert stats["value_loss"] > 0.0
    assert sum(s["episodes"] for s in history) >= 2  # ~7-step episodes: several ended
    # Every tensor of actor, critic and the action std was updated.
    assert result["changed"] == result["parameters"]
