//! [`VecEnv`]: many [`NavEnv`]s stepped side by side on rayon's thread pool.

use super::{NavEnv, Room, StepOutcome};
use crate::EnvConfig;
use rayon::prelude::*;
use std::sync::Arc;

/// A batch of environments an actor steps together (one policy forward pass for all).
///
/// Environments never reset themselves: the caller reads the final observation of an ended
/// episode (the transition's next observation) and then calls [`VecEnv::reset`]. Results do not
/// depend on the number of threads: each environment has its own generator and only reads the
/// shared rooms.
#[derive(Clone, Debug)]
pub struct VecEnv {
    envs: Vec<NavEnv>,
}

impl VecEnv {
    /// One environment per seed; environment `i` runs in `rooms[i]`, or in `rooms[0]` when a
    /// single room is given.
    ///
    /// # Panics
    /// If `rooms` is empty, or neither 1 nor `seeds.len()` long.
    pub fn new(rooms: Vec<Arc<Room>>, cfg: &EnvConfig, seeds: &[u64]) -> VecEnv {
        assert!(
            rooms.len() == 1 || rooms.len() == seeds.len(),
            "VecEnv::new: give one room or one per seed ({} rooms, {} seeds)",
            rooms.len(),
            seeds.len()
        );
        let envs = seeds
            .par_iter()
            .enumerate()
            .map(|(i, &seed)| NavEnv::new(rooms[i.min(rooms.len() - 1)].clone(), cfg, seed))
            .collect();
        VecEnv { envs }
    }

    /// Wraps environments built elsewhere.
    pub fn from_envs(envs: Vec<NavEnv>) -> VecEnv {
        VecEnv { envs }
    }

    /// Number of environments.
    pub fn len(&self) -> usize {
        self.envs.len()
    }

    /// True when there are no environments.
    pub fn is_empty(&self) -> bool {
        self.envs.is_empty()
    }

    /// The environments.
    pub fn envs(&self) -> &[NavEnv] {
        &self.envs
    }

    /// The environments, mutably (e.g. to `reset_to` or `set_room` one of them).
    pub fn envs_mut(&mut self) -> &mut [NavEnv] {
        &mut self.envs
    }

    /// Length of one observation (all environments share the config).
    pub fn obs_dim(&self) -> usize {
        self.envs.first().map_or(0, NavEnv::obs_dim)
    }

    /// Steps environment `i` with `commands[i] = (v, ω)`, all in parallel.
    ///
    /// # Panics
    /// If `commands` is not [`VecEnv::len`] long.
    pub fn step(&mut self, commands: &[(f64, f64)]) -> Vec<StepOutcome> {
        let mut out = vec![StepOutcome { reward: 0.0, done: None }; self.envs.len()];
        self.step_into(commands, &mut out);
        out
    }

    /// Like [`VecEnv::step`], writing into `out` instead of allocating.
    pub fn step_into(&mut self, commands: &[(f64, f64)], out: &mut [StepOutcome]) {
        assert_eq!(commands.len(), self.envs.len(), "one command per environment");
        assert_eq!(out.len(), self.envs.len(), "one outcome per environment");
        self.envs
            .par_iter_mut()
            .zip(commands.par_iter())
            .zip(out.par_iter_mut())
            .for_each(|((env, &(v, w)), o)| *o = env.step(v, w));
    }

    /// Writes every environment's observation, back to back: `len() * obs_dim()` floats.
    ///
    /// # Panics
    /// If `out` has the wrong length.
    pub fn write_obs(&self, out: &mut [f32]) {
        let dim = self.obs_dim();
        assert_eq!(out.len(), self.envs.len() * dim, "observation buffer length");
        if dim == 0 {
            return;
        }
        out.par_chunks_mut(dim).zip(self.envs.par_iter()).for_each(|(o, env)| env.write_obs(o));
    }

    /// Starts a new episode in environment `i`.
    pub fn reset(&mut self, i: usize) {
        self.envs[i].reset();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Outcome;

    #[test]
    fn parallel_steps_match_sequential_envs() {
        let cfg = EnvConfig { max_steps: 30, ..EnvConfig::default() };
        let rooms = vec![Room::builtin("env0").unwrap(), Room::builtin("env3").unwrap()];
        let seeds = [3, 4];
        let mut vec_env = VecEnv::new(rooms.clone(), &cfg, &seeds);
        let mut singles: Vec<NavEnv> =
            (0..2).map(|i| NavEnv::new(rooms[i].clone(), &cfg, seeds[i])).collect();
        assert_eq!(vec_env.len(), 2);
        assert_eq!(vec_env.envs()[1].room().name(), "env3");
        let dim = vec_env.obs_dim();
        let mut batch = vec![0.0; 2 * dim];
        let mut one = vec![0.0; dim];
        let mut episodes = 0;
        for t in 0..80 {
            let commands = [(0.4, 0.3 * (t as f64).sin()), (0.5, -0.5)];
            let outs = vec_env.step(&commands);
            vec_env.write_obs(&mut batch);
            for i in 0..2 {
                let expect = singles[i].step(commands[i].0, commands[i].1);
                assert_eq!(outs[i], expect);
                singles[i].write_obs(&mut one);
                assert_eq!(&batch[i * dim..(i + 1) * dim], &one[..]);
                if let Some(o) = expect.done {
                    assert!(matches!(o, Outcome::Success | Outcome::Collision | Outcome::Timeout));
                    vec_env.reset(i);
                    singles[i].reset();
                    episodes += 1;
                }
            }
        }
        assert!(episodes >= 2);
    }

    #[test]
    #[should_panic(expected = "one room or one per seed")]
    fn room_count_must_match() {
        let room = Room::builtin("env0").unwrap();
        VecEnv::new(vec![room.clone(), room], &EnvConfig::default(), &[1, 2, 3]);
    }
}
