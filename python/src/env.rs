//! [`Env`]: one environment with Gymnasium's reset and step.

use crate::setup::{Setup, flags, value_error};
use dvnav_nav::control::action_to_velocity;
use dvnav_sim::{NavEnv, Pose2};
use numpy::{PyArray1, PyArray3, PyArrayMethods};
use pyo3::prelude::*;

/// One navigation environment (`dvnav.NavEnv` wraps it as a `gymnasium.Env`).
#[pyclass(module = "dvnav._core")]
pub struct Env {
    setup: Setup,
    env: NavEnv,
    /// Episodes begun since the last seeding; picks the room.
    episode: usize,
    /// The environment was just built or reseeded: its first episode is already drawn.
    fresh: bool,
}

#[pymethods]
impl Env {
    /// `room`: a built-in room or a room file; `footprint`: a footprint file (default: the
    /// config's robot); `config`: a run config whose `[env]` section is the base; `env_config`:
    /// JSON `[env]` keys over it.
    #[new]
    #[pyo3(signature = (room, seed, footprint=None, config=None, env_config="{}"))]
    fn new(
        room: &str,
        seed: u64,
        footprint: Option<&str>,
        config: Option<&str>,
        env_config: &str,
    ) -> PyResult<Self> {
        let setup = Setup::new(room, footprint, config, env_config).map_err(value_error)?;
        let env = setup.env(0, seed).map_err(value_error)?;
        Ok(Env { setup, env, episode: 0, fresh: true })
    }

    /// Starts an episode: with `seed`, the first episode of a generator seeded so (the same
    /// for the same seed); without, the next episode of the current generator.
    #[pyo3(signature = (seed=None))]
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        seed: Option<u64>,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        match seed {
            Some(s) => {
                self.env = self.setup.env(0, s).map_err(value_error)?;
                self.episode = 0;
            }
            None if self.fresh => {}
            None => {
                self.episode += 1;
                self.env.set_room(self.setup.room(0, self.episode));
                self.env.reset();
            }
        }
        self.fresh = false;
        Ok(self.obs(py))
    }

    /// Starts an episode from `start` = (x, y, yaw) towards `goal` = (x, y), in the room of the
    /// next episode; neither is checked for clearance (an evaluation route's legs).
    fn reset_to<'py>(
        &mut self,
        py: Python<'py>,
        start: (f64, f64, f64),
        goal: (f64, f64),
    ) -> Bound<'py, PyArray1<f32>> {
        if !self.fresh {
            self.episode += 1;
            self.env.set_room(self.setup.room(0, self.episode));
        }
        self.fresh = false;
        self.env.reset_to(Pose2::new(start.0, start.1, start.2), [goal.0, goal.1]);
        self.obs(py)
    }

    /// Runs the next episodes in `room` (a built-in name or a room file), from the next reset
    /// on: a curriculum's next stage.
    fn set_room(&mut self, room: &str) -> PyResult<()> {
        self.setup.rooms = crate::setup::load_rooms(room).map_err(value_error)?;
        self.env.set_room(self.setup.room(0, self.episode + 1));
        Ok(())
    }

    /// One control period with the normalized action `a` ∈ [−1, 1]²:
    /// (observation, reward, terminated, truncated, outcome or None).
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        a0: f32,
        a1: f32,
    ) -> (Bound<'py, PyArray1<f32>>, f32, bool, bool, Option<&'static str>) {
        let (v, omega) = action_to_velocity([a0, a1], &self.setup.cfg);
        self.step_velocity(py, v, omega)
    }

    /// One control period with the command (v m/s, ω rad/s), clamped to the robot's bounds.
    fn step_velocity<'py>(
        &mut self,
        py: Python<'py>,
        v: f64,
        omega: f64,
    ) -> (Bound<'py, PyArray1<f32>>, f32, bool, bool, Option<&'static str>) {
        let out = self.env.step(v, omega);
        let (terminated, truncated) = flags(out.done);
        (self.obs(py), out.reward, terminated, truncated, out.done.map(|o| o.as_str()))
    }

    /// The observation now: scan (m), goal distance (m), goal bearing (rad), v, ω.
    fn obs<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f32>> {
        let array = PyArray1::<f32>::zeros(py, self.env.obs_dim(), false);
        // SAFETY: the array was just made here and nothing else can see it yet.
        let out = unsafe { array.as_slice_mut() }.expect("a new array is contiguous");
        self.env.write_obs(out);
        array
    }

    /// The observation space's bounds: (low, high).
    fn obs_bounds(&self) -> (Vec<f32>, Vec<f32>) {
        self.setup.obs_bounds()
    }

    /// A `size` x `size` RGB frame of the room, robot, rays and goal.
    #[pyo3(signature = (size=400))]
    fn render<'py>(&self, py: Python<'py>, size: u32) -> PyResult<Bound<'py, PyArray3<u8>>> {
        let canvas = dvnav_render::frame::render_frame(&self.env, size).map_err(value_error)?;
        let s = size as usize;
        PyArray1::from_vec(py, canvas.rgb()).reshape([s, s, 3])
    }

    /// The robot's pose (x, y, yaw).
    #[getter]
    fn pose(&self) -> (f64, f64, f64) {
        let p = self.env.pose();
        (p.x, p.y, p.yaw)
    }

    /// Where this episode started (x, y, yaw).
    #[getter]
    fn start(&self) -> (f64, f64, f64) {
        let p = self.env.start();
        (p.x, p.y, p.yaw)
    }

    /// With subgoals (`env.subgoals`): the goal the observation shows (the lookahead point on
    /// the planned path), else None.
    #[getter]
    fn subgoal(&self) -> Option<(f64, f64)> {
        self.env.route_stats()?;
        let [x, y] = self.env.observed_goal();
        Some((x, y))
    }

    /// With subgoals: the rotation shim's (v, ω) while it would hold the robot, else None.
    #[getter]
    fn shim_command(&self) -> Option<(f64, f64)> {
        self.env.shim_command()
    }

    /// With subgoals: the current plan's vertices (room frame), else None.
    #[getter]
    fn planned_path(&self) -> Option<Vec<(f64, f64)>> {
        self.env.planned_path().map(|p| p.points.iter().map(|q| (q[0], q[1])).collect())
    }

    /// The goal (x, y).
    #[getter]
    fn goal(&self) -> (f64, f64) {
        let g = self.env.goal();
        (g[0], g[1])
    }

    /// The room of this episode.
    #[getter]
    fn room(&self) -> String {
        self.env.room().name().to_string()
    }

    /// Steps taken in this episode.
    #[getter]
    fn steps(&self) -> u32 {
        self.env.steps()
    }

    /// The env config in force, as JSON.
    #[getter]
    fn env_config(&self) -> String {
        serde_json::to_string(&self.setup.cfg).expect("the env config serializes")
    }

    /// The robot's radius (m): the circle's or the footprint's bounding radius.
    #[getter]
    fn robot_radius(&self) -> f64 {
        self.env.robot_radius()
    }
}
