"""dvnav/Nav-v0 as Gymnasium defines an environment: API, spaces, determinism, config, errors."""

import math

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import dvnav


def rollout(env, actions, seed):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, r, te, tr, _ = env.step(a)
        out.append(np.append(obs, [r, te, tr]))
        if te or tr:
            obs, _ = env.reset()
            out.append(obs)
    return out


def test_passes_gymnasiums_env_checker():
    env = gymnasium.make("dvnav/Nav-v0", room="env3", seed=0, render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)


def test_spaces_are_the_training_observation_and_the_normalized_action():
    env = gymnasium.make("dvnav/Nav-v0", room="env3", seed=0)
    assert env.observation_space.shape == (544,) and env.observation_space.dtype == np.float32
    assert env.action_space.shape == (2,)
    assert (env.action_space.low == -1).all() and (env.action_space.high == 1).all()
    obs, info = env.reset()
    assert env.observation_space.contains(obs)
    assert set(info) == {"room", "start", "goal"} and info["room"] == "env3"
    high = env.observation_space.high
    assert high[0] == 10.0 and high[542] == 0.5, "range_max and v_max bound the entries"
    # Full speed ahead: a = (1, 0) is v_max; the observation reports the command back.
    obs, *_ = env.step([1.0, 0.0])
    assert obs[542] == pytest.approx(0.5) and obs[543] == 0.0


def test_the_same_seed_replays_the_same_episodes():
    rng = np.random.default_rng(5)
    actions = rng.uniform(-1, 1, size=(600, 2)).astype(np.float32)
    a = rollout(gymnasium.make("dvnav/Nav-v0", room="env2"), actions, seed=11)
    b = rollout(gymnasium.make("dvnav/Nav-v0", room="env2"), actions, seed=11)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    c = rollout(gymnasium.make("dvnav/Nav-v0", room="env2"), actions, seed=12)
    assert not np.array_equal(a[0], c[0])
    # A seed at construction is the first episode of reset() without one.
    env = gymnasium.make("dvnav/Nav-v0", room="env2", seed=11)
    assert np.array_equal(env.reset()[0], a[0])


def test_episodes_end_as_the_trainer_ends_them():
    env = gymnasium.make("dvnav/Nav-v0", room="env0", seed=3, max_steps=5)
    env.reset()
    for _ in range(4):
        _, _, te, tr, info = env.step([-1.0, 0.0])  # standing still
        assert not te and not tr and info == {}
    _, r, te, tr, info = env.step([-1.0, 0.0])
    assert (te, tr, info["outcome"]) == (False, True, "timeout"), "max_steps truncates"
    assert r == pytest.approx(-dvnav.NavEnv(room="env0").env_config["reward"]["time_penalty"])

    # Driving into a wall: a collision terminates with r_c.
    env = gymnasium.make("dvnav/Nav-v0", room="env0", seed=3)
    env.reset(options={"start": (0.0, 3.3, np.pi / 2), "goal": (0.0, -3.0)})
    for _ in range(50):
        _, r, te, tr, info = env.step([1.0, 0.0])
        if te or tr:
            break
    assert (te, info["outcome"], info["is_success"]) == (True, "collision", False)
    assert r == env.unwrapped.env_config["reward"]["collision"]


def test_every_room_name_and_env_config_key_is_accepted():
    for name in dvnav.room_names():
        env = gymnasium.make("dvnav/Nav-v0", room=name, seed=0)
        assert env.reset()[1]["room"] == name
    env = gymnasium.make(
        "dvnav/Nav-v0", room="env3", seed=0, lidar={"beams": 90, "noise_std": 0.01}, v_max=0.8
    )
    assert env.observation_space.shape == (94,)
    cfg = env.unwrapped.env_config
    assert cfg["lidar"]["beams"] == 90 and cfg["lidar"]["fov_deg"] == 270.0 and cfg["v_max"] == 0.8


def test_a_sensor_file_or_dict_observes_through_that_lidar(root):
    hokuyo = root / "sensors/hokuyo-ust10lx-front.toml"
    env = gymnasium.make("dvnav/Nav-v0", room="env3", seed=3, sensor=str(hokuyo))
    meta = gymnasium.make("dvnav/Nav-v0", room="env3", seed=3)
    assert env.unwrapped.env_config["sensor"]["beams"] == 1081
    assert env.observation_space.shape == meta.observation_space.shape, "still the meta layout"
    obs, _ = env.reset()
    ref, _ = meta.reset()
    scan, truth = obs[:540], ref[:540]
    # The same start seen through a sensor 0.1 m ahead: close to the meta scan, nothing inside
    # the robot (0.2 m).
    assert scan.min() >= 0.2 and np.median(np.abs(scan - truth)) < 0.05
    env = gymnasium.make(
        "dvnav/Nav-v0", room="env3", seed=3,
        sensor={"beams": 360, "fov_deg": 360.0, "range_min": 0.1, "range_max": 5.0, "no_return": "zero"},
    )
    assert env.reset()[0][:540].max() <= 5.0
    with pytest.raises(ValueError, match="env.sensor.fov_deg"):
        gymnasium.make("dvnav/Nav-v0", room="env3", sensor={"beams": 10, "fov_deg": 400.0, "range_min": 0, "range_max": 5})


