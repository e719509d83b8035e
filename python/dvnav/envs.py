"""``dvnav/Nav-v0``: dvnav's navigation task as a Gymnasium environment and vector environment.

The observation is the one ``dvnav train`` feeds its agent, in physical units: the LiDAR scan
(540 ranges in metres by default), the goal's distance (m) and bearing in the robot frame (rad,
left positive), and the last commanded v (m/s) and ω (rad/s). The action is the agent's
normalized command in [-1, 1]²: v = (a0 + 1)/2 · v_max, ω = a1 · ω_max. The reward is the
paper's; an episode terminates on reaching the goal or a collision and is truncated at
``max_steps``. Rooms are every name ``dvnav`` accepts (``dvnav.room_names()``) or a room file,
and every key of a run config's ``[env]`` section is a keyword argument (nested sections as
dicts: ``lidar={"noise_std": 0.01}``), or ``config=`` names a run config whose ``[env]`` is used.
``sensor=`` observes through a real robot's LiDAR: a sensor file (``sensors/*.toml``) or its
keys as a dict; the scan is simulated at the sensor's mounting and resampled to the meta agent's
beams as ``dvnav serve`` does.

``tasks="long"`` draws goals 5-10 m away by any route (``"local"``: 2-5 m, a path at most 1.5x
the straight line), as ``dvnav eval --tasks``; ``subgoals=True`` (or the ``[env.subgoals]`` keys
as a dict) plans each episode's path for the robot and the observation's goal is the lookahead
point on it (the progress reward follows the path); with long tasks each episode's time limit is
then at least 4 times its planned path at v_max, as in ``dvnav eval``. ``info["subgoal"]``
gives that point, and ``info["shim_command"]`` the rotation shim's (v, omega) while it would
hold the robot (dvnav eval and dvnav serve apply it; a Gymnasium agent decides itself).
"""

from __future__ import annotations

import json
import os
import secrets
import tomllib
from typing import Any, Sequence

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from dvnav import _core

#: Start-goal bounds of ``tasks=``: the held-out suite's local tasks and ``dvnav eval``'s long.
TASKS = {
    "local": {"min_start_goal_distance": 2.0, "max_start_goal_distance": 5.0, "max_path_ratio": 1.5},
    "long": {"min_start_goal_distance": 5.0, "max_start_goal_distance": 10.0, "max_path_ratio": 0.0},
}

#: Outcome codes of the vector environment's ``info["outcome"]``.
OUTCOMES = ("running", "success", "collision", "timeout", "reset")


def _spaces(core) -> tuple[spaces.Box, spaces.Box]:
    low, high = core.obs_bounds()
    obs = spaces.Box(np.array(low, np.float32), np.array(high, np.float32), dtype=np.float32)
    act = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
    return obs, act


# `dvnav eval --tasks long`'s step-limit factor: at least 4 times the planned path at v_max.
LONG_TASK_TIME_LIMIT_FACTOR = 4.0


def _random_seed() -> int:
    return secrets.randbits(63)


def _core_kwargs(render_mode, footprint, config, env_config) -> dict[str, Any]:
    """Checks the render mode and shapes the arguments both Rust classes take."""
    if render_mode is not None and render_mode not in ("rgb_array",):
        raise ValueError(f"render_mode {render_mode!r}: dvnav renders 'rgb_array' only")
    env_config = dict(env_config)
    tasks = env_config.pop("tasks", None)
    if tasks is not None:
        if tasks not in TASKS:
            raise ValueError(f"tasks={tasks!r}: one of {', '.join(map(repr, TASKS))}")
        env_config = {**TASKS[tasks], **env_config}
    subgoals = env_config.get("subgoals")
    if subgoals is True:
        env_config["subgoals"] = {}
    elif subgoals is False or subgoals is None:
        env_config.pop("subgoals", None)
    if tasks == "long" and isinstance(env_config.get("subgoals"), dict):
        # As `dvnav eval --tasks long`: a route's time limit grows with its planned path.
        env_config["subgoals"] = {"time_limit_factor": LONG_TASK_TIME_LIMIT_FACTOR, **env_config["subgoals"]}
    sensor = env_config.get("sensor")
    if isinstance(sensor, (str, os.PathLike)):
        try:
            with open(sensor, "rb") as f:
                env_config = {**env_config, "sensor": tomllib.load(f)}
        except (OSError, tomllib.TOMLDecodeError) as e:
            raise ValueError(f"sensor file {os.fspath(sensor)}: {e}") from e
    return {
        "footprint": None if footprint is None else str(footprint),
        "config": None if config is None else str(config),
        "env_config": json.dumps(env_config),
    }


