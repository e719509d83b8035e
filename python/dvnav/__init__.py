"""dvnav from Python: the simulator as Gymnasium environments, the trained agent as a policy.

    import gymnasium, dvnav
    env = gymnasium.make("dvnav/Nav-v0", room="env3", seed=0)
    envs = gymnasium.make_vec("dvnav/Nav-v0", num_envs=64, room="env3", seed=0)
    policy = dvnav.Policy.load("models/meta-r0.2")

Environments, rooms, rewards and the agent are dvnav's own Rust code (the extension module
``dvnav._core``); this package only shapes them as Gymnasium expects.
"""

import gymnasium

from dvnav._core import Route, __version__, default_env_config, room_names
from dvnav.envs import NavEnv, NavVectorEnv
from dvnav.policy import Policy

__all__ = [
    "NavEnv",
    "NavVectorEnv",
    "Policy",
    "Route",
    "room_names",
    "default_env_config",
    "__version__",
]

ENV_ID = "dvnav/Nav-v0"

if ENV_ID not in gymnasium.registry:
    # No max_episode_steps: the environment truncates at its own env.max_steps, as in training.
    gymnasium.register(
        id=ENV_ID,
        entry_point="dvnav.envs:NavEnv",
        vector_entry_point="dvnav.envs:NavVectorEnv",
    )
