//! [`Policy`]: a trained meta agent for Python, alone or driving another robot through DVST.

use crate::setup::value_error;
use dvnav_nav::control::velocity_to_action;
use dvnav_nav::dvst::{Dvst, VariedRobot};
use dvnav_nav::policy::{MetaAgent, NavPolicy, read_policy};
use dvnav_sim::EnvConfig;
use dvnav_sim::laser_scan::BeamLayout;
use dvnav_sim::latency;
use dvnav_sim::safety;
use numpy::{
    PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use std::path::Path;

/// The deterministic policy of a checkpoint or model directory (a = tanh(μ(s))), as `dvnav
/// eval` and `dvnav serve` run it. With a footprint file it is the meta agent in DVST for that
/// robot: observations are the robot's own, commands within its own bounds.
#[pyclass(module = "dvnav._core")]
pub struct Policy {
    policy: Box<dyn NavPolicy + Send + Sync>,
    /// The run's `[env]`: the action scale (v_max, ω_max) of its environments.
    env: EnvConfig,
    mu: f64,
    /// The collision monitor's horizon (s; 0: off).
    safety_horizon_s: f64,
    path: String,
}

#[pymethods]
impl Policy {
    /// `path`: a model or checkpoint directory, or its `policy.safetensors`; `footprint`: a
    /// footprint file for DVST (its meta robot must be the one the model was trained as);
    /// `margin` (m) replaces the file's margin; `safety_horizon` (s, 0: off) runs the collision
    /// monitor on every command.
    #[staticmethod]
    #[pyo3(signature = (path, footprint=None, margin=None, safety_horizon=0.0))]
    fn load(
        path: &str,
        footprint: Option<&str>,
        margin: Option<f64>,
        safety_horizon: f64,
    ) -> PyResult<Policy> {
        if !(safety_horizon.is_finite() && safety_horizon >= 0.0) {
            return Err(value_error(anyhow::anyhow!(
                "safety_horizon is {safety_horizon}; it must be 0 (off) or a positive number of \
                 seconds (0.6 as measured in docs/results.md)"
            )));
        }
        let file = read_policy(Path::new(path)).map_err(value_error)?;
        let agent = MetaAgent::from_policy_file(&file).map_err(value_error)?;
        let env = file.config.env.clone();
        let (policy, mu): (Box<dyn NavPolicy + Send + Sync>, f64) = match footprint {
            None => {
                if margin.is_some() {
                    return Err(value_error(anyhow::anyhow!("a margin needs a footprint file")));
                }
                (Box::new(agent), 1.0)
            }
            Some(f) => {
                let mut robot = VariedRobot::load(Path::new(f)).map_err(value_error)?;
                if let Some(m) = margin {
                    robot.margin = m;
                }
                let dvst = Dvst::for_run(agent, &env, robot).map_err(value_error)?;
                let mu = dvst.mu();
                (Box::new(dvst), mu)
            }
        };
        Ok(Policy {
            policy,
            env,
            mu,
            safety_horizon_s: safety_horizon,
            path: file.path.display().to_string(),
        })
    }

    /// Commands (v m/s, ω rad/s) for observations `obs` (n x obs_dim), one row each; `noise`
    /// (n x 2): ε for the rows sampled from the policy's distribution (the stall escape), NaN
    /// rows deterministic.
    #[pyo3(signature = (obs, noise=None))]
    fn velocities<'py>(
        &mut self,
        py: Python<'py>,
        obs: PyReadonlyArray2<'py, f32>,
        noise: Option<PyReadonlyArray2<'py, f32>>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let commands = self.commands(py, &obs, noise.as_ref())?;
        let flat: Vec<f64> = commands.iter().flat_map(|&(v, w)| [v, w]).collect();
        numpy::PyArray1::from_vec(py, flat).reshape([commands.len(), 2])
    }

    /// The same commands as normalized actions in [−1, 1]² (n x 2), the action space of
    /// environments with the run's env config.
    #[pyo3(signature = (obs, noise=None))]
    fn actions<'py>(
        &mut self,
        py: Python<'py>,
        obs: PyReadonlyArray2<'py, f32>,
        noise: Option<PyReadonlyArray2<'py, f32>>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let commands = self.commands(py, &obs, noise.as_ref())?;
        let flat: Vec<f32> =
            commands.iter().flat_map(|&(v, w)| velocity_to_action(v, w, &self.env)).collect();
        numpy::PyArray1::from_vec(py, flat).reshape([commands.len(), 2])
    }

    /// The observation `obs` (one row) taken before the robot drove `commands` ((v m/s, ω
    /// rad/s), oldest first, each held for `dt` s; default the run's control period), as the
    /// robot reads it now: its scan and goal carried forward by those commands' motion, as `dvnav
    /// serve` does with `scan_age_s` and the environments with `latency_compensation`. v and ω
    /// are left as given (the last command is the caller's own, never delayed). The robot's own
    /// units: in DVST its commands and metres.
    #[pyo3(signature = (obs, commands, dt=None))]
    fn carry_forward<'py>(
        &self,
        py: Python<'py>,
        obs: PyReadonlyArray1<'py, f32>,
        commands: Vec<(f64, f64)>,
        dt: Option<f64>,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let old = obs.as_slice().map_err(value_error)?;
        let d = self.policy.obs_dim();
        if old.len() != d {
            return Err(value_error(anyhow::anyhow!(
                "the observation has {} values; this policy takes {d}",
                old.len()
            )));
        }
        let dt = dt.unwrap_or(self.env.dt);
        if !(dt.is_finite() && dt > 0.0) {
            return Err(value_error(anyhow::anyhow!(
                "dt is {dt}; it must be a positive number of seconds"
            )));
        }
        if let Some((k, c)) =
            commands.iter().enumerate().find(|(_, (v, w))| !(v.is_finite() && w.is_finite()))
        {
            return Err(value_error(anyhow::anyhow!(
                "commands[{k}] is {c:?}; commands must be finite"
            )));
        }
        let lidar = &self.env.lidar;
        let layout = BeamLayout::new(lidar.beams, lidar.fov_deg);
        // The meta robot's range in this robot's metres: what DVST maps onto the meta scan.
        let range = [lidar.range_min * self.mu, lidar.range_max * self.mu];
        let moved = latency::motion_since(commands, dt);
        let mut out = old.to_vec();
        latency::carry_observation(old, layout, range, moved, &mut out);
        Ok(PyArray1::from_vec(py, out))
    }

    /// Length of one observation.
    #[getter]
    fn obs_dim(&self) -> usize {
        self.policy.obs_dim()
    }

    /// The collision monitor's horizon (s; 0: off).
    #[getter]
    fn safety_horizon(&self) -> f64 {
        self.safety_horizon_s
    }

    /// μ, the DVST scale (1 without a footprint).
    #[getter]
    fn mu(&self) -> f64 {
        self.mu
    }

    /// (v_max, ω_max) of the commands: the robot's own in DVST.
    #[getter]
    fn velocity_bounds(&self) -> (f64, f64) {
        self.policy.velocity_bounds()
    }

    /// The run's `[env]` section as JSON: make environments with it to match the agent.
    #[getter]
    fn env_config(&self) -> String {
        serde_json::to_string(&self.env).expect("the env config serializes")
    }

    /// The same, clean, as `dvnav eval` drives the agent by default (`EnvConfig::clean`).
    #[getter]
    fn eval_env_config(&self) -> String {
        serde_json::to_string(&self.env.clean()).expect("the env config serializes")
    }

    /// The weights file read.
    #[getter]
    fn path(&self) -> String {
        self.path.clone()
    }
}

