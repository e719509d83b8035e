"""dvnav.Policy: the shipped agent from Python, batched, and in DVST for another robot."""

import numpy as np
import pytest

import dvnav
from conftest import MODEL, ROOT


def observations(n, seed=0):
    envs = dvnav.NavVectorEnv(num_envs=n, room="env3", seed=seed)
    return envs.reset()[0]


def test_one_observation_or_a_batch_gives_the_same_actions():
    policy = dvnav.Policy.load(str(MODEL))
    obs = observations(8)
    batch = policy(obs)
    assert batch.shape == (8, 2) and batch.dtype == np.float32
    assert (np.abs(batch) <= 1).all()
    for i in range(8):
        assert np.allclose(policy(obs[i]), batch[i], atol=1e-6)
    v = policy.velocities(obs)
    v_max, w_max = policy.velocity_bounds
    assert ((0 <= v[:, 0]) & (v[:, 0] <= v_max)).all() and (np.abs(v[:, 1]) <= w_max).all()
    # The action maps back to the command: v = (a0 + 1)/2 v_max, ω = a1 ω_max.
    assert np.allclose((batch[:, 0] + 1) / 2 * v_max, v[:, 0], atol=1e-5)
    assert np.allclose(batch[:, 1] * w_max, v[:, 1], atol=1e-5)


def test_in_dvst_a_bigger_robot_is_driven_in_the_meta_robots_frame():
    meta = dvnav.Policy.load(str(MODEL))
    big = dvnav.Policy.load(str(MODEL), footprint=str(ROOT / "footprints/circle-0.5.toml"))
    assert big.mu == pytest.approx(2.5) and meta.mu == 1.0
    # The big robot's observation, scaled by 1/μ, is what the meta agent sees: with every
    # length divided by μ the meta agent's command, with v scaled back by μ within bounds.
    fp = str(ROOT / "footprints/circle-0.5.toml")
    obs, _ = dvnav.NavVectorEnv(num_envs=32, room="env0", seed=2, footprint=fp).reset()
    scaled = obs.copy()
    scaled[:, :540] = np.clip(obs[:, :540] / big.mu, 0.02, 10.0)
    scaled[:, 540] /= big.mu
    scaled[:, 542] /= big.mu
    meta_cmd = meta.velocities(scaled)
    cmd = big.velocities(obs)
    v_max, w_max = big.velocity_bounds
    assert (cmd[:, 0] <= v_max + 1e-12).all() and (np.abs(cmd[:, 1]) <= w_max + 1e-12).all()
    # Where μ·v of the meta command is within the big robot's bounds, DVST passes it as is.
    free = (meta_cmd[:, 0] * big.mu <= v_max) & (np.abs(meta_cmd[:, 1]) <= w_max)
    assert free.sum() >= 4, "some commands are within the bounds"
    assert np.allclose(cmd[free, 0], meta_cmd[free, 0] * big.mu)
    assert np.allclose(cmd[free, 1], meta_cmd[free, 1])


def test_the_shipped_agent_reaches_goals_in_its_training_room():
    policy = dvnav.Policy.load(str(MODEL))
    envs = dvnav.NavVectorEnv(num_envs=20, room="env3", seed=100, **policy.env_config)
    obs, _ = envs.reset()
    done = np.zeros(20, dtype=bool)
    success = np.zeros(20, dtype=bool)
    for _ in range(400):
        obs, _, te, tr, info = envs.step(policy(obs))
        success |= ~done & (info["outcome"] == 1)
        done |= te | tr
        if done.all():
            break
    assert done.all() and success.mean() >= 0.9, f"{success.mean():.0%} of 20"


@pytest.mark.parametrize(
    "args, says",
    [
        (("/no/such/model",), "no such file"),
        ((str(MODEL), None, 0.05), "a margin needs a footprint file"),
        ((str(MODEL), "/no/such.toml"), "/no/such.toml"),
    ],
)
def test_bad_loads_say_what_is_wrong(args, says):
    with pytest.raises(ValueError) as e:
        dvnav.Policy.load(*args)
    assert says in str(e.value)


