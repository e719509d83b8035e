//! [`VecEnv`]: many environments stepped in Rust threads, without the GIL.

use crate::setup::{Setup, flags, outcome_code, value_error};
use dvnav_nav::control::action_to_velocity;
use dvnav_sim::NavEnv;
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use rayon::prelude::*;

/// One environment of the batch and what autoreset needs to know of it.
struct Slot {
    env: NavEnv,
    /// Episodes begun since seeding; picks the room.
    episode: usize,
    /// Its episode ended at the last step: the next step starts a new one instead.
    ended: bool,
}

/// A batch of environments (`dvnav.NavVectorEnv` wraps it as a `gymnasium.vector.VectorEnv`).
///
/// `step` steps every environment on rayon's threads with the GIL released and writes the
/// observations straight into the arrays it returns. An environment whose episode ended at
/// the previous step is reset by this step instead (Gymnasium's `NEXT_STEP` autoreset): its
/// action is ignored, its reward is 0 and its flags are false.
#[pyclass(module = "dvnav._core")]
pub struct VecEnv {
    setup: Setup,
    slots: Vec<Slot>,
}

type StepArrays<'py> = (
    Bound<'py, PyArray2<f32>>,
    Bound<'py, PyArray1<f32>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray1<u8>>,
);

/// An environment's room, pose (x, y, yaw) and goal (x, y).
type EnvState = (String, (f64, f64, f64), (f64, f64));

#[pymethods]
impl VecEnv {
    /// One environment per seed, each like `Env(room, seed, …)`; environment `i` starts in
    /// room `i` of a multi-room file.
    #[new]
    #[pyo3(signature = (room, seeds, footprint=None, config=None, env_config="{}"))]
    fn new(
        py: Python<'_>,
        room: &str,
        seeds: Vec<u64>,
        footprint: Option<&str>,
        config: Option<&str>,
        env_config: &str,
    ) -> PyResult<Self> {
        if seeds.is_empty() {
            return Err(value_error(anyhow::anyhow!(
                "a vector environment needs at least one seed"
            )));
        }
        let setup = Setup::new(room, footprint, config, env_config).map_err(value_error)?;
        let slots = py.detach(|| build(&setup, &seeds)).map_err(value_error)?;
        Ok(VecEnv { setup, slots })
    }

    /// Number of environments.
    fn __len__(&self) -> usize {
        self.slots.len()
    }

