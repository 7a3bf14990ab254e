"""The Gymnasium environment: active branch scanning, one modeling iteration per step."""

from __future__ import annotations

import copy
import logging
from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np

from branch_gym.env.actions import ActionCodec
from branch_gym.env.config import (
    EnvConfig,
    branch_value_from_options,
    draw_branch_value_s,
    env_config_from_kwargs,
    tree_from_options,
)
from branch_gym.env.coverage import CoverageMemory, rows_to_heights_m
from branch_gym.env.info import final_metrics, step_info, step_timings
from branch_gym.env.layout import COVERAGE_KEY, PRICE_KEY, price_feature
from branch_gym.env.observation import (
    Drawing,
    PipelineState,
    draw_state,
    make_observation,
    observation_space,
    pipeline_state,
)
from branch_gym.env.rendering import camera_frame, follow_in_gui, require_display
from branch_gym.env.reward import REWARD_TERMS, RewardTracker
from branch_gym.env.score_cache import ScoreCache
from branch_gym.scan import ScanSession
from branch_gym.scoring import (
    ScanResult,
    scan_metrics_config,
    score_scan,
    session_surroundings,
)
from branch_gym.surroundings import Surroundings
from recon.metrics import TreeMetrics
from recon.modeler import IterationReport, Outcome
from recon.timing import stage_timer

logger = logging.getLogger(__name__)

# Video frame rate (our choice): a step is ~0.4 s of scan time, so 10 fps plays ~4x real time.
RENDER_FPS = 10
# Episode seeds drawn from the env's generator when reset() gets none: [0, 2**31 - 1).
_SEED_BOUND = 2**31 - 1