def test_observations_of_the_wrong_length_are_refused():
    policy = dvnav.Policy.load(str(MODEL))
    with pytest.raises(ValueError, match="this policy takes 544"):
        policy(np.zeros((2, 100), np.float32))


def test_a_route_gives_the_lookahead_subgoal_and_refuses_bad_input():
    route = dvnav.Route([(0.0, 0.0), (10.0, 0.0)])
    s = route.step((1.0, 0.0, 0.0), 0.2, 1.0, 0.2)
    assert s["subgoal"] == pytest.approx((2.5, 0.0))
    assert (s["goal_distance"], s["goal_angle"]) == pytest.approx((1.5, 0.0))
    assert s["remaining_m"] == pytest.approx(9.0)
    assert not s["replan_wanted"] and not s["arrived"] and s["shim"] is None
    # Twice the size: twice the lookahead; facing away from a new route, the shim turns first.
    big = dvnav.Route([(0.0, 0.0), (10.0, 0.0)], mu=2.0)
    assert big.step((1.0, 0.0, 3.0), 0.2, 1.0, 0.4)["shim"] == pytest.approx((0.0, -1.0))
    assert (big.goal, big.length_m, big.lookahead_m) == ((10.0, 0.0), 10.0, 3.0)
    # Far off the path: the robot's planner should plan again.
    assert route.step((5.0, 3.0, 0.0), 0.2, 1.0, 0.2)["replan_wanted"]
    for poses, says in [([], "poses"), ([(0.0, 0.0), (float("nan"), 1.0)], r"poses\[1\]\.x")]:
        with pytest.raises(ValueError, match=says):
            dvnav.Route(poses)
    with pytest.raises(ValueError, match="lookahead_m"):
        dvnav.Route([(1.0, 1.0)], lookahead_m=-1.0)
    with pytest.raises(ValueError, match=r"pose\.yaw"):
        route.step((1.0, 0.0, float("inf")), 0.2, 1.0, 0.2)


def test_a_policy_follows_a_planners_path_to_a_goal_behind_walls():
    import gymnasium

    policy = dvnav.Policy.load(str(MODEL))
    # Long tasks in a furnished generated room (a training seed); the environment plans each
    # episode's path, which here stands for the robot's own planner, and shows the final goal.
    env = gymnasium.make(
        "dvnav/Nav-v0", room="generated:rooms:8001", seed=4, tasks="long", subgoals={"follow": False}
    )
    reached, followed = 0, 0
    for _ in range(6):
        obs, info = env.reset()
        core = env.unwrapped
        path = core._core.planned_path
        route = policy.route(path)
        assert route.goal == pytest.approx(info["goal"])
        for _ in range(1000):
            (v, w), step = policy.follow(route, obs, core.pose)
            followed += step["shim"] is None and not step["arrived"]
            obs, _, terminated, truncated, info = env.unwrapped.step_velocity(v, w)
            if terminated or truncated:
                reached += info.get("is_success", False)
                break
    assert followed > 100
    assert reached >= 5, f"{reached} of 6 goals reached along the path"


def test_carry_forward_is_the_environments_latency_compensation():
    import gymnasium

    policy = dvnav.Policy.load(str(MODEL))
    # Two environments with one cycle of latency, driven alike; one compensates in Rust.
    kwargs = dict(room="env3", robustness={"latency_steps": 1})
    delayed = gymnasium.make("dvnav/Nav-v0", **kwargs)
    compensated = gymnasium.make("dvnav/Nav-v0", latency_compensation=True, **kwargs)
    assert compensated.unwrapped.env_config["latency_compensation"]
    rng = np.random.default_rng(7)
    steps, moved = 0, 0
    for episode in range(6):
        d, _ = delayed.reset(seed=40 + episode)
        c, _ = compensated.reset(seed=40 + episode)
        for _ in range(40):
            a = rng.uniform(-1, 1, size=2).astype(np.float32)
            d, _, te, tr, _ = delayed.step(a)
            c, *_ = compensated.step(a)
            assert delayed.unwrapped.pose == pytest.approx(compensated.unwrapped.pose)
            # The command just sent is the one the delayed scan has not seen.
            carried = policy.carry_forward(d, [(d[542], d[543])])
            assert np.allclose(carried, c, atol=1e-4), np.abs(carried - c).max()
            moved += np.abs(d[:540] - c[:540]).max() > 0.01
            steps += 1
            if te or tr:
                break
    assert steps >= 40 and moved >= steps // 2, f"the scan moved on {moved} of {steps} steps"