    /// Resets every environment: reseeded from `seeds` (one each) when given, else each to its
    /// next episode. Returns the observations, one row each.
    #[pyo3(signature = (seeds=None))]
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        seeds: Option<Vec<u64>>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        match seeds {
            Some(seeds) => {
                if seeds.len() != self.slots.len() {
                    return Err(value_error(anyhow::anyhow!(
                        "{} seeds for {} environments",
                        seeds.len(),
                        self.slots.len()
                    )));
                }
                let setup = &self.setup;
                self.slots = py.detach(|| build(setup, &seeds)).map_err(value_error)?;
            }
            None => {
                let setup = &self.setup;
                let slots = &mut self.slots;
                py.detach(|| {
                    slots.par_iter_mut().enumerate().for_each(|(i, s)| next_episode(setup, i, s))
                });
            }
        }
        Ok(self.observations(py))
    }

    /// Steps every environment with its row of `actions` (n x 2, each in [−1, 1]²). Returns
    /// (observations n x d, rewards, terminated, truncated, outcome codes: 0 running,
    /// 1 success, 2 collision, 3 timeout, 4 reset by this step).
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        actions: PyReadonlyArray2<'py, f32>,
    ) -> PyResult<StepArrays<'py>> {
        let n = self.slots.len();
        if actions.shape() != [n, 2] {
            return Err(value_error(anyhow::anyhow!(
                "actions have shape {:?}; expected ({n}, 2)",
                actions.shape()
            )));
        }
        let actions = actions.as_slice().map_err(value_error)?;
        let dim = self.setup.cfg.obs_layout().dim();
        let obs = PyArray2::<f32>::zeros(py, [n, dim], false);
        let rewards = PyArray1::<f32>::zeros(py, n, false);
        let terminated = PyArray1::<bool>::zeros(py, n, false);
        let truncated = PyArray1::<bool>::zeros(py, n, false);
        let codes = PyArray1::<u8>::zeros(py, n, false);
        // SAFETY: the arrays were just made here and nothing else can see them yet.
        let (o, r, te, tr, c) = unsafe {
            (
                obs.as_slice_mut(),
                rewards.as_slice_mut(),
                terminated.as_slice_mut(),
                truncated.as_slice_mut(),
                codes.as_slice_mut(),
            )
        };
        let (o, r, te, tr, c) = (o.unwrap(), r.unwrap(), te.unwrap(), tr.unwrap(), c.unwrap());
        let setup = &self.setup;
        let slots = &mut self.slots;
        py.detach(|| {
            slots
                .par_iter_mut()
                .enumerate()
                .zip(o.par_chunks_mut(dim))
                .zip(
                    r.par_iter_mut()
                        .zip(te.par_iter_mut())
                        .zip(tr.par_iter_mut().zip(c.par_iter_mut())),
                )
                .for_each(|(((i, s), o), ((r, te), (tr, c)))| {
                    if s.ended {
                        next_episode(setup, i, s);
                        *c = 4;
                    } else {
                        let a = [actions[2 * i], actions[2 * i + 1]];
                        let (v, omega) = action_to_velocity(a, &setup.cfg);
                        let out = s.env.step(v, omega);
                        *r = out.reward;
                        (*te, *tr) = flags(out.done);
                        s.ended = out.done.is_some();
                        *c = out.done.map_or(0, outcome_code);
                    }
                    s.env.write_obs(o);
                });
        });
        Ok((obs, rewards, terminated, truncated, codes))
    }

    /// Runs every environment's next episodes in `room` (a built-in name or a room file),
    /// from each one's next reset on.
    fn set_room(&mut self, room: &str) -> PyResult<()> {
        self.setup.rooms = crate::setup::load_rooms(room).map_err(value_error)?;
        for (i, s) in self.slots.iter_mut().enumerate() {
            s.env.set_room(self.setup.room(i, s.episode + 1));
        }
        Ok(())
    }

    /// Every environment's observation now, one row each.
    fn observations<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
        let dim = self.setup.cfg.obs_layout().dim();
        let obs = PyArray2::<f32>::zeros(py, [self.slots.len(), dim], false);
        // SAFETY: the array was just made here and nothing else can see it yet.
        let out = unsafe { obs.as_slice_mut() }.expect("a new array is contiguous");
        let slots = &self.slots;
        py.detach(|| {
            out.par_chunks_mut(dim).zip(slots.par_iter()).for_each(|(o, s)| s.env.write_obs(o))
        });
        obs
    }

    /// The observation space's bounds for one environment: (low, high).
    fn obs_bounds(&self) -> (Vec<f32>, Vec<f32>) {
        self.setup.obs_bounds()
    }

    /// Environment `i`'s room, pose (x, y, yaw) and goal (x, y).
    fn state(&self, i: usize) -> PyResult<EnvState> {
        let s = self.slots.get(i).ok_or_else(|| {
            value_error(anyhow::anyhow!("no environment {i} of {}", self.slots.len()))
        })?;
        let (p, g) = (s.env.pose(), s.env.goal());
        Ok((s.env.room().name().to_string(), (p.x, p.y, p.yaw), (g[0], g[1])))
    }

    /// A `size` x `size` RGB frame of environment `i`.
    #[pyo3(signature = (i, size=400))]
    fn render<'py>(
        &self,
        py: Python<'py>,
        i: usize,
        size: u32,
    ) -> PyResult<Bound<'py, numpy::PyArray3<u8>>> {
        let s = self.slots.get(i).ok_or_else(|| {
            value_error(anyhow::anyhow!("no environment {i} of {}", self.slots.len()))
        })?;
        let canvas = dvnav_render::frame::render_frame(&s.env, size).map_err(value_error)?;
        let n = size as usize;
        PyArray1::from_vec(py, canvas.rgb()).reshape([n, n, 3])
    }
}

fn build(setup: &Setup, seeds: &[u64]) -> anyhow::Result<Vec<Slot>> {
    seeds
        .par_iter()
        .enumerate()
        .map(|(i, &seed)| Ok(Slot { env: setup.env(i, seed)?, episode: 0, ended: false }))
        .collect()
}

fn next_episode(setup: &Setup, i: usize, s: &mut Slot) {
    s.episode += 1;
    s.env.set_room(setup.room(i, s.episode));
    s.env.reset();
    s.ended = false;
}
