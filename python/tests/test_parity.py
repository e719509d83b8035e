"""The Python environment and policy against dvnav's own evaluation, in Rust: `dvnav eval` runs
the shipped agent on the curriculum rooms (routes and random episodes, one at a time) and writes
each episode's seed, start, goal, outcome, steps, path length and return; the same episodes
driven from Python (dvnav/Nav-v0 + dvnav.Policy) must end the same way, step for step."""

import csv
import math
import subprocess

import gymnasium
import numpy as np

import dvnav
from conftest import MODEL


def drive(env, policy, obs):
    """Runs one leg to its end: (outcome, steps, path length, return)."""
    steps, path, ret = 0, 0.0, 0.0
    x0, y0, _ = env.unwrapped.pose
    while True:
        obs, r, te, tr, info = env.step(policy(obs))
        x, y, _ = env.unwrapped.pose
        path += math.hypot(x - x0, y - y0)
        x0, y0 = x, y
        steps += 1
        ret += r
        if te or tr:
            return obs, (info["outcome"], steps, path, ret)


def test_episodes_of_dvnav_eval_replay_step_for_step_in_python(tmp_path, dvnav_bin):
    out = tmp_path / "eval"
    subprocess.run(
        [str(dvnav_bin), "eval", "--checkpoint", str(MODEL), "--episodes", "3", "--batch", "1",
         "--seed", "5", "--out-dir", str(out)],
        check=True, capture_output=True,
    )
    rows = list(csv.DictReader(open(out / "episodes.csv")))
    assert len(rows) >= 12
    policy = dvnav.Policy.load(str(MODEL))
    env_config = policy.eval_env_config
    checked = 0
    by_task = {}
    for row in rows:
        by_task.setdefault(row["task"], []).append(row)
    for legs in by_task.values():
        first = legs[0]
        env = gymnasium.make("dvnav/Nav-v0", room=first["room"], seed=int(first["seed"]), **env_config)
        if first["kind"] == "random":
            # dvnav eval builds each episode's environment from its seed (which draws a first
            # episode) and resets it once more: its random episode is the seed's second.
            env.reset()
            obs, info = env.reset()
            assert np.allclose(info["start"], [float(first[k]) for k in ("start_x", "start_y", "start_yaw")], atol=1e-4)
            assert np.allclose(info["goal"], [float(first["goal_x"]), float(first["goal_y"])], atol=1e-4)
        else:
            start = [float(first[k]) for k in ("start_x", "start_y", "start_yaw")]
            obs, _ = env.reset(options={"start": start, "goal": (float(first["goal_x"]), float(first["goal_y"]))})
        for k, row in enumerate(legs):
            if k > 0:
                obs, _ = env.reset(options={"start": env.unwrapped.pose,
                                            "goal": (float(row["goal_x"]), float(row["goal_y"]))})
            obs, (outcome, steps, path, ret) = drive(env, policy, obs)
            assert (outcome, steps) == (row["outcome"], int(row["steps"])), row
            assert abs(path - float(row["path_length_m"])) < 1e-3, row
            assert abs(ret - float(row["episode_return"])) < 1e-3, row
            checked += 1
    assert checked == len(rows)
