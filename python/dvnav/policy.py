"""``dvnav.Policy``: a trained dvnav agent, callable on observations from Python."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from dvnav import _core


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
    def load(cls, path: str, footprint: str | None = None, margin: float | None = None) -> "Policy":
        """Loads ``path`` (a model or checkpoint directory, or its ``policy.safetensors``);
        ``footprint``: a footprint file for DVST; ``margin`` (m) replaces its margin."""
        return cls(_core.Policy.load(str(path), None if footprint is None else str(footprint), margin))

    def __call__(self, obs) -> np.ndarray:
        return self.actions(obs)

    def actions(self, obs) -> np.ndarray:
        """Normalized actions, shape (2,) for one observation or (n, 2) for n."""
        return self._run(self._core.actions, obs)

    def velocities(self, obs) -> np.ndarray:
        """Commands (v m/s, ω rad/s), shape (2,) or (n, 2)."""
        return self._run(self._core.velocities, obs)

    def _run(self, fn, obs) -> np.ndarray:
        x = np.ascontiguousarray(obs, dtype=np.float32)
        if x.ndim == 1:
            return fn(x.reshape(1, -1))[0]
        if x.ndim != 2:
            raise ValueError(f"observations have shape {x.shape}; expected (obs_dim,) or (n, obs_dim)")
        return fn(x)

    @property
    def obs_dim(self) -> int:
        """Length of one observation."""
        return self._core.obs_dim

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
        makes environments it was trained for."""
        return json.loads(self._core.env_config)