impl Policy {
    fn commands(
        &mut self,
        py: Python<'_>,
        obs: &PyReadonlyArray2<'_, f32>,
        noise: Option<&PyReadonlyArray2<'_, f32>>,
    ) -> PyResult<Vec<(f64, f64)>> {
        let d = self.policy.obs_dim();
        if obs.shape()[1] != d {
            return Err(value_error(anyhow::anyhow!(
                "observations have {} values; this policy takes {d}",
                obs.shape()[1]
            )));
        }
        let data = obs.as_slice().map_err(value_error)?;
        let noise: Option<Vec<Option<[f32; 2]>>> = match noise {
            None => None,
            Some(n) => {
                if n.shape() != [obs.shape()[0], 2] {
                    return Err(value_error(anyhow::anyhow!(
                        "noise has shape {:?}; expected ({}, 2), one (ε_v, ε_ω) per observation                          (NaN for a deterministic row)",
                        n.shape(),
                        obs.shape()[0]
                    )));
                }
                let flat = n.as_slice().map_err(value_error)?;
                Some(
                    flat.chunks_exact(2)
                        .map(|e| (e[0].is_finite() && e[1].is_finite()).then_some([e[0], e[1]]))
                        .collect(),
                )
            }
        };
        let policy = &mut self.policy;
        let mut commands = py
            .detach(|| match &noise {
                Some(n) => policy.act_batch_noisy(data, n),
                None => policy.act_batch(data),
            })
            .map_err(value_error)?;
        if self.safety_horizon_s > 0.0 {
            // In the robot's own frame: DVST scales the meta robot's scan, disc and speed by
            // the same μ, so the monitor on the robot's scan, the meta disc times μ and the
            // robot's command limits what `dvnav serve` limits on the meta ones (the robot's
            // own velocity bounds, lower, only shorten the arc checked).
            let lidar = &self.env.lidar;
            let layout = BeamLayout::new(lidar.beams, lidar.fov_deg);
            let radius = self.env.robot_radius * self.mu;
            for (row, c) in data.chunks_exact(d).zip(commands.iter_mut()) {
                c.0 = safety::safe_speed(
                    &row[..layout.beams],
                    layout,
                    lidar.range_max * self.mu,
                    radius,
                    *c,
                    self.safety_horizon_s,
                );
            }
        }
        Ok(commands)
    }
}
