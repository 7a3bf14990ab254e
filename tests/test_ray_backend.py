"""eval.py's Ray backend: the same trials as the process pool, saved as they finish, resumable.

The Ray tests start private local Ray instances (``ray.init(address="local")``, 2 CPUs); Ray is
in the ``dev`` extra, so they run in CI. Trials use the depth-oracle tracker and end at 0.4 m
(~2 s of CPU each, one rotation for the periodic policy).
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

from agents.factory import AGENTS
from branch_gym.evaluation.config import EvalConfig
from branch_gym.evaluation.pipeline import run_evaluation
from branch_gym.evaluation.ray_backend import INSTALL_HINT, RayUnavailableError
from branch_gym.evaluation.runner import load_records, run_trials
from branch_gym.evaluation.trials import TRIALS_DIR, trial_path
from branch_gym.scan import ScanConfig

ROOT = Path(__file__).resolve().parents[1]
POLICIES = ("none", "periodic:22.5:1.5")
SCAN_ARGS = ["--tracker", "oracle", "--end-height", "0.4"]
SCAN = ScanConfig(tracker="oracle", end_height_m=0.4)
# Wall-clock measurements in a trial's row: the only fields that differ between two runs.
WALL_CLOCK_PREFIXES = ("wall_time_s", "stage_")


def _load_cli():
    """eval.py as a module (a script at the repository root)."""
    spec = importlib.util.spec_from_file_location("eval_cli_ray", ROOT / "eval.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


eval_cli = _load_cli()


def _cli(out: Path, *extra: str) -> list[str]:
    return [
        "--policies",
        *POLICIES,
        "--trees",
        "2",
        "--workers",
        "2",
        "--out",
        str(out),
        *SCAN_ARGS,
        *extra,
    ]


def _trial_files(out: Path) -> dict[str, dict]:
    """Every trial file of ``out`` as JSON, wall-clock fields removed, by relative path."""
    files = {}
    for path in sorted((out / TRIALS_DIR).rglob("*.json")):
        data = json.loads(path.read_text())
        if "row" in data:
            data["row"] = {
                k: v for k, v in data["row"].items() if not k.startswith(WALL_CLOCK_PREFIXES)
            }
        files[str(path.relative_to(out))] = data
    return files


# ----------------------------------------------------------------------------- without Ray
def test_backend_and_address_are_validated() -> None:
    with pytest.raises(ValueError, match="backend"):
        EvalConfig(POLICIES, 1, backend="dask", policy_factory=AGENTS)
    with pytest.raises(ValueError, match="ray backend"):
        EvalConfig(POLICIES, 1, address="auto", policy_factory=AGENTS)
    base = EvalConfig(POLICIES, 2, scan=SCAN, policy_factory=AGENTS)
    ray = EvalConfig(
        POLICIES, 2, scan=SCAN, backend="ray", address="auto", workers=8, policy_factory=AGENTS
    )
    # The backend, like the worker count, changes neither the results nor the folder's hash.
    assert ray.scan_hash == base.scan_hash and ray.to_json_dict() == base.to_json_dict()
    with pytest.raises(SystemExit):
        eval_cli.build_parser().parse_args(_cli(Path("x"), "--backend", "spark"))


def test_missing_ray_is_a_clear_error(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now raises ImportError
    config = EvalConfig(POLICIES, 1, scan=SCAN, backend="ray", policy_factory=AGENTS)
    with pytest.raises(RayUnavailableError, match=r"pip install '\.\[ray\]'"):
        run_trials(config, tmp_path, config.keys)
    out = tmp_path / "run"
    assert eval_cli.main(_cli(out, "--backend", "ray")) == eval_cli.EXIT_USAGE
    assert INSTALL_HINT in capsys.readouterr().err
    assert not out.exists()  # refused before anything is written


# ----------------------------------------------------------------------------- with Ray
@pytest.mark.slow
def test_ray_backend_matches_the_pool_and_resumes_its_folder(tmp_path: Path, capsys) -> None:
    pytest.importorskip("ray", reason="Ray is not installed: pip install '.[ray]'")
    from branch_gym.evaluation.ray_backend import ray_session

    pool, ray = tmp_path / "pool", tmp_path / "ray"
    assert eval_cli.main(_cli(pool)) == 0
    assert "4 trials run, 0 loaded" in capsys.readouterr().out
    assert eval_cli.main(_cli(ray, "--backend", "ray")) == 0  # a local instance of 2 CPUs
    assert "4 trials run, 0 loaded" in capsys.readouterr().out

    # 2 policies x 2 trees: the same records, outputs built from them byte for byte.
    pool_files = _trial_files(pool)
    assert len(pool_files) == 5  # 4 trials + the folder's config
    assert _trial_files(ray) == pool_files
    for name in ("summary.json", "table.md"):  # trials.csv holds the wall-clock columns
        assert (ray / name).read_bytes() == (pool / name).read_bytes(), name
    records = load_records(EvalConfig(POLICIES, 2, scan=SCAN, policy_factory=AGENTS), ray)
    assert [r.rotations for r in records] == [0, 0, 1, 1]

    # The pool's folder resumes with Ray (in a Ray session this process started: used as is).
    for key in (("none", 1), ("periodic:22.5:1.5", 0)):
        trial_path(pool, *key).unlink()
    config = EvalConfig(POLICIES, 2, workers=2, scan=SCAN, backend="ray", policy_factory=AGENTS)
    finished = []
    with ray_session(None, 2) as ray_module:
        outcome = run_evaluation(config, pool, on_done=finished.append)
        assert ray_module.is_initialized()  # not shut down by the evaluation
        # A trial that raises in a Ray worker: an error naming the trial, not Ray's wrapper.
        with pytest.raises(RuntimeError, match="'spin:3' seed 0"):
            run_trials(config, tmp_path / "bad", [("none", 0), ("spin:3", 0)])
    assert sorted(outcome.computed) == sorted(finished) == [("none", 1), ("periodic:22.5:1.5", 0)]
    assert _trial_files(pool) == pool_files
    assert (pool / "summary.json").read_bytes() == (ray / "summary.json").read_bytes()
