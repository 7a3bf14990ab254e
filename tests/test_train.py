"""Training: the CLI end to end, resuming, checkpoints, loading models, seeds, configs."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium import spaces

import branch_gym
from agents.factory import AGENTS, make_agent
from agents.ppo import check_ppo_spec, load_policy
from branch_gym.env.layout import PRICE_KEY, branch_value_s, flatten_observation
from branch_gym.env.reward import RewardConfig
from branch_gym.evaluation.episodes import run_episode, run_trial
from branch_gym.scan import ScanConfig
from branch_gym.training.callbacks import (
    TorchThreadsCallback,
    ValueWarmupCallback,
    WarmupLearningRate,
    scan_metrics,
)
from branch_gym.training.checkpoints import CheckpointError, read_checkpoint
from branch_gym.training.config import PPOConfig, TrainConfig
from branch_gym.training.envs import (
    DICT_LSTM_POLICY,
    DICT_POLICY,
    FLAT_LSTM_POLICY,
    FLAT_POLICY,
    policy_class,
)
from branch_gym.training.model_files import ModelFileError, PolicyAgent, load_model
from branch_gym.training.paths import RunPaths
from branch_gym.training.prices import PriceRangeWrapper, tree_branch_value_s
from branch_gym.training.seeds import (
    EVAL_SEED_BASE,
    MAX_EVAL_TREES,
    MAX_RUN_SEEDS,
    TreeSeedWrapper,
    eval_tree_seeds,
    train_seed_range,
    train_tree_seed,
)
from branch_gym.training.train import scale_action_logits, train

ROOT = Path(__file__).resolve().parents[1]
SHORT = {"tracker": "oracle", "end_height_m": 0.33}  # ~6 steps per episode
FIRST_STEPS, RESUMED_STEPS = 128, 192
# Tiny PPO: rollouts of 32 steps; a small action std (std 0.05 x 45 deg) keeps rotations short.
CLI_ARGS = [
    "--tracker", "oracle", "--end-height", "0.33", "--n-envs", "1", "--seed", "3",
    "--n-steps", "32", "--batch-size", "32", "--n-epochs", "2", "--log-std-init", "-3",
    "--checkpoint-every", "64", "--eval-every", "64", "--eval-trees", "1",
]  # fmt: skip
# A tiny RecurrentPPO run on the discrete v1 env: one rollout of 32 steps, one epoch.
RECURRENT_STEPS = 32
RECURRENT_ARGS = [
    "--env", branch_gym.DISCRETE_ENV_ID_V1, "--recurrent", "--first-action-logit", "3",
    "--tracker", "oracle", "--end-height", "0.33", "--n-envs", "1", "--seed", "3",
    "--n-steps", "32", "--batch-size", "32", "--n-epochs", "1",
    "--checkpoint-every", "32", "--eval-every", "32", "--eval-trees", "1",
]  # fmt: skip


def load_cli():
    """train.py as a module (a script at the repository root, not a package)."""
    spec = importlib.util.spec_from_file_location("train_cli", ROOT / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ------------------------------------------------------------------ seeds and configs (fast)
def test_training_and_evaluation_trees_are_disjoint() -> None:
    eval_seeds = set(eval_tree_seeds(MAX_EVAL_TREES))
    assert min(eval_seeds) >= EVAL_SEED_BASE  # above eval.py's benchmark trees
    ranges = [train_seed_range(seed) for seed in (0, 1, MAX_RUN_SEEDS - 1)]
    for r in ranges:
        assert r.start > max(eval_seeds)
        assert r.stop - 1 < 2**31 - 1
    assert ranges[0].stop <= ranges[1].start  # run seeds do not share trees
    assert eval_tree_seeds(3) == eval_tree_seeds(3)  # the same held-out trees every time
    per_env = [{train_tree_seed(0, rank, 3, e) for e in range(50)} for rank in range(3)]
    assert not (per_env[0] & per_env[1]) and not (per_env[1] & per_env[2])
    assert all(s in ranges[0] for seeds in per_env for s in seeds)
    with pytest.raises(ValueError, match="seed"):
        train_tree_seed(MAX_RUN_SEEDS, 0, 1, 0)


class _SeedRecorder(gymnasium.Env):
    observation_space = spaces.Box(0, 1, (1,))
    action_space = spaces.Box(0, 1, (1,))

    def __init__(self) -> None:
        self.seeds: list[int | None] = []

    def reset(self, *, seed=None, options=None):
        self.seeds.append(seed)
        return np.zeros(1, np.float32), {}


def test_tree_seed_wrapper_ignores_vec_env_seeds_and_resumes() -> None:
    inner = _SeedRecorder()
    env = TreeSeedWrapper(inner, seed=5, rank=1, n_envs=2)
    env.reset(seed=123)
    env.reset()
    env.set_episodes(10)
    env.reset()
    assert inner.seeds == [train_tree_seed(5, 1, 2, e) for e in (0, 1, 10)]


def test_price_range_wrapper_draws_dear_prices_the_observation_reads() -> None:
    env = PriceRangeWrapper(
        gymnasium.make(branch_gym.DISCRETE_ENV_ID, tracker="oracle", end_height_m=0.33),
        (200.0, 400.0),
    )
    bounds = env.unwrapped.config.branch_value_s  # the env's own range, (25, 400)
    drawn = []
    for tree_seed in range(6):
        obs, _ = env.reset(seed=tree_seed)
        value = float(branch_value_s(obs[PRICE_KEY], bounds)[0])
        assert 200.0 - 1e-3 <= value <= 400.0 + 1e-3
        assert value == pytest.approx(tree_branch_value_s(tree_seed, (200.0, 400.0)), rel=1e-4)
        drawn.append(value)
    assert len(set(np.round(drawn, 3))) == len(drawn)  # a price per tree, not one for all
    obs, _ = env.reset(seed=0, options={"branch_value_s": 25.0})  # a fixed price is kept
    assert float(branch_value_s(obs[PRICE_KEY], bounds)[0]) == pytest.approx(25.0, rel=1e-4)
    with pytest.raises(ValueError, match="seed"):
        env.reset()
    env.close()
    with pytest.raises(ValueError, match="branch_value_s"):
        PriceRangeWrapper(env, (400.0, 200.0))


def test_train_price_range_lies_within_the_env_range() -> None:
    config = TrainConfig(env_id=branch_gym.DISCRETE_ENV_ID, train_branch_value_s=[200, 400])
    assert config.train_branch_value_s == (200.0, 400.0)
    assert TrainConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config
    with pytest.raises(ValueError, match="within the branch_value_s range"):
        TrainConfig(env_id=branch_gym.DISCRETE_ENV_ID, train_branch_value_s=(200, 800))
    with pytest.raises(ValueError, match="needs a priced env id"):
        TrainConfig(train_branch_value_s=(200, 400))  # v0: no price
    with pytest.raises(ValueError, match="train_branch_value_s"):
        TrainConfig(env_id=branch_gym.DISCRETE_ENV_ID, train_branch_value_s=(float("nan"), 400))


def test_run_scan_time_limit_reaches_the_env() -> None:
    config = TrainConfig(env_id=branch_gym.DISCRETE_ENV_ID, max_scan_time_s=160.0, **SHORT)
    env = gymnasium.make(config.env_id, **config.env_kwargs())
    assert env.unwrapped.config.scan.max_scan_time_s == 160.0
    env.close()
    assert "max_scan_time_s" not in TrainConfig().env_kwargs()  # the scan default, 100 s
    with pytest.raises(ValueError, match="max_scan_time_s"):
        TrainConfig(max_scan_time_s=-1.0)
    with pytest.raises(ValueError, match="max_scan_time_s"):
        TrainConfig(max_scan_time_s="long")


def test_config_validation_names_the_field() -> None:
    for kwargs, field in [
        ({"n_envs": 0}, "n_envs"),
        ({"env_id": "Nope-v0"}, "env_id"),
        ({"seed": -1}, "seed"),
        ({"eval_trees": 0}, "eval_trees"),
        ({"tracker": "sift"}, "tracker"),
        ({"ppo": PPOConfig(n_steps=8, batch_size=64)}, "batch_size"),
    ]:
        with pytest.raises(ValueError, match=field):
            TrainConfig(**kwargs)
    with pytest.raises(ValueError, match="gamma"):
        PPOConfig(gamma=1.5)
    with pytest.raises(ValueError, match="target_kl"):
        PPOConfig(target_kl=0.0)
    with pytest.raises(ValueError, match="time_penalty_per_s"):
        TrainConfig(time_penalty_per_s=-0.01)
    cheap_time = TrainConfig(time_penalty_per_s=0.002)
    assert cheap_time.env_kwargs()["reward"].time_penalty_per_s == 0.002
    assert "reward" not in TrainConfig().env_kwargs()
    with pytest.raises(ValueError, match="spurious_penalty"):
        TrainConfig(spurious_penalty=-0.1)
    cheap_false = TrainConfig(spurious_penalty=0.1, duplicate_penalty=0.2).env_kwargs()["reward"]
    assert (cheap_false.spurious_penalty, cheap_false.duplicate_penalty) == (0.1, 0.2)
    assert cheap_false.time_penalty_per_s == RewardConfig().time_penalty_per_s
    assert TrainConfig.from_dict(json.loads(json.dumps(cheap_time.to_dict()))) == cheap_time
    assert PPOConfig(target_kl=0.02).sb3_kwargs()["target_kl"] == 0.02
    config = TrainConfig(n_envs=2, end_height_m=0.5, ppo=PPOConfig(n_steps=64, target_kl=0.02))
    assert TrainConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config
    assert config.resume_conflicts(config) == []
    longer = TrainConfig.from_dict({**config.to_dict(), "timesteps": 10**6})
    assert longer.resume_conflicts(config) == []
    other = TrainConfig.from_dict({**config.to_dict(), "tracker": "oracle"})
    assert other.resume_conflicts(config) == ["tracker: 'lk' -> 'oracle'"]


def test_recurrent_config_round_trips_and_cannot_change_on_resume() -> None:
    recurrent = TrainConfig(recurrent=True, **SHORT)
    assert TrainConfig.from_dict(json.loads(json.dumps(recurrent.to_dict()))) == recurrent
    old = {k: v for k, v in recurrent.to_dict().items() if k != "recurrent"}  # an older run
    assert TrainConfig.from_dict(old).recurrent is False
    assert recurrent.resume_conflicts(TrainConfig(**SHORT)) == ["recurrent: False -> True"]
    with pytest.raises(ValueError, match="recurrent"):
        TrainConfig(recurrent="yes")


def test_scan_metrics_skip_undefined_values() -> None:
    row = {"missed_pct": None, "spurious_pct": 0.0, "rotations": 2, "scan_time_s": 20.0}
    metrics = scan_metrics({**row, "failure": "lost_branch"})
    assert metrics == {"spurious_pct": 0.0, "rotations": 2.0, "scan_time_s": 20.0, "failed": 1.0}


def test_torch_threads_follow_the_training_phase() -> None:
    import torch
    from stable_baselines3 import PPO

    initial = torch.get_num_threads()
    callback = TorchThreadsCallback(rollout_threads=1, update_threads=2)
    callback.init_callback(PPO("MlpPolicy", "CartPole-v1", n_steps=8, batch_size=8, device="cpu"))
    callback.on_training_start({}, {})
    callback.on_rollout_start()
    assert torch.get_num_threads() == 1
    callback.on_rollout_end()
    assert torch.get_num_threads() == 2
    callback.on_training_end()
    assert torch.get_num_threads() == initial
    with pytest.raises(ValueError, match="update_threads=0"):
        TorchThreadsCallback(rollout_threads=1, update_threads=0)


def test_value_warmup_trains_only_the_critic_until_its_step_count() -> None:
    import torch
    from stable_baselines3 import PPO

    model = PPO(
        "MlpPolicy", "CartPole-v1", n_steps=32, batch_size=32, n_epochs=2, seed=0, device="cpu"
    )
    before = {name: p.detach().clone() for name, p in model.policy.named_parameters()}
    model.learn(32, callback=ValueWarmupCallback(32))
    changed = {
        name for name, p in model.policy.named_parameters() if not torch.equal(p, before[name])
    }
    assert changed and all(n.startswith(("value_net", "mlp_extractor.value_net")) for n in changed)
    model.learn(32, callback=ValueWarmupCallback(32), reset_num_timesteps=False)
    assert not torch.equal(model.policy.action_net.weight, before["action_net.weight"])
    with pytest.raises(ValueError, match="value_warmup_steps"):
        TrainConfig(value_warmup_steps=100, recurrent=True)


def test_the_value_warmup_steps_at_its_own_learning_rate() -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    schedule = WarmupLearningRate(3e-4, 1e-5, warmup_steps=64, total_steps=128)
    assert schedule(1.0) == 3e-4 and schedule(0.5) == 3e-4  # 0 and 64 steps done
    assert schedule(0.25) == 1e-5 and schedule(0.0) == 1e-5  # 96 and 128
    ramped = WarmupLearningRate(3e-4, 1e-5, warmup_steps=64, total_steps=128, ramp_steps=32)
    assert ramped(0.5) == 3e-4 and ramped(0.375) == pytest.approx(0.5e-5)  # 64 and 80 steps
    assert ramped(0.25) == 1e-5  # 96: the ramp done
    model = PPO(
        "MlpPolicy", "CartPole-v1", n_steps=32, batch_size=32, n_epochs=1, seed=0, device="cpu"
    )
    model.lr_schedule = schedule

    rates: list[float] = []

    class UpdateRates(BaseCallback):  # the rate of each update, read after it
        def _on_step(self) -> bool:
            return True

        def _on_rollout_start(self) -> None:
            rates.append(model.policy.optimizer.param_groups[0]["lr"])

    model.learn(128, callback=[ValueWarmupCallback(64), UpdateRates()])
    assert rates[1:] == [3e-4, 3e-4, 1e-5]  # the updates at 32, 64 and 96 steps
    with pytest.raises(ValueError, match="needs value_warmup_steps"):
        TrainConfig(value_warmup_learning_rate=3e-4)
    with pytest.raises(ValueError, match="value_warmup_learning_rate"):
        TrainConfig(value_warmup_steps=64, value_warmup_learning_rate=-1.0)
    with pytest.raises(ValueError, match="learning_rate_ramp_steps needs"):
        TrainConfig(value_warmup_steps=64, learning_rate_ramp_steps=32)
    with pytest.raises(ValueError, match="positive rates"):
        WarmupLearningRate(3e-4, 1e-5, warmup_steps=0, total_steps=128)


def test_init_logit_scale_sharpens_sampling_and_keeps_the_argmax() -> None:
    import torch
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", "CartPole-v1", seed=0, device="cpu")
    observations = torch.as_tensor(
        np.random.default_rng(0).normal(size=(64, 4)), dtype=torch.float32
    )
    with torch.no_grad():
        model.policy.action_net.bias.copy_(torch.tensor([0.3, -0.2]))
        before = model.policy.get_distribution(observations).distribution.probs
        scale_action_logits(model, 3.0)
        after = model.policy.get_distribution(observations).distribution.probs
    assert torch.equal(before.argmax(1), after.argmax(1))
    assert (after.max(1).values > before.max(1).values).all()  # temperature 1/3: sharper
    with pytest.raises(ValueError, match="init_logit_scale"):
        TrainConfig(init_logit_scale=3.0)  # without an init model
    with pytest.raises(ValueError, match="init_logit_scale"):
        TrainConfig(init_model="m.zip", init_logit_scale=0.0)


def test_policy_class_follows_the_observation_space() -> None:
    env = gymnasium.make(branch_gym.ENV_ID_V0, **SHORT)
    flat = gymnasium.make(branch_gym.FLAT_ENV_ID, **SHORT)
    try:
        assert policy_class(env.observation_space) == DICT_POLICY
        assert policy_class(flat.observation_space) == FLAT_POLICY
        assert policy_class(env.observation_space, recurrent=True) == DICT_LSTM_POLICY
        assert policy_class(flat.observation_space, recurrent=True) == FLAT_LSTM_POLICY
        dict_obs, _ = env.reset(seed=1)
        flat_obs, _ = flat.reset(seed=1)
        assert np.allclose(flatten_observation(dict_obs), flat_obs)
        batch = {k: np.stack([v, v]) for k, v in dict_obs.items()}
        assert flatten_observation(batch).shape == (2, *flat_obs.shape)
    finally:
        env.close()
        flat.close()


# ------------------------------------------------------------------ bad files (fast)
def test_missing_or_corrupt_model_files_give_clear_errors(tmp_path: Path) -> None:
    missing = tmp_path / "nope.zip"
    with pytest.raises(FileNotFoundError, match=r"nope\.zip"):
        load_policy(missing)
    with pytest.raises(FileNotFoundError, match=r"nope\.zip"):
        make_agent(f"ppo:{missing}", None)
    with pytest.raises(ValueError, match="ppo:PATH"):
        check_ppo_spec("ppo:")
    corrupt = tmp_path / "corrupt.zip"
    corrupt.write_bytes(b"definitely not a zip file")
    with pytest.raises(ModelFileError, match=r"corrupt\.zip"):
        load_policy(corrupt)


def test_resume_without_or_with_a_corrupt_checkpoint(tmp_path: Path) -> None:
    config = TrainConfig(**SHORT)
    with pytest.raises(FileNotFoundError, match=r"checkpoint\.json"):
        train(config, tmp_path / "empty", resume=True)
    paths = RunPaths(tmp_path / "torn")
    paths.checkpoints.mkdir(parents=True)
    paths.checkpoint.write_text("{not json")
    with pytest.raises(CheckpointError, match=r"checkpoint\.json"):
        read_checkpoint(paths)
    paths.checkpoint.write_text(
        json.dumps({"num_timesteps": 64, "model": "model_64.zip", "vecnormalize": None,
                    "episodes": [3], "best_mean_reward": None})
    )  # fmt: skip
    with pytest.raises(FileNotFoundError, match=r"model_64\.zip"):
        read_checkpoint(paths)
    (paths.checkpoints / "model_64.zip").write_bytes(b"\x00" * 10)
    paths.config.write_text(json.dumps({"config": config.to_dict()}))
    with pytest.raises(ModelFileError, match=r"model_64\.zip"):
        train(config, paths.out, resume=True)


# ------------------------------------------------------------------ end to end (slow)
@pytest.mark.slow
def test_train_load_and_resume_end_to_end(tmp_path: Path) -> None:
    """A tiny PPO run through the CLI (128 steps), then resumed to 192 steps.

    One test, not several sharing a fixture: pytest-xdist would train once per worker.
    """
    out = tmp_path / "run"
    cli = load_cli()
    assert cli.main(["--timesteps", str(FIRST_STEPS), "--out", str(out), *CLI_ARGS]) == 0
    check_first_run(RunPaths(out))
    check_loaded_model_acts(RunPaths(out))
    check_resume(cli, RunPaths(out))


def check_first_run(paths: RunPaths) -> None:
    saved = json.loads(paths.config.read_text())
    config = TrainConfig.from_dict(saved["config"])
    assert (config.seed, config.tracker, config.end_height_m, config.ppo.n_steps) == (
        3, "oracle", 0.33, 32,
    )  # fmt: skip
    assert saved["tree_seeds"]["train_first"] == train_seed_range(3).start
    assert saved["tree_seeds"]["eval"] == eval_tree_seeds(1)
    checkpoint = read_checkpoint(paths)
    assert checkpoint.num_timesteps == FIRST_STEPS
    assert checkpoint.episodes[0] > 1  # whole scans were played
    evaluations = [json.loads(line) for line in paths.evaluations.read_text().splitlines()]
    assert [e["num_timesteps"] for e in evaluations] == [64, 128]
    assert paths.best_model.is_file() and paths.final_model.is_file()
    assert (paths.out / "training_curve.png").stat().st_size > 10_000
    tags = _tensorboard_tags(paths.tensorboard)
    for tag in ("scan/spurious_pct", "scan/rotations", "scan/scan_time_s", "episode/scan_time_s",
                "eval/mean_reward", "eval/scan_time_s", "rollout/ep_rew_mean"):  # fmt: skip
        assert tag in tags, tag


def check_loaded_model_acts(paths: RunPaths) -> None:
    agent = load_policy(paths.final_model)
    assert isinstance(agent, PolicyAgent)
    env = gymnasium.make(branch_gym.ENV_ID_V0, **SHORT)
    obs, _ = env.reset(seed=EVAL_SEED_BASE)
    env.close()
    action, state = agent.predict(obs, deterministic=True)
    assert action.shape == (1,) and env.action_space.contains(action.astype(np.float32))
    assert state is None
    batch = {k: np.stack([v, v]) for k, v in obs.items()}
    actions, _ = agent.predict(batch, episode_start=np.array([True, False]))
    assert actions.shape == (2, 1) and np.allclose(actions[0], action)
    # eval.py's path: the "ppo:PATH" spec plays a whole scan.
    result = run_trial(0, f"ppo:{paths.final_model}", ScanConfig(**SHORT), AGENTS)
    assert result.policy == f"ppo:{paths.final_model}" and result.n_iterations > 0


def check_resume(cli, paths: RunPaths) -> None:
    before = read_checkpoint(paths)
    argv = ["--timesteps", str(RESUMED_STEPS), "--out", str(paths.out), *CLI_ARGS]
    assert cli.main(argv) == 2  # a new run into a run folder is refused
    assert cli.main([*argv, "--resume", "--tracker", "lk"]) == 2  # another configuration
    assert cli.main([*argv, "--resume"]) == 0
    after = read_checkpoint(paths)
    assert after.num_timesteps == RESUMED_STEPS > before.num_timesteps
    assert after.episodes[0] > before.episodes[0]  # new trees, not the same ones again
    assert load_policy(paths.final_model).model.num_timesteps == RESUMED_STEPS
    saved = TrainConfig.from_dict(json.loads(paths.config.read_text())["config"])
    assert saved.timesteps == RESUMED_STEPS
    assert len(paths.evaluations.read_text().splitlines()) == 3  # 64, 128, then 192


@pytest.mark.slow
def test_flat_env_with_vecnormalize_resumes_and_acts_in_the_dict_env(tmp_path: Path) -> None:
    ppo = PPOConfig(n_steps=32, batch_size=32, n_epochs=1, log_std_init=-3.0)
    config = TrainConfig(
        env_id=branch_gym.FLAT_ENV_ID, timesteps=32, normalize=True, eval_every=0,
        checkpoint_every=32, ppo=ppo, **SHORT,
    )  # fmt: skip
    out = tmp_path / "flat"
    assert train(config, out).num_timesteps == 32
    longer = TrainConfig.from_dict({**config.to_dict(), "timesteps": 64})
    result = train(longer, out, resume=True)
    assert (result.start_timesteps, result.num_timesteps) == (32, 64)
    assert read_checkpoint(RunPaths(out)).vecnormalize == "model_000000064_vecnormalize.pkl"
    env = gymnasium.make(branch_gym.ENV_ID_V0, **SHORT)  # Dict observations
    try:
        agent = make_agent(f"ppo:{result.final_model}", env)
        assert agent.normalizer is not None and agent.flatten_dict
        obs, _ = env.reset(seed=EVAL_SEED_BASE)
        action, _ = agent.predict(obs)
        assert env.action_space.contains(action.astype(np.float32))
        discrete = gymnasium.make(branch_gym.DISCRETE_ENV_ID_V0, **SHORT)
        with pytest.raises(ValueError, match="Discrete"):
            make_agent(f"ppo:{result.final_model}", discrete)
        discrete.close()
    finally:
        env.close()


class _StateSpy:
    """An agent that records the state and episode_start each predict call gets."""

    def __init__(self, agent: PolicyAgent) -> None:
        self.agent = agent
        self.calls: list[tuple[object, object]] = []

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        self.calls.append((state, episode_start))
        return self.agent.predict(observation, state, episode_start, deterministic)


@pytest.mark.slow
def test_recurrent_run_plays_carries_its_lstm_state_and_resumes(tmp_path: Path, capsys) -> None:
    """A RecurrentPPO run through the CLI (32 steps), an episode of it, then resumed to 64."""
    from sb3_contrib import RecurrentPPO

    out = tmp_path / "lstm"
    cli = load_cli()
    argv = ["--timesteps", str(RECURRENT_STEPS), "--out", str(out), *RECURRENT_ARGS]
    assert cli.main(argv) == 0
    paths = RunPaths(out)
    assert TrainConfig.from_dict(json.loads(paths.config.read_text())["config"]).recurrent
    assert len(paths.evaluations.read_text().splitlines()) == 1  # held-out eval with the LSTM
    model = load_model(paths.final_model)
    assert isinstance(model, RecurrentPPO)
    bias = model.policy.action_net.bias.detach().numpy()
    assert bias[0] - bias[1:].max() > 2.5  # --first-action-logit reached the LSTM policy
    env = gymnasium.make(branch_gym.DISCRETE_ENV_ID_V1, **SHORT)
    try:
        spy = _StateSpy(load_policy(paths.final_model, env))
        episode = run_episode(spy, env, EVAL_SEED_BASE, options={"branch_value_s": 80.0})
        assert episode.steps == len(spy.calls) > 1 and episode.result.n_iterations > 0
        assert spy.calls[0] == (None, True)  # a fresh LSTM state at the first step
        hidden, cell = spy.calls[1][0]  # then the state predict returned, passed back
        assert hidden.shape == cell.shape == (1, 1, model.policy.lstm_hidden_state_shape[-1])
        assert all(state is not None and start is False for state, start in spy.calls[1:])
    finally:
        env.close()
    resume = ["--timesteps", str(2 * RECURRENT_STEPS), "--out", str(out), *RECURRENT_ARGS]
    capsys.readouterr()
    assert cli.main([a for a in resume if a != "--recurrent"] + ["--resume"]) == 2
    assert "recurrent: True -> False" in capsys.readouterr().err
    assert cli.main([*resume, "--resume"]) == 0
    assert read_checkpoint(paths).num_timesteps == 2 * RECURRENT_STEPS
    resumed = load_model(paths.final_model)
    assert isinstance(resumed, RecurrentPPO) and resumed.num_timesteps == 2 * RECURRENT_STEPS


def _tensorboard_tags(folder: Path) -> set[str]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    tags: set[str] = set()
    for run in folder.iterdir():
        events = EventAccumulator(str(run))
        events.Reload()
        tags |= set(events.Tags()["scalars"])
    return tags


def test_training_curve_needs_a_run_folder(tmp_path: Path) -> None:
    from branch_gym.training.curve import _running_mean, plot_training_curve

    with pytest.raises(FileNotFoundError, match="no TensorBoard logs"):
        plot_training_curve(tmp_path)
    np.testing.assert_allclose(_running_mean(np.arange(4.0)), [0.0, 0.5, 1.0, 1.5])
