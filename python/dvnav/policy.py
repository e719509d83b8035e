"""``dvnav.Policy``: a trained dvnav agent, callable on observations from Python."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from dvnav import _core
from dvnav._core import Route


class Policy:
    """The deterministic policy of a dvnav model or checkpoint (``models/meta-r0.2``), the
    same network and weights ``dvnav eval`` and ``dvnav serve`` run.

    With ``footprint`` (a footprint file) it is the meta agent in DVST for that robot: give it
    that robot's own observations and it answers within that robot's velocity bounds, with no
    retraining. ``policy(obs)`` returns normalized actions in [-1, 1]² for environments made
    with the model's env config (:attr:`env_config`); :meth:`velocities` returns (v, ω) in m/s
    and rad/s. Both take one observation or a batch (one row each).
    """

    def __init__(self, core: Any):
        self._core = core

    @classmethod
    def load(
        cls,
        path: str,
        footprint: str | None = None,
        margin: float | None = None,
        safety_horizon: float = 0.0,
    ) -> "Policy":
        """Loads ``path`` (a model or checkpoint directory, or its ``policy.safetensors``);
        ``footprint``: a footprint file for DVST; ``margin`` (m) replaces its margin.

        ``safety_horizon`` (seconds, 0: off) runs a collision monitor on every command, as
        ``dvnav serve --safety-horizon`` and ``dvnav eval --safety-horizon`` do: v is scaled
        down so that the robot, driving the command that long, would not reach a return of the
        observation's scan (ω is the policy's). 0.6 took dense held-out clutter at R = 0.6 from
        93.9 to 98.7 % with no collision on long routes (docs/results.md, "A collision
        monitor")."""
        return cls(
            _core.Policy.load(
                str(path), None if footprint is None else str(footprint), margin, float(safety_horizon)
            )
        )

    def __call__(self, obs, noise=None) -> np.ndarray:
        return self.actions(obs, noise)

    def actions(self, obs, noise=None) -> np.ndarray:
        """Normalized actions, shape (2,) for one observation or (n, 2) for n. ``noise``: see
        :meth:`velocities`."""
        return self._run(self._core.actions, obs, noise)

    def velocities(self, obs, noise=None) -> np.ndarray:
        """Commands (v m/s, ω rad/s), shape (2,) or (n, 2). ``noise``: ε = (ε_v, ε_ω) to sample
        the policy's own distribution, tanh(μ + σ·ε), instead of its deterministic action: what
        :meth:`escape`'s watch returns (None: deterministic); for a batch, one pair or None per
        row."""
        return self._run(self._core.velocities, obs, noise)

    def escape(self, after_s: float = 3.0, seed: int = 0):
        """The stall escape's watch for one robot (``dvnav eval --escape-after``, ``dvnav serve
        --escape-after``): each cycle ``eps = escape.noise(t, goal_distance)`` is None while the
        robot makes progress and, after ``after_s`` seconds in which its goal distance has not
        come down by half its radius, the noise for :meth:`velocities` for ``after_s`` seconds.
        ``escape.reset()`` on a new goal. 3 s was best on tuning rooms; it frees big robots
        frozen in tight clutter (docs/results.md, "The stall escape")."""
        radius_m = self.env_config["robot_radius"] * self.mu
        return _core.StallEscape.for_radius(float(after_s), radius_m, int(seed))

    def carry_forward(self, obs, commands, dt: float | None = None) -> np.ndarray:
        """Latency compensation: ``obs`` (one observation) was taken before the robot drove
        ``commands`` ((v m/s, ω rad/s) pairs, oldest first, each held ``dt`` seconds: default
        the model's control period); returns it as the robot reads it now, its scan and goal
        carried forward by those commands' motion (``dvnav serve``'s ``scan_age_s``, the
        environments' ``latency_compensation``). v and ω are left as given. Feed the result to
        the policy when your scans arrive a cycle or more late: one cycle of latency takes the
        shipped agent from 100 % to 92.8 % success in the paper layout at R = 0.4 (tuning
        rooms), compensated it stays at 100 % (``tests/shipped_model.rs``). In DVST (a
        footprint), the robot's own units."""
        x = np.ascontiguousarray(obs, dtype=np.float32)
        if x.shape != (self.obs_dim,):
            raise ValueError(f"observation has shape {x.shape}; expected ({self.obs_dim},)")
        pairs = [(float(v), float(w)) for v, w in np.asarray(commands, dtype=np.float64).reshape(-1, 2)]
        return self._core.carry_forward(x, pairs, None if dt is None else float(dt))

    def route(self, poses, **options) -> Route:
        """A :class:`dvnav.Route` along ``poses`` ((x, y) points, the goal last: a planner's
        path in the frame the robot's poses are in) for this policy's robot: its lookahead and
        stray distance scaled by :attr:`mu`. ``options``: ``lookahead_m``, ``rotation_shim``,
        ``replan_distance_m``, ``stall_s`` (the meta robot's, as ``[env.subgoals]``)."""
        return Route([tuple(p[:2]) for p in poses], mu=self.mu, **options)

    def follow(self, route: Route, obs, pose, dt: float | None = None):
        """One control cycle along ``route``, as ``dvnav serve`` runs a robot's ``SetRoute``:
        the robot at ``pose`` (x, y, yaw) with its observation ``obs`` (its own scan and
        velocities; the goal fields are replaced by the subgoal). Returns ``((v, ω), step)``:
        the command (the rotation shim's while it turns the robot towards a new route's
        subgoal, zero once arrived, else the policy's) and the route's step (a dict:
        ``subgoal``, ``goal_distance``, ``goal_angle``, ``remaining_m``, ``replan_wanted``
        (ask your planner for a new path), ``arrived``, ``shim``). ``dt``: seconds since the
        last cycle (default the model's control period)."""
        env = self.env_config
        step = route.step(
            tuple(float(x) for x in pose),
            env["dt"] if dt is None else float(dt),
            self.velocity_bounds[1],
            env["goal_tolerance"] * self.mu,
        )
        if step["arrived"]:
            return np.zeros(2), step
        if step["shim"] is not None:
            return np.array(step["shim"], dtype=np.float64), step
        x = np.array(obs, dtype=np.float32, copy=True)
        if x.shape != (self.obs_dim,):
            raise ValueError(f"observation has shape {x.shape}; expected ({self.obs_dim},)")
        # The observation ends with goal distance, goal angle, v and ω.
        x[-4], x[-3] = step["goal_distance"], step["goal_angle"]
        return self.velocities(x), step

    def _run(self, fn, obs, noise=None) -> np.ndarray:
        x = np.ascontiguousarray(obs, dtype=np.float32)
        if x.ndim == 1:
            n = None if noise is None else _noise_rows([noise], 1)
            return fn(x.reshape(1, -1), n)[0]
        if x.ndim != 2:
            raise ValueError(f"observations have shape {x.shape}; expected (obs_dim,) or (n, obs_dim)")
        return fn(x, None if noise is None else _noise_rows(noise, len(x)))

    @property
    def obs_dim(self) -> int:
        """Length of one observation."""
        return self._core.obs_dim

    @property
    def safety_horizon(self) -> float:
        """The collision monitor's horizon (s; 0: off)."""
        return self._core.safety_horizon

    @property
    def mu(self) -> float:
        """The DVST scale μ (1 without a footprint)."""
        return self._core.mu

    @property
    def velocity_bounds(self) -> tuple[float, float]:
        """(v_max, ω_max) of the commands: the robot's own in DVST."""
        return self._core.velocity_bounds

    @property
    def env_config(self) -> dict[str, Any]:
        """The model's ``[env]`` section: ``gymnasium.make("dvnav/Nav-v0", **policy.env_config)``
        makes environments it was trained for, with its training-time robots of other sizes
        (``dvst``), subgoal share (``subgoals``) and perturbations (``robustness``) if it had
        any; :attr:`eval_env_config` is the environment ``dvnav eval`` measures it in."""
        return json.loads(self._core.env_config)

    @property
    def eval_env_config(self) -> dict[str, Any]:
        """The environment ``dvnav eval`` drives the model in by default: its ``[env]`` section
        without what only training draws (``dvst``'s robots of other sizes, ``subgoals``'
        share of planner-followed episodes, ``robustness``' perturbations) and with a noiseless
        LiDAR, as ``dvnav eval`` builds it (``EnvConfig::clean`` in Rust). The same seed gives
        the same episodes as ``dvnav eval --seed``."""
        return json.loads(self._core.eval_env_config)


def _noise_rows(noise, n: int) -> np.ndarray:
    """(n, 2) float32: each row a pair ε or NaN for None (a deterministic row)."""
    rows = [(np.nan, np.nan) if e is None else tuple(e) for e in noise]
    out = np.ascontiguousarray(rows, dtype=np.float32)
    if out.shape != (n, 2):
        raise ValueError(f"noise has shape {out.shape}; expected ({n}, 2): one pair or None per observation")
    return out