def test_a_curriculum_moves_to_the_next_room_at_the_next_reset():
    env = gymnasium.make("dvnav/Nav-v0", room="env0", seed=0)
    env.reset()
    env.unwrapped.set_room("env3")
    env.step([0.0, 0.0])
    assert env.unwrapped._core.room == "env0", "the episode under way keeps its room"
    assert env.reset()[1]["room"] == "env3"
    envs = dvnav.NavVectorEnv(num_envs=2, room="env0", seed=0)
    envs.reset()
    envs.set_room("env2")
    envs.reset()
    assert [envs.state(i)[0] for i in range(2)] == ["env2", "env2"]
    with pytest.raises(ValueError, match="unknown room"):
        envs.set_room("nowhere")


def test_a_run_config_and_a_footprint_file(root):
    env = gymnasium.make("dvnav/Nav-v0", room="env0", seed=0, config=str(root / "configs/sac_ri.toml"))
    assert env.observation_space.shape == (545,), "the SAC_RI run appends the radius"
    env = gymnasium.make("dvnav/Nav-v0", room="env0", seed=0, footprint=str(root / "footprints/circle-0.5.toml"))
    env.reset()
    assert env.unwrapped._core.robot_radius == pytest.approx(0.5)


@pytest.mark.parametrize(
    "kwargs, says",
    [
        ({"room": "env9"}, "unknown room `env9`"),
        ({"room": "env3", "max_step": 3}, "unknown field `max_step`"),
        ({"room": "env3", "dt": -1.0}, "env.dt"),
        ({"room": "env3", "footprint": "/no/such.toml"}, "/no/such.toml"),
    ],
)
def test_bad_arguments_say_what_is_wrong(kwargs, says):
    with pytest.raises(ValueError, match=None) as e:
        gymnasium.make("dvnav/Nav-v0", seed=0, **kwargs)
    assert says in str(e.value)


def test_only_rgb_array_frames():
    # gymnasium.make wraps "human" in its HumanRendering over rgb_array; the class says no.
    with pytest.raises(ValueError, match="rgb_array"):
        dvnav.NavEnv(room="env3", seed=0, render_mode="human")


def test_a_bad_action_is_refused():
    env = gymnasium.make("dvnav/Nav-v0", room="env3", seed=0).unwrapped
    env.reset()
    with pytest.raises(ValueError, match="expected \\(2,\\)"):
        env.step([0.1, 0.2, 0.3])


def test_frames_come_from_dvnavs_renderer():
    env = gymnasium.make("dvnav/Nav-v0", room="env1", seed=0, render_mode="rgb_array", render_size=128)
    env.reset()
    frame = env.render()
    assert frame.shape == (128, 128, 3) and frame.dtype == np.uint8
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 5, "room, robot, rays, goal"
    assert env.metadata["render_fps"] == pytest.approx(5.0), "one frame per control period"


def test_long_tasks_with_subgoals_observe_the_lookahead_point():
    env = gymnasium.make("dvnav/Nav-v0", room="generated:rooms:8001", seed=2, tasks="long", subgoals=True)
    obs, info = env.reset()
    start, goal = info["start"], info["goal"]
    assert 5.0 <= math.hypot(goal[0] - start[0], goal[1] - start[1]) <= 10.0
    path, sub = info["path"], info["subgoal"]
    assert path[0] == pytest.approx(start[:2]) and path[-1] == pytest.approx(goal)
    # The observation's goal is the lookahead point on the path, not the goal.
    assert obs[-4] == pytest.approx(math.hypot(sub[0] - start[0], sub[1] - start[1]), abs=1e-4)
    assert obs[-4] <= 1.5 + 1e-4
    assert env.unwrapped.env_config["subgoals"]["lookahead_m"] == 1.5
    assert env.unwrapped.env_config["subgoals"]["time_limit_factor"] == 4.0
    _, _, _, _, info = env.step(np.zeros(2, np.float32))
    assert "subgoal" in info and "shim_command" in info
    plain = gymnasium.make("dvnav/Nav-v0", room="env3", seed=2)
    assert "subgoal" not in plain.reset()[1]
    with pytest.raises(ValueError, match="tasks="):
        gymnasium.make("dvnav/Nav-v0", room="env3", tasks="medium")