class BranchScanEnv(gym.Env):
    """Scan up a tree's primary branch; decide, once per modeling iteration, where to look from.

    A UR5e with an eye-in-hand camera follows the primary branch upward while the reconstruction
    pipeline (``recon``) builds a 3D model of the primary and its side branches. At every step
    the agent picks the camera's rotation about the branch (yaw about the world vertical through
    the followed branch point); the scan rotates there if it changed (rotating is motion at the
    scan speed: it costs scan time), then follows the branch until the modeler has run its next
    iteration (every 10 mm of travel): renders, segmentation, tracking, triangulation, modeling
    (:meth:`branch_gym.scan.ScanSession.step`).

    ## Action space

    By ``action_type`` (each registered id has one: :mod:`branch_gym.env.versions`):

    ============================  ==============================================================
    ``continuous``                ``Box(-1, 1, (1,), float32)``: target angle / theta_max
                                  (theta_max 45 deg). Finite values outside [-1, 1] are clipped;
                                  NaN, infinities and shapes other than (1,) or a scalar raise
                                  ``ValueError``.
    ``discrete``                  ``Discrete(5)``: target angle -45, -22.5, 0, 22.5 or 45 deg.
                                  Non-integer or out-of-range indices raise ``ValueError``.
    ``discrete_hold``             ``Discrete(6)``: 0 holds the current angle; k = 1..5 targets
                                  -45, -22.5, 0, 22.5 or 45 deg (the discrete v1 and v2 ids).
    ``trigger``                   ``Discrete(3)``: 0 holds the angle; 1 / 2 advance the paper's
                                  cycle (+theta, 0, -theta, 0) by one move with theta 22.5 /
                                  45 deg (from a rotated view back to 0, from 0 to the side
                                  opposite the last rotation). Bad indices raise ``ValueError``.
    ============================  ==============================================================

    ## Observation space

    ``Dict(image=Box(0, 255, (3, 60, 80), uint8), vector=Box(low, high, (12,), float32))``; with
    ``flatten=True`` (or ``BranchScanFlat-v0``) one ``Box`` of 12 + 14400 float32: the vector,
    then the image / 255 (channel-first order). Only what the pipeline knows, no ground truth.
    Names: :class:`branch_gym.env.layout.ImageChannel`, :class:`~branch_gym.env.layout.VectorField`.

    =====  =============================  ============================================  =======
    image  channel                        content (camera image / 4, area-averaged)     range
    =====  =============================  ============================================  =======
    0      ``MASK``                       latest segmentation mask (as cleaned by 2D)   0..255
    1      ``MODEL``                      3D model projected into the current view,     0..255
                                          primary + secondaries as wide as their radii
    2      ``UNCONFIRMED``                2D side-branch candidates of the latest       0..255
                                          mask that no projected 3D secondary explains
    =====  =============================  ============================================  =======

    ======  =============================  ============================================  =======
    vector  field                          meaning                                       range
    ======  =============================  ============================================  =======
    0       ``ANGLE``                      current rotation / theta_max                  [-1, 1]
    1       ``TRAVEL_FOV``                 vertical travel since the last rotation, in   [0, 10]
                                           vertical FoVs at z_target (0.115 m)
    2       ``PROGRESS``                   fraction of the scan height range covered     [0, 1]
    3-5     ``OUTCOME_*``                  latest iteration consistent / inconsistent /  {0, 1}
                                           restart, one-hot (all 0 before the first)
    6       ``MODEL_SECONDARIES``          secondaries in the 3D model / 10              [0, 1]
    7       ``MODEL_SECONDARIES_IN_VIEW``  ... of which project into the image / 10      [0, 1]
    8       ``CANDIDATES_2D``              2D side-branch candidates in the mask / 10    [0, 1]
    9       ``UNCONFIRMED_CANDIDATES``     ... not explained by the 3D model / 10        [0, 1]
    10      ``PREVIOUS_ACTION``            previous target angle / theta_max (0 after    [-1, 1]
                                           reset)
    11      ``SCAN_TIME``                  scan time so far / the scan-time limit        [0, 1]
    ======  =============================  ============================================  =======

    v1 observations (``BranchScan-v1``, ``BranchScanDiscrete-v1``; ``coverage=CoverageConfig()``,
    ``branch_value_s=(25, 400)``) add two entries, flattened after the image in this order:

    ============  ===========================  ==================================================
    key           shape                        content
    ============  ===========================  ==================================================
    ``coverage``  (128,) float32 in [0, 1]     16 height bins x 8 channels, row-major: per height
                                               bin of the scan band: seen from each of
                                               the 5 rotation sectors (-45 .. 45 deg), unconfirmed
                                               2D candidates, model secondaries (their base
                                               heights), mask-model disagreements
                                               (:mod:`branch_gym.env.coverage`)
    ``price``     (1,) float32 in [0, 1]       this episode's branch value: log-scaled, 0 at
                                               25 s, 1 at 400 s of scan time per found branch
    ============  ===========================  ==================================================

    v2 observations (``BranchScan-v2``, ``BranchScanDiscrete-v2``;
    ``coverage=CoverageConfig(in_front_channel=True)``) hold a (144,) ``coverage``: 16 height bins
    x 9 channels, the v1 channels and ``IN_FRONT`` last, the tracked primary points per bin that
    triangulated in front of the model (``IterationReport.points_in_front``: a branch pointing at
    the lens covers the trunk in the mask and leaves no other trace), / 10, clipped to 1.

    ## Rewards (ground truth, simulation only; :class:`branch_gym.env.reward.RewardConfig`)

    =================  ==========  ==============================================================
    term               weight      per
    =================  ==========  ==============================================================
    ``matched``        +1.0        ground-truth secondary newly matched (-1.0 if a match is lost)
    ``spurious``       -0.5        spurious model branch added (+0.5 when one is pruned)
    ``duplicates``     -0.5        duplicate of a matched branch added (+0.5 when merged)
    ``time``           -0.01       second of scan time (following and rotating); v1: -1 / value,
                                   the episode's branch value (``branch_value_s``) in seconds
    ``failure``        -1.0        once, when the scan fails (terminated with a failure reason,
                                   the scan-time limit included)
    =================  ==========  ==============================================================

    Scoring is :func:`recon.metrics.evaluate` up to the height scanned so far, after every step
    (recomputed only when the model or the branches in scope changed, ``score_cache``); the
    return telescopes to the final score. ``info["reward_terms"]`` splits each reward.

    ## Episode end

    - ``terminated``: the camera reached ``end_height_m`` (0.75 m) or the scan failed
      (``singularity``, ``joint_limit``, ``joint_speed``, ``collision``, ``lost_branch``, or
      ``timeout``: the simulated scan-time limit ``ScanConfig.max_scan_time_s``, 100 s;
      ``info["failure"]``). The scan-time limit is part of the task, not a truncation: a scan
      that runs out of time ends there with the failure penalty, the branches above never found
      (the observation's ``SCAN_TIME`` tells the policy how much time is left). Treating it as a
      truncation let a learner bootstrap the value of branches it would never reach
      (``docs/results/history.md``).
    - ``truncated``: the step limit of the registered ids (``max_episode_steps=200``,
      gymnasium's ``TimeLimit``; ``gymnasium.make(..., max_episode_steps=N)`` changes it).
      Stepping a terminated episode raises ``RuntimeError``: call ``reset()``.

    ## Info

    Every ``reset`` / ``step``: ``seed`` (the tree's), ``metrics`` (flat
    :meth:`recon.metrics.TreeMetrics.to_dict` so far, NaN as None), ``reward_terms``,
    ``failure`` ("" if none), ``stop_reason`` ("" while running), ``scan_time_s``, ``rotations``,
    ``angle_deg``, ``camera_height_m``, ``progress``, ``outcome`` (latest iteration, "" before the
    first), ``iterations`` (this step), ``n_iterations``, ``rotated``, and with ``info_timings``
    ``timings_ms`` (modeler stages summed over the step's iterations, ``scan_step_ms``,
    ``render_ms`` (the renders of the step's frames), ``metrics_ms``, ``observation_ms``,
    ``env_step_ms``). When the scan ends (terminated):
    ``final_metrics``, the :meth:`branch_gym.scoring.ScanResult.to_row` of
    the scan. After a ``TimeLimit`` truncation ``metrics`` is the final score.

    ## Arguments

    ``gymnasium.make(id, render_mode=None, **kwargs)``; the fields of
    :class:`~branch_gym.env.config.EnvConfig` and shortcuts into its ``scan``.

    =======================  =====================================================================
    ``render_mode``          None, "rgb_array" (camera image + mask, 2D curves, projected model),
                             "human" (pybullet GUI; needs a display, else ``RuntimeError``)
    ``world``                "clean" (default) or "orchard" (sky, the row with true depth,
                             trellis, dormant bark, camera model; ``docs/worlds.md``)
    ``tracker``              "lk" (default) or "oracle" (exact tracks from rendered depth, faster)
    ``segmenter``            "gt" (default), "noisy:mild" | "noisy:moderate" | "noisy:severe",
                             "learned" | "learned:PATH" (RGB network, branch_gym.sensing)
    ``tree``                 "paper" (default), "cluttered", "hard", "tall_spindle", "ufo" or a
                             ``TreeConfig``
    ``end_height_m``         scan end height (0.75 m); ``speed_mps``: scan speed (0.025 m/s)
    ``max_scan_time_s``      simulated time limit of a scan (100 s; a benchmark may set its own)
    ``scan``                 a full :class:`branch_gym.scan.ScanConfig` (the shortcuts above
                             modify it)
    ``action_type``          "continuous", "discrete", "discrete_hold" or "trigger" (set by id)
    ``coverage``             a ``CoverageConfig``: the v1 / v2 coverage memory (None in v0)
    ``branch_value_s``       (low, high) s: the per-episode price of scan time (None in v0);
                             ``reset(options={"branch_value_s": v})`` fixes it (v in range)
    ``theta_max_deg``        continuous action bound and angle normaliser (45)
    ``discrete_angles_deg``  discrete target angles ((-45, -22.5, 0, 22.5, 45))
    ``trigger_angles_deg``   cycle angles of the trigger actions ((22.5, 45))
    ``flatten``              flat float32 observation (False)
    ``info_timings``         per-stage wall-clock timings in ``info`` (False: keeps infos
                             deterministic, as gymnasium's check_env requires)
    ``reward``               :class:`~branch_gym.env.reward.RewardConfig` or a dict of weights
    ``observation``          :class:`~branch_gym.env.config.ObservationConfig` or a dict
    =======================  =====================================================================

    Unknown keywords and bad values raise ``ValueError`` naming the key. ``reset(seed=s)`` scans
    the tree of seed ``s``; ``reset()`` draws the seed from the env's generator;
    ``options={"tree": TreeGT}`` scans a given tree.

    ## Version History

    A change to the observation, the action or the reward registers a new version of the ids
    (a row of :data:`branch_gym.env.versions.ENV_VERSIONS`, its Version History in
    ``docs/env.md``); the old version stays registered.

    - v0: the tables above: 12-entry vector (``SCAN_TIME`` last) and a 3-channel 60x80 image;
      continuous, discrete and trigger actions; the scan-time limit a terminal failure.
    - v1: adds the ``coverage`` memory and the ``price`` of scan time to the observation, draws
      the price per episode (the reward's time term follows it), and the discrete id gains a
      hold action (``discrete_hold``). v0 ids are unchanged.
    - v2: the coverage memory gains the ``IN_FRONT`` channel (144 entries). v1 ids are unchanged.
    - v3: the reward's spurious branch is one with nothing there (a reconstructed spur, stub,
      neighbour's branch or wire is classed as such, not charged), and every side branch up to
      the planned end height is in scope. v2 ids keep the paper's scoring.

    The scan itself is the ``scan`` argument's (:class:`branch_gym.scan.ScanConfig`), not the
    id's: since orchard-v2 its default holds the model through a rotation
    (``orbit_holds_model``); ``ScanConfig(orbit_holds_model=False)`` scans as before.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": RENDER_FPS}  # noqa: RUF012

    def __init__(self, render_mode: str | None = None, **kwargs: Any) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, "
                f"got {render_mode!r}"
            )
        config = env_config_from_kwargs(kwargs)
        if render_mode == "human":
            require_display()
            world = config.scan.world
            gui_world = replace(world, bullet=replace(world.bullet, gui=True))
            config = replace(config, scan=replace(config.scan, world=gui_world))
        self.config: EnvConfig = config
        self.render_mode = render_mode
        self._actions = ActionCodec(
            config.action_type,
            config.theta_max_deg,
            config.discrete_angles_deg,
            config.trigger_angles_deg,
        )
        self.action_space = self._actions.space
        self._priced = config.branch_value_s is not None
        self.observation_space = observation_space(
            config.observation, config.flatten, config.coverage, self._priced
        )
        self._session = ScanSession(config.scan)
        self._coverage = None
        if config.coverage is not None:
            margin_m = self._session.vertical_fov_m / 2.0  # heights seen above and below
            self._coverage = CoverageMemory(
                config.coverage,
                config.scan.world.scan_start_height_m - margin_m,
                config.scan.end_height_m + margin_m,
            )
        self._price = 0.0
        self._reward = RewardTracker(config.reward)
        self._scores = ScoreCache(
            config.score_cache,
            scan_metrics_config(config.scan, count_unreached_as_missed=not config.paper_scoring),
        )
        self._surroundings: Surroundings | None = None
        self._seed: int | None = None
        self._over = True
        self._last_report: IterationReport | None = None
        self._drawing: Drawing | None = None
        self._previous_action = 0.0

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        tree = tree_from_options(options)
        branch_value_s = self._branch_value_s(branch_value_from_options(options))
        self._seed = int(seed) if seed is not None else int(self.np_random.integers(_SEED_BOUND))
        env_ms: dict[str, float] = {}
        with stage_timer(env_ms, "reset_ms"):
            self._session.reset(self._seed, tree)
            penalty = (
                None if branch_value_s is None else self.config.reward.match_reward / branch_value_s
            )
            self._reward.reset(penalty)
            self._scores.reset()
            self._surroundings = (
                None if self.config.paper_scoring else session_surroundings(self._session)
            )
            if self._coverage is not None:
                self._coverage.reset()
            self._actions.reset()
            self._last_report, self._previous_action, self._over = None, 0.0, False
        metrics = self._score(env_ms)
        obs = self._observe(env_ms, [])
        terms = dict.fromkeys(REWARD_TERMS, 0.0)
        return obs, self._info(metrics, terms, [], False, env_ms)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        if self._seed is None:
            raise RuntimeError("BranchScanEnv.step() called before reset(): call reset() first")
        if self._over:
            raise RuntimeError(
                "BranchScanEnv.step() called after the episode ended (stop reason "
                f"{self._session.stop_reason!r}): call reset() to start a new scan"
            )
        angle_deg = self._actions.to_angle_deg(action, self._session.angle_deg)
        env_ms: dict[str, float] = {}
        render_ms_before = self._session.sensor.render_ms
        with stage_timer(env_ms, "env_step_ms"):
            with stage_timer(env_ms, "scan_step_ms"):
                result = self._session.step(angle_deg)
            env_ms["render_ms"] = self._session.sensor.render_ms - render_ms_before
            self._previous_action = self._actions.normalised(angle_deg)
            if result.reports:
                self._last_report = result.reports[-1]
            session = self._session
            terminated, truncated = session.done, False
            metrics = self._score(env_ms)
            failed = terminated and session.failure is not None
            reward, terms = self._reward.step(metrics, session.scan_time_s, failed)
            obs = self._observe(env_ms, result.reports)
        info = self._info(metrics, terms, result.reports, result.rotated, env_ms)
        if session.done:
            self._over = True
            logger.debug(
                "episode over: %s after %d iterations", session.stop_reason, len(session.reports)
            )
            info["final_metrics"] = final_metrics(self.result(), self.config.info_timings)
        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """rgb_array: (240, 320, 3) uint8 camera image with the pipeline's state overlaid."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode: pass render_mode to make()")
            return None
        if self._seed is None or self._drawing is None:
            raise RuntimeError("BranchScanEnv.render() called before reset()")
        if self.render_mode == "human":
            follow_in_gui(self._session.world)
            return None
        return camera_frame(self._session, self._last_report, self._drawing)

    def close(self) -> None:
        self._session.close()

    # ------------------------------------------------------------------ extras
    @property
    def session(self) -> ScanSession:
        """The scan behind the env (ground truth included: for evaluation, not for policies)."""
        return self._session

    def result(self) -> ScanResult:
        """The current scan scored against the ground truth (``policy="env"``)."""
        return score_scan(self._session, "env", surroundings=self._surroundings)

    def target_angle_deg(self, action: Any, current_angle_deg: float | None = None) -> float:
        """The target angle (deg) that ``action`` commands from ``current_angle_deg``.

        Side-effect free: a trigger action's cycle does not advance.

        Args:
            action: An action of this env's space.
            current_angle_deg: The camera's angle about the branch (deg); None: the angle now.

        Raises:
            ValueError: a bad action (see :meth:`step`).
        """
        current = self._session.angle_deg if current_angle_deg is None else current_angle_deg
        return copy.copy(self._actions).to_angle_deg(action, float(current))

    # ------------------------------------------------------------------ internals
    def _score(self, env_ms: dict[str, float]) -> TreeMetrics:
        session = self._session
        with stage_timer(env_ms, "metrics_ms"):
            return self._scores.score(
                session.model,
                session.tree,
                session.camera_height_m,
                self._surroundings,
                session.config.end_height_m,
            )

    def _observe(self, env_ms: dict[str, float], reports: list[IterationReport]) -> Any:
        """The observation; the step's iterations (``reports``) enter the coverage memory."""
        with stage_timer(env_ms, "observation_ms"):
            state = pipeline_state(
                self._session, self._last_report, self._actions.normalised, self._previous_action
            )
            self._drawing = draw_state(state, self.config.observation)
            extras: dict[str, np.ndarray] = {}
            if self._coverage is not None:
                if reports:
                    self._remember(state, reports)
                extras[COVERAGE_KEY] = self._coverage.as_array().ravel()
            if self._priced:
                extras[PRICE_KEY] = np.array([self._price], np.float32)
            return make_observation(
                state, self._drawing, self.config.observation, self.config.flatten, extras
            )

    def _remember(self, state: PipelineState, reports: list[IterationReport]) -> None:
        """Put the latest iteration's view, candidates and model, and the points every
        iteration of the step found in front of the model, into the coverage memory."""
        session, K = self._session, state.intrinsics
        z_target = session.controller.config.z_target_m
        camera_z = session.camera_height_m
        candidates = self._drawing.candidates
        unconfirmed_rows = [curve.samples_px[0, 1] for curve, ok in candidates if not ok]
        heights = rows_to_heights_m(np.array(unconfirmed_rows), camera_z, K.cy, K.fy, z_target)
        found = np.array([b.points[0, 2] for b in state.model.secondaries if len(b.points)])
        half_m = session.vertical_fov_m / 2.0
        disagreed = state.outcome is not None and state.outcome is not Outcome.CONSISTENT
        in_front = np.concatenate([report.points_in_front[:, 2] for report in reports])
        self._coverage.update(
            camera_z - half_m,
            camera_z + half_m,
            session.angle_deg,
            heights,
            found,
            camera_z if disagreed else None,
            in_front,
        )

    def _branch_value_s(self, fixed_s: float | None) -> float | None:
        """This episode's branch value (s): the reset option, else drawn log-uniformly."""
        if not self._priced:
            if fixed_s is not None:
                raise ValueError("reset option 'branch_value_s' needs an env with branch_value_s")
            return None
        low, high = self.config.branch_value_s
        if fixed_s is not None and not low <= fixed_s <= high:
            raise ValueError(
                f"reset option 'branch_value_s' must lie in this env's branch_value_s range "
                f"[{low:g}, {high:g}] s, got {fixed_s:g}: the observation's price would read "
                "the range's end"
            )
        value = fixed_s
        if value is None:
            value = draw_branch_value_s(self.np_random, (low, high))
        self._price = price_feature(value, (low, high))
        return value

    def _info(
        self,
        metrics: TreeMetrics,
        terms: dict[str, float],
        reports: list[IterationReport],
        rotated: bool,
        env_ms: dict[str, float],
    ) -> dict[str, Any]:
        info = step_info(self._session, self._seed, metrics, self._last_report, reports, rotated)
        info["reward_terms"] = dict(terms)
        if self.config.info_timings:
            info["timings_ms"] = step_timings(reports, env_ms)
        return info
