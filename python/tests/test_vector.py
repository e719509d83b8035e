"""The vector environment: Gymnasium's VectorEnv API, NEXT_STEP autoreset, and the same episodes
as single environments of the same seeds."""

import gymnasium
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import dvnav


def test_make_vec_gives_dvnavs_vector_env():
    envs = gymnasium.make_vec("dvnav/Nav-v0", num_envs=4, room="env3", seed=0)
    assert isinstance(envs.unwrapped, dvnav.NavVectorEnv)
    assert envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert envs.observation_space.shape == (4, 544) and envs.action_space.shape == (4, 2)
    obs, _ = envs.reset()
    assert obs.shape == (4, 544) and obs.dtype == np.float32 and obs.flags["C_CONTIGUOUS"]
    obs, rewards, te, tr, info = envs.step(envs.action_space.sample())
    assert rewards.dtype == np.float32 and te.dtype == bool and tr.dtype == bool
    assert info["outcome"].shape == (4,)


def test_each_environment_runs_the_episodes_of_a_single_env_with_its_seed():
    n, seed, steps = 6, 40, 500
    rng = np.random.default_rng(1)
    actions = rng.uniform(-1, 1, size=(steps, n, 2)).astype(np.float32)
    envs = dvnav.NavVectorEnv(num_envs=n, room="env1", seed=seed, max_steps=60)
    singles = [dvnav.NavEnv(room="env1", seed=seed + i, max_steps=60) for i in range(n)]
    obs, _ = envs.reset()
    for i, e in enumerate(singles):
        assert np.array_equal(obs[i], e.reset()[0])
    ended = np.zeros(n, dtype=bool)
    resets = 0
    for t in range(steps):
        obs, rewards, te, tr, info = envs.step(actions[t])
        for i, e in enumerate(singles):
            if ended[i]:
                # NEXT_STEP: this step reset environment i; its action was ignored.
                want, _ = e.reset()
                assert info["outcome"][i] == 4 and rewards[i] == 0 and not te[i] and not tr[i]
                resets += 1
            else:
                want, r, t_e, t_r, _ = e.step(actions[t, i])
                assert (rewards[i], te[i], tr[i]) == (np.float32(r), t_e, t_r)
            assert np.array_equal(obs[i], want), f"env {i} step {t}"
        ended = te | tr
    assert resets > n, "episodes ended and restarted"


def test_reseeding_with_one_seed_each_or_a_base_seed():
    envs = dvnav.NavVectorEnv(num_envs=3, room="env2", seed=0)
    a, _ = envs.reset(seed=7)
    b, _ = envs.reset(seed=[7, 8, 9])
    assert np.array_equal(a, b)
    assert np.array_equal(a[1], dvnav.NavEnv(room="env2", seed=8).reset()[0])
    c, _ = envs.reset()
    assert not np.array_equal(a, c), "no seed: the next episodes"
    with pytest.raises(ValueError, match="2 seeds for 3 environments"):
        envs.reset(seed=[1, 2])


def test_wrong_actions_are_refused():
    envs = dvnav.NavVectorEnv(num_envs=3, room="env2", seed=0)
    envs.reset()
    with pytest.raises(ValueError):
        envs.step(np.zeros((2, 2), np.float32))


def test_frames_of_every_environment():
    envs = dvnav.NavVectorEnv(num_envs=2, room="env2", seed=0, render_mode="rgb_array", render_size=64)
    envs.reset()
    frames = envs.render()
    assert len(frames) == 2 and frames[0].shape == (64, 64, 3)
    assert not np.array_equal(frames[0], frames[1])
