//! What an environment is made of, from what Python gives: rooms by name or file, the env config
//! as JSON over the defaults (validated as `dvnav train` validates it), a footprint file, and
//! the observation's bounds.

use dvnav_config::Config;
use dvnav_sim::{EnvConfig, Footprint, NavEnv, Outcome, Room};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::sync::Arc;

/// A caller's mistake as a `ValueError` with the whole cause chain.
pub fn value_error(e: impl Into<anyhow::Error>) -> PyErr {
    PyValueError::new_err(format!("{:#}", e.into()))
}

/// What every environment of one `Env` or `VecEnv` shares.
#[derive(Clone, Debug)]
pub struct Setup {
    /// The rooms episodes cycle through (one for a built-in name; a room file may hold several).
    pub rooms: Vec<Arc<Room>>,
    /// The task's constants.
    pub cfg: EnvConfig,
    /// The robot, when it is not the config's.
    pub footprint: Option<Footprint>,
}

impl Setup {
    /// `room`: a built-in name or a room file; `env_config`: a JSON object of `[env]` keys over
    /// the defaults (`{}` for none), or `config`'s `[env]` section when that run config file is
    /// given; `footprint`: a footprint file for the robot.
    pub fn new(
        room: &str,
        footprint: Option<&str>,
        config: Option<&str>,
        env_config: &str,
    ) -> anyhow::Result<Setup> {
        let rooms = load_rooms(room)?;
        let cfg = env_config_from(config, env_config)?;
        let footprint = match footprint {
            Some(path) => Some(Footprint::load(std::path::Path::new(path))?),
            None => None,
        };
        Ok(Setup { rooms, cfg, footprint })
    }

    /// Episode `episode` of environment `index` runs in this room: each environment starts in
    /// its own room and moves on to the next at every episode.
    pub fn room(&self, index: usize, episode: usize) -> Arc<Room> {
        self.rooms[(index + episode) % self.rooms.len()].clone()
    }

    /// A fresh environment `index`, seeded `seed`, reset to its first episode.
    ///
    /// Rooms too small for the robot panic in `NavEnv`'s sampler; that is checked first.
    pub fn env(&self, index: usize, seed: u64) -> anyhow::Result<NavEnv> {
        let room = self.room(index, 0);
        let r = self.footprint.as_ref().map_or(self.cfg.robot_radius, Footprint::bounding_radius);
        let need = r + self.cfg.spawn_clearance;
        anyhow::ensure!(
            room.side() / 2.0 > need,
            "room `{}` ({} m) is too small for a robot of radius {r} m",
            room.name(),
            room.side()
        );
        Ok(match &self.footprint {
            Some(f) => NavEnv::with_footprint(room, &self.cfg, seed, f.clone()),
            None => NavEnv::new(room, &self.cfg, seed),
        })
    }

    /// Lowest and highest value of each observation entry: the scan within the LiDAR's range,
    /// the goal distance ≥ 0, its bearing in [−π, π], v in [0, v_max], ω in [−ω_max, ω_max],
    /// and the radius input (when on) ≥ 0.
    pub fn obs_bounds(&self) -> (Vec<f32>, Vec<f32>) {
        let layout = self.cfg.obs_layout();
        let beams = layout.beams;
        let l = &self.cfg.lidar;
        let mut low = vec![l.range_min.min(0.0) as f32; beams];
        let mut high = vec![l.range_max as f32; beams];
        let pi = std::f32::consts::PI;
        low.extend([0.0, -pi, 0.0, -self.cfg.omega_max as f32]);
        high.extend([f32::INFINITY, pi, self.cfg.v_max as f32, self.cfg.omega_max as f32]);
        if layout.radius_input {
            low.push(0.0);
            high.push(f32::INFINITY);
        }
        (low, high)
    }
}

/// The rooms of `room` (a built-in name or a room file), at least one.
pub fn load_rooms(room: &str) -> anyhow::Result<Vec<Arc<Room>>> {
    let rooms = Room::load(room)?;
    anyhow::ensure!(!rooms.is_empty(), "room `{room}`: the file holds no room");
    Ok(rooms)
}

fn env_config_from(config: Option<&str>, env_json: &str) -> anyhow::Result<EnvConfig> {
    let base = match config {
        Some(path) => Config::load(std::path::Path::new(path))?.env,
        None => EnvConfig::default(),
    };
    let overrides: serde_json::Value = serde_json::from_str(env_json)
        .map_err(|e| anyhow::anyhow!("env config is not JSON: {e}"))?;
    let mut merged = serde_json::to_value(&base)?;
    merge(&mut merged, overrides);
    let env: EnvConfig = serde_json::from_value(merged).map_err(|e| {
        anyhow::anyhow!("env config: {e} (the keys are those of a run config's [env] section)")
    })?;
    let cfg = Config { env, ..Config::default() };
    cfg.validate()?;
    Ok(cfg.env)
}

/// Objects merge key by key (so `lidar={"noise_std": 0.01}` keeps the other LiDAR keys);
/// anything else replaces.
fn merge(base: &mut serde_json::Value, over: serde_json::Value) {
    match (base, over) {
        (serde_json::Value::Object(b), serde_json::Value::Object(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

/// An episode's end as Gymnasium flags: (terminated, truncated). A timeout truncates: the value
/// of its last state still counts, as the learner treats it.
pub fn flags(done: Option<Outcome>) -> (bool, bool) {
    match done {
        Some(Outcome::Success | Outcome::Collision) => (true, false),
        Some(Outcome::Timeout) => (false, true),
        None => (false, false),
    }
}

/// The vector environment's outcome code: 1 success, 2 collision, 3 timeout (0: running,
/// 4: reset by this step).
pub fn outcome_code(o: Outcome) -> u8 {
    match o {
        Outcome::Success => 1,
        Outcome::Collision => 2,
        Outcome::Timeout => 3,
    }
}

/// The names `room=` accepts besides room files.
#[pyfunction]
pub fn room_names() -> Vec<String> {
    Room::builtin_names()
}

/// The default `[env]` section as JSON (every key `gymnasium.make` accepts).
#[pyfunction]
pub fn default_env_config() -> String {
    serde_json::to_string(&EnvConfig::default()).expect("the env config serializes")
}