def test_carry_forward_with_no_motion_or_bad_input():
    policy = dvnav.Policy.load(str(MODEL))
    obs = observations(1)[0]
    assert np.array_equal(policy.carry_forward(obs, []), obs)
    assert np.array_equal(policy.carry_forward(obs, [(0.0, 0.0)] * 3), obs)
    # Driving 0.5 m straight ahead (five cycles at 0.5 m/s) brings the goal 0.5 m closer when
    # it lies ahead, and what was 2 m dead ahead is 1.5 m away.
    ahead = obs.copy()
    ahead[:540] = 2.0
    ahead[540], ahead[541] = 3.0, 0.0
    out = policy.carry_forward(ahead, [(0.5, 0.0)] * 5)
    assert out[540] == pytest.approx(2.5, abs=1e-5) and out[541] == pytest.approx(0.0, abs=1e-6)
    assert out[269] == pytest.approx(1.5, abs=0.02) and out[270] == pytest.approx(1.5, abs=0.02)
    for args, says in [
        ((obs[:100], []), "expected \\(544,\\)"),
        ((obs, [(float("nan"), 0.0)]), r"commands\[0\]"),
        ((obs, [(0.1, 0.0)], 0.0), "dt is 0"),
    ]:
        with pytest.raises(ValueError, match=says):
            policy.carry_forward(*args)


def test_the_collision_monitor_slows_a_robot_short_of_an_obstacle_and_leaves_open_space_alone():
    plain = dvnav.Policy.load(str(MODEL))
    monitored = dvnav.Policy.load(str(MODEL), safety_horizon=3.0)
    assert monitored.safety_horizon == 3.0 and plain.safety_horizon == 0.0
    obs = observations(8, seed=3)
    obs[:, 540], obs[:, 541] = 3.0, 0.0  # the goal 3 m dead ahead
    # Nothing within reach: the monitor changes nothing.
    obs[:, :540] = 10.0
    assert np.array_equal(monitored.velocities(obs), plain.velocities(obs))
    # An obstacle 1.2 m ahead (beams within ±10°): the agent drives on at ~0.49 m/s, turning
    # gently; the monitor slows it so that the disc (plus 1 %) driving the command for 3 s
    # stays clear of every return, and keeps its ω.
    obs[:, 250:290] = 1.2
    free, held = plain.velocities(obs), monitored.velocities(obs)
    assert np.array_equal(held[:, 1], free[:, 1])
    assert (free[:, 0] > 0.45).all() and (held[:, 0] < free[:, 0] - 0.1).all(), held[:, 0]
    angles = np.deg2rad(-135 + 270 * (np.arange(540) + 0.5) / 540)
    returns = np.stack([1.2 * np.cos(angles[250:290]), 1.2 * np.sin(angles[250:290])], axis=1)
    for v, w in held:
        for t in np.linspace(0, 3.0, 301):
            heading = w * t
            x, y = (v * t, 0.0) if abs(w) < 1e-9 else (v / w * np.sin(heading), v / w * (1 - np.cos(heading)))
            assert np.hypot(returns[:, 0] - x, returns[:, 1] - y).min() >= 0.2, (v, w, t)