class NavEnv(gymnasium.Env):
    """One dvnav environment: a room, a robot (the meta robot, or ``footprint``), a goal.

    Args:
        room: a built-in room (``"env0"`` ... ``"env3"``, ``"sac_ri"``, ``"gate"``,
            ``"dynamic"``) or a room file; a file with several rooms is cycled per episode.
        footprint: a footprint file for the robot (default: the config's circular robot).
        seed: seeds the first episode (``reset(seed=...)`` reseeds); ``None`` draws one.
        config: a run config file (TOML) whose ``[env]`` section is the base.
        render_mode: ``"rgb_array"`` for frames from dvnav's renderer, or ``None``.
        render_size: frame side in pixels.
        **env_config: ``[env]`` keys over the base, e.g. ``max_steps=200``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(
        self,
        room: str = "env3",
        footprint: str | None = None,
        seed: int | None = None,
        config: str | None = None,
        render_mode: str | None = None,
        render_size: int = 400,
        **env_config: Any,
    ):
        kwargs = _core_kwargs(render_mode, footprint, config, env_config)
        self._seed = _random_seed() if seed is None else int(seed)
        self._core = _core.Env(str(room), self._seed, **kwargs)
        self.observation_space, self.action_space = _spaces(self._core)
        self.render_mode = render_mode
        self.render_size = int(render_size)
        # One frame per control period.
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.env_config["dt"]}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Starts an episode. ``options={"start": (x, y, yaw), "goal": (x, y)}`` drives a
        given task (not checked for clearance) instead of a drawn one."""
        super().reset(seed=seed)
        if seed is not None:
            obs = self._core.reset(int(seed))
        else:
            obs = self._core.reset(None)
        if options and ("start" in options or "goal" in options):
            if not ("start" in options and "goal" in options):
                raise ValueError("options: give both 'start' (x, y, yaw) and 'goal' (x, y)")
            start = tuple(float(x) for x in options["start"])
            goal = tuple(float(x) for x in options["goal"])
            if len(start) != 3 or len(goal) != 2:
                raise ValueError("options: 'start' is (x, y, yaw) and 'goal' is (x, y)")
            obs = self._core.reset_to(start, goal)
        return obs, self._reset_info()

    def step(self, action):
        a = np.asarray(action, dtype=np.float32).reshape(-1)
        if a.shape != (2,):
            raise ValueError(f"action has shape {np.shape(action)}; expected (2,)")
        obs, reward, terminated, truncated, outcome = self._core.step(float(a[0]), float(a[1]))
        info: dict[str, Any] = {}
        if outcome is not None:
            info = {"outcome": outcome, "is_success": outcome == "success"}
        return obs, float(reward), terminated, truncated, self._route_info(info)

    def _route_info(self, info: dict[str, Any]) -> dict[str, Any]:
        """With subgoals: the subgoal the observation shows and the rotation shim's command."""
        subgoal = self._core.subgoal
        if subgoal is not None:
            info = {**info, "subgoal": subgoal, "shim_command": self._core.shim_command}
        return info

    def step_velocity(self, v: float, omega: float):
        """Like :meth:`step` with a command in physical units (m/s, rad/s)."""
        obs, reward, terminated, truncated, outcome = self._core.step_velocity(float(v), float(omega))
        info = {} if outcome is None else {"outcome": outcome, "is_success": outcome == "success"}
        return obs, float(reward), terminated, truncated, self._route_info(info)

    def set_room(self, room: str) -> None:
        """Runs the next episodes (from the next reset on) in ``room``: a curriculum's next
        stage."""
        self._core.set_room(str(room))

    def render(self):
        if self.render_mode == "rgb_array":
            return self._core.render(self.render_size)
        return None

    def _reset_info(self) -> dict[str, Any]:
        info = {"room": self._core.room, "start": self._core.start, "goal": self._core.goal}
        if self._core.subgoal is not None:
            info["path"] = self._core.planned_path
        return self._route_info(info)

    @property
    def pose(self) -> tuple[float, float, float]:
        """The robot's pose (x, y, yaw) in the room frame."""
        return self._core.pose

    @property
    def goal(self) -> tuple[float, float]:
        """The goal (x, y) in the room frame."""
        return self._core.goal

    @property
    def env_config(self) -> dict[str, Any]:
        """The ``[env]`` section in force."""
        return json.loads(self._core.env_config)


class NavVectorEnv(VectorEnv):
    """``num_envs`` dvnav environments stepped together in Rust threads, without the GIL.

    Autoreset is Gymnasium's ``NEXT_STEP``: the step after an episode ends resets that
    environment (its action is ignored, reward 0, both flags false). ``info["outcome"]`` holds
    each environment's code (see :data:`OUTCOMES`). Environment ``i`` is seeded ``seed + i``;
    the other arguments are :class:`NavEnv`'s.
    """

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        room: str = "env3",
        footprint: str | None = None,
        seed: int | None = None,
        config: str | None = None,
        render_mode: str | None = None,
        render_size: int = 400,
        **env_config: Any,
    ):
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        kwargs = _core_kwargs(render_mode, footprint, config, env_config)
        base = _random_seed() if seed is None else int(seed)
        self.num_envs = int(num_envs)
        self._core = _core.VecEnv(str(room), [base + i for i in range(self.num_envs)], **kwargs)
        self.single_observation_space, self.single_action_space = _spaces(self._core)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = render_mode
        self.render_size = int(render_size)
        self._fresh = True

    def reset(
        self,
        *,
        seed: int | Sequence[int] | None = None,
        options: dict[str, Any] | None = None,
    ):
        """Resets every environment: ``seed`` an int (environment ``i`` gets ``seed + i``) or
        one seed each; ``None`` moves each to its next episode."""
        super().reset(seed=seed if isinstance(seed, int) or seed is None else None)
        if seed is None:
            obs = self._core.observations() if self._fresh else self._core.reset(None)
        else:
            seeds = [seed + i for i in range(self.num_envs)] if isinstance(seed, int) else list(seed)
            obs = self._core.reset([int(s) for s in seeds])
        self._fresh = False
        return obs, {}

    def step(self, actions):
        a = np.ascontiguousarray(actions, dtype=np.float32).reshape(self.num_envs, 2)
        obs, rewards, terminated, truncated, outcome = self._core.step(a)
        self._fresh = False
        return obs, rewards, terminated, truncated, {"outcome": outcome}

    def set_room(self, room: str) -> None:
        """Runs every environment's next episodes in ``room``, from each one's next reset."""
        self._core.set_room(str(room))

    def render(self):
        if self.render_mode == "rgb_array":
            return tuple(self._core.render(i, self.render_size) for i in range(self.num_envs))
        return None

    def state(self, i: int) -> tuple[str, tuple[float, float, float], tuple[float, float]]:
        """Environment ``i``'s room, pose (x, y, yaw) and goal (x, y)."""
        return self._core.state(i)
