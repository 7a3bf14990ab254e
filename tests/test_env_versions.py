"""The env ids as data (branch_gym/env/versions.py): registration, docs, models' recorded ids."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import gymnasium
import pytest

import branch_gym
from agents.factory import make_agent, spec_env_kwargs
from agents.ppo import resolve_model_path, shipped_models
from branch_gym.env import BranchScanEnv
from branch_gym.env.versions import (
    ENV_VERSIONS,
    env_version,
    markdown_table,
    version_history,
)
from branch_gym.training.model_files import (
    ENV_ID_ATTRIBUTE,
    ModelFileError,
    env_id_of_spaces,
    load_model,
    saved_env_id,
    version_spaces,
)

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = {
    "ppo_ctg_orchard": "BranchScanDiscrete-v2",
    "ppo_dagger": "BranchScanDiscrete-v1",
    "ppo_dagger_priced": "BranchScanDiscrete-v1",
    "ppo_dagger_v2": "BranchScanDiscrete-v2",
    "ppo_dagger_v2_shift1": "BranchScanDiscrete-v2",
}


def test_every_row_is_registered_with_its_kwargs_and_ids_are_unique() -> None:
    assert branch_gym.ENV_IDS == tuple(v.env_id for v in ENV_VERSIONS)
    assert len(set(branch_gym.ENV_IDS)) == len(ENV_VERSIONS)
    for version in ENV_VERSIONS:
        spec = gymnasium.spec(version.env_id)
        assert spec.kwargs == version.env_kwargs()
        assert spec.max_episode_steps == branch_gym.MAX_EPISODE_STEPS
    with pytest.raises(ValueError, match="unknown env id 'BranchScan-v9'"):
        env_version("BranchScan-v9")


def test_retired_ids_stay_registered_and_each_name_has_one_current_version() -> None:
    current = [v for v in ENV_VERSIONS if not v.retired]
    assert len({v.name for v in current}) == len(current) == len({v.name for v in ENV_VERSIONS})
    assert {v.env_id for v in current} >= {"BranchScan-v3", "BranchScanDiscrete-v3"}
    assert env_version("BranchScan-v0").retired and env_version("BranchScanDiscrete-v2").retired


@pytest.mark.parametrize("version", ENV_VERSIONS, ids=lambda v: v.env_id)
def test_the_env_of_a_row_has_the_spaces_models_are_matched_against(version) -> None:
    env = BranchScanEnv(**version.env_kwargs())
    try:
        assert (env.observation_space, env.action_space) == version_spaces(version)
    finally:
        env.close()
    # A file without a recorded id gets the oldest id of its spaces (v3 changed only the reward).
    oldest = next(v for v in ENV_VERSIONS if version_spaces(v) == version_spaces(version))
    assert env_id_of_spaces(*version_spaces(version)) == oldest.env_id
    assert version.paper_scoring or oldest.version < version.version


def test_the_docs_show_the_table_and_the_version_history() -> None:
    docs = (ROOT / "docs" / "env.md").read_text()
    assert markdown_table() in docs, "docs/env.md: paste markdown_table()\n" + markdown_table()
    assert version_history() in docs, "docs/env.md: paste version_history()\n" + version_history()


def test_shipped_models_are_found_by_name_and_record_their_env() -> None:
    assert set(shipped_models()) == set(SHIPPED)
    for name, env_id in SHIPPED.items():
        path = resolve_model_path(name)
        assert path == resolve_model_path(f"models/{name}.zip")  # the former place
        assert saved_env_id(path) == env_id
        assert (path.parent / f"{name}.md").is_file()  # its card
        assert spec_env_kwargs(f"ppo:{name}@100") == env_version(env_id).env_kwargs()
    with pytest.raises(FileNotFoundError, match="shipped models: ppo_ctg_orchard, ppo_dagger"):
        resolve_model_path("no_such_model")


def _without_env_id(source: Path, target: Path, env_id: str | None = None) -> Path:
    """A copy of a model file as saved before ids were recorded (or recording ``env_id``)."""
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(target, "w") as dst:
        for info in src.infolist():
            payload = src.read(info.filename)
            if info.filename == "data":
                data = json.loads(payload)
                data.pop(ENV_ID_ATTRIBUTE)
                if env_id is not None:
                    data[ENV_ID_ATTRIBUTE] = env_id
                payload = json.dumps(data).encode()
            dst.writestr(info, payload)
    return target


def test_an_old_model_file_gets_the_id_of_its_spaces_and_a_new_save_records_it(tmp_path) -> None:
    old = _without_env_id(resolve_model_path("ppo_dagger_v2"), tmp_path / "old.zip")
    assert saved_env_id(old) is None
    model = load_model(old)
    assert getattr(model, ENV_ID_ATTRIBUTE) == "BranchScanDiscrete-v2"
    assert spec_env_kwargs(f"ppo:{old}") == env_version("BranchScanDiscrete-v2").env_kwargs()
    model.save(tmp_path / "resaved.zip")
    assert saved_env_id(tmp_path / "resaved.zip") == "BranchScanDiscrete-v2"


def test_a_model_recording_another_env_than_its_spaces_is_refused(tmp_path) -> None:
    source = resolve_model_path("ppo_dagger_v2")
    wrong = _without_env_id(source, tmp_path / "wrong.zip", env_id="BranchScanDiscrete-v1")
    with pytest.raises(ModelFileError, match="records env 'BranchScanDiscrete-v1'"):
        load_model(wrong)
    unknown = _without_env_id(source, tmp_path / "unknown.zip", env_id="BranchScan-v9")
    with pytest.raises(ModelFileError, match="unknown env id"):
        load_model(unknown)


def test_a_model_in_the_env_of_another_id_is_refused_naming_both_ids() -> None:
    env = gymnasium.make("BranchScanDiscrete-v1")
    try:
        with pytest.raises(ValueError, match="trained on BranchScanDiscrete-v2, the env is "):
            make_agent("ppo:ppo_dagger_v2", env)
    finally:
        env.close()


def test_a_run_starts_from_a_model_of_an_id_that_differs_only_in_its_reward() -> None:
    from branch_gym.env.versions import same_spaces
    from branch_gym.training.train import load_policy_weights

    assert same_spaces("BranchScanDiscrete-v2", "BranchScanDiscrete-v3")  # v3: the reward only
    assert not same_spaces("BranchScanDiscrete-v1", "BranchScanDiscrete-v2")
    assert not same_spaces("BranchScan-v3", "BranchScanDiscrete-v3")
    path = resolve_model_path("ppo_dagger_v2")
    model = load_model(path)
    setattr(model, ENV_ID_ATTRIBUTE, "BranchScanDiscrete-v3")
    load_policy_weights(model, path)
    setattr(model, ENV_ID_ATTRIBUTE, "BranchScanDiscrete-v1")
    with pytest.raises(ValueError, match="their observations or actions differ"):
        load_policy_weights(model, path)