def test_the_collision_monitor_in_dvst_is_the_meta_robots_scaled():
    fp = str(ROOT / "footprints/circle-0.5.toml")
    meta = dvnav.Policy.load(str(MODEL), safety_horizon=0.6)
    big = dvnav.Policy.load(str(MODEL), footprint=fp, safety_horizon=0.6)
    obs, _ = dvnav.NavVectorEnv(num_envs=32, room="env0", seed=2, footprint=fp).reset()
    obs[:, :540] = np.minimum(obs[:, :540], 0.3 * big.mu)  # an obstacle close on every side
    scaled = obs.copy()
    scaled[:, :540] = np.clip(obs[:, :540] / big.mu, 0.02, 10.0)
    scaled[:, 540] /= big.mu
    scaled[:, 542] /= big.mu
    meta_cmd, cmd = meta.velocities(scaled), big.velocities(obs)
    v_max, w_max = big.velocity_bounds
    free = (meta_cmd[:, 0] * big.mu <= v_max) & (np.abs(meta_cmd[:, 1]) <= w_max)
    assert free.sum() >= 4
    assert np.allclose(cmd[free, 0], meta_cmd[free, 0] * big.mu, atol=1e-9)
    assert (meta_cmd[:, 0] < 0.2).all(), "the meta robot, 0.1 m from an obstacle, is held"


@pytest.mark.parametrize("horizon", [-1.0, float("nan"), float("inf")])
def test_a_bad_safety_horizon_is_refused(horizon):
    with pytest.raises(ValueError, match="safety_horizon is"):
        dvnav.Policy.load(str(MODEL), safety_horizon=horizon)


def test_noise_samples_the_policys_distribution_row_by_row():
    policy = dvnav.Policy.load(str(MODEL))
    obs = observations(4)
    det = policy.velocities(obs)
    assert np.array_equal(policy.velocities(obs, noise=[None] * 4), det)
    # ε = 0 is the mean: tanh(μ), the deterministic action (to float rounding).
    assert np.allclose(policy.velocities(obs[0], noise=(0.0, 0.0)), det[0], atol=1e-5)
    noisy = policy.velocities(obs, noise=[None, (2.0, -2.0), None, (-2.0, 2.0)])
    assert np.array_equal(noisy[[0, 2]], det[[0, 2]]), "rows without noise stay as they are"
    assert not np.allclose(noisy[1], det[1]) and not np.allclose(noisy[3], det[3])
    v_max, w_max = policy.velocity_bounds
    assert ((0 <= noisy[:, 0]) & (noisy[:, 0] <= v_max)).all() and (np.abs(noisy[:, 1]) <= w_max).all()
    # The same noise, the same command: the sample is a function of ε.
    again = policy.velocities(obs, noise=[None, (2.0, -2.0), None, (-2.0, 2.0)])
    assert np.array_equal(again, noisy)
    with pytest.raises(ValueError, match="noise"):
        policy.velocities(obs, noise=[None] * 3)


def test_the_stall_escape_asks_for_noise_after_the_delay_and_forgets_on_a_new_goal():
    policy = dvnav.Policy.load(str(MODEL), footprint=str(ROOT / "footprints/circle-0.5.toml"))
    escape = policy.escape(after_s=1.0, seed=3)
    dt = 0.2
    # Frozen 4 m from the goal: deterministic for 1 s, then noise for 1 s, then watched again.
    eps = [escape.noise(k * dt, 4.0) for k in range(15)]
    assert all(e is None for e in eps[:5]) and all(e is not None for e in eps[5:10])
    assert all(e is None for e in eps[10:15])
    # Progress of half the robot's radius (0.25 m for R = 0.5) restarts the watch; 0.2 m does not.
    escape.reset()
    assert escape.noise(0.0, 4.0) is None
    assert escape.noise(0.8, 3.8) is None and escape.noise(1.0, 3.8) is not None
    escape.reset()
    assert escape.noise(0.0, 4.0) is None
    assert escape.noise(0.8, 3.7) is None and escape.noise(1.0, 3.7) is None
    # Seeded: the same watch replays the same noise.
    a, b = policy.escape(1.0, seed=5), policy.escape(1.0, seed=5)
    assert [a.noise(k * dt, 4.0) for k in range(10)] == [b.noise(k * dt, 4.0) for k in range(10)]
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="delay"):
            policy.escape(after_s=bad)
