//! Which episodes an actor writes to MCAP, and the glue from environment state to log records.
//! The writing itself is [`dvnav_common::episode_log::EpisodeLogger`].

use dvnav_common::config::Config;
use dvnav_common::episode_log::{EpisodeLogger, EpisodeStart, LogMetadata, StepLog};
use dvnav_common::sim::NavEnv;
use std::path::Path;

/// Logs every Nth episode of an actor (N = `logging.every_nth_episode`). An MCAP logger
/// writes one episode at a time, and an actor's environments run episodes side by side, so
/// each environment gets its own logger and files (`{name}-env{i}-NNNNN.mcap`), rotated by
/// `logging.episodes_per_file` and `logging.max_file_mb`.
pub struct EpisodeSelector {
    dir: std::path::PathBuf,
    prefix: String,
    meta: LogMetadata,
    episodes_per_file: u64,
    max_file_bytes: Option<u64>,
    loggers: Vec<Option<EpisodeLogger>>,
    every_nth: u64,
}

impl EpisodeSelector {
    /// A selector writing into `dir`; `None` when logging is off (N = 0).
    pub fn create(
        dir: &Path,
        prefix: &str,
        meta: LogMetadata,
        cfg: &Config,
    ) -> anyhow::Result<Option<Self>> {
        if cfg.logging.every_nth_episode == 0 {
            return Ok(None);
        }
        std::fs::create_dir_all(dir)?;
        Ok(Some(Self {
            dir: dir.to_path_buf(),
            prefix: prefix.to_string(),
            meta,
            episodes_per_file: cfg.logging.episodes_per_file,
            max_file_bytes: Some(cfg.logging.max_file_mb * 1024 * 1024).filter(|&b| b > 0),
            loggers: Vec::new(),
            every_nth: cfg.logging.every_nth_episode,
        }))
    }

    fn logger(&mut self, env_index: usize) -> anyhow::Result<&mut EpisodeLogger> {
        if self.loggers.len() <= env_index {
            self.loggers.resize_with(env_index + 1, || None);
        }
        if self.loggers[env_index].is_none() {
            let prefix = format!("{}-env{env_index}", self.prefix);
            self.loggers[env_index] = Some(
                EpisodeLogger::create(
                    &self.dir,
                    &prefix,
                    self.meta.clone(),
                    self.episodes_per_file,
                )?
                .with_max_file_bytes(self.max_file_bytes),
            );
        }
        Ok(self.loggers[env_index].as_mut().expect("created above"))
    }

    /// Starts logging episode `id` if it is selected; logs its first step (the pose after
    /// reset). Returns whether it is logged.
    pub fn maybe_begin(
        &mut self,
        env_index: usize,
        id: u64,
        env: &NavEnv,
        cfg: &Config,
    ) -> anyhow::Result<bool> {
        if !id.is_multiple_of(self.every_nth) {
            return Ok(false);
        }
        self.logger(env_index)?.begin_episode(&EpisodeStart {
            episode_id: id,
            room: env.room().spec(),
            robot_radius: env.robot_radius(),
            goal: env.goal(),
            lidar: &cfg.env.lidar,
            dt: cfg.env.dt,
            mu: 1.0,
        })?;
        self.log_step(env_index, env, (0.0, 0.0), [-1.0, 0.0], 0.0)?;
        Ok(true)
    }

    /// Logs the state of `env` after a step.
    pub fn log_step(
        &mut self,
        env_index: usize,
        env: &NavEnv,
        command: (f64, f64),
        action: [f32; 2],
        reward: f32,
    ) -> anyhow::Result<()> {
        let p = env.pose();
        self.logger(env_index)?.log_step(&StepLog {
            step: env.steps(),
            pose: [p.x, p.y, p.yaw],
            scan: env.scan(),
            v: command.0,
            omega: command.1,
            action,
            reward,
            goal_distance: env.goal_distance(),
            goal_angle: env.goal_angle(),
        })
    }

    /// Ends the open episode with its summary.
    pub fn end(
        &mut self,
        env_index: usize,
        summary: dvnav_proto::EpisodeSummary,
    ) -> anyhow::Result<()> {
        self.logger(env_index)?.end_episode(summary)
    }

    /// Finishes the open file. An episode still running is left out of the summary records
    /// but its steps stay in the file.
    pub fn close(self) -> anyhow::Result<()> {
        for l in self.loggers.into_iter().flatten() {
            l.close()?;
        }
        Ok(())
    }
}
