//! Which episodes an actor writes to MCAP, and the glue from environment state to log records.
//! The writing itself is [`dvnav_eval::episode_log::EpisodeLogger`].

use dvnav_config::Config;
use dvnav_eval::episode_log::{EpisodeLogger, EpisodeStart, LogMetadata, StepLog};
use dvnav_sim::NavEnv;
use std::path::Path;

/// Logs every Nth episode of an actor (N = `logging.every_nth_episode`). An MCAP logger
/// writes one episode at a time, and an actor's environments run episodes side by side, so
/// each environment gets its own logger and files (`{name}-env{i}-NNNNN.mcap`), rotated by
/// `logging.episodes_per_file` and `logging.max_file_mb`.
///
/// A write error (disk full, a directory that went read-only) never stops the actor: it is
/// logged with the file and the OS error and counted ([`EpisodeSelector::write_failures`]); that
/// environment's file is abandoned unfinished (`dvnav inspect --check` reads its complete
/// episodes), the rest of its episode is not logged, and its next selected episode tries again
/// in a new file.
pub struct EpisodeSelector {
    dir: std::path::PathBuf,
    prefix: String,
    meta: LogMetadata,
    episodes_per_file: u64,
    max_file_bytes: Option<u64>,
    loggers: Vec<Option<EpisodeLogger>>,
    /// Per environment: its current episode lost its log to a write error.
    abandoned: Vec<bool>,
    every_nth: u64,
    write_failures: u64,
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
            abandoned: Vec::new(),
            every_nth: cfg.logging.every_nth_episode,
            write_failures: 0,
        }))
    }

    /// Write errors survived so far.
    pub fn write_failures(&self) -> u64 {
        self.write_failures
    }

    /// Handles a write error of environment `env_index`: logs and counts it, drops its logger
    /// (the file stays unfinished) and skips the rest of its episode.
    fn failed(&mut self, env_index: usize, error: anyhow::Error) {
        let path = self
            .loggers
            .get(env_index)
            .and_then(|l| l.as_ref())
            .and_then(|l| l.current_file().map(Path::to_path_buf))
            .unwrap_or_else(|| self.dir.clone());
        self.write_failures += 1;
        tracing::error!(path = %path.display(), error = %format!("{error:#}"), failures = self.write_failures, "cannot write the episode log; the actor goes on, this episode is not logged, the next selected one tries again in a new file");
        if let Some(l) = self.loggers.get_mut(env_index) {
            *l = None;
        }
        self.abandoned[env_index] = true;
    }

    fn logger(&mut self, env_index: usize) -> anyhow::Result<&mut EpisodeLogger> {
        if self.loggers.len() <= env_index {
            self.loggers.resize_with(env_index + 1, || None);
            self.abandoned.resize(env_index + 1, false);
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
        let begun = self.logger(env_index).and_then(|l| {
            l.begin_episode(&EpisodeStart {
                episode_id: id,
                room: env.room().spec(),
                robot_radius: env.robot_radius(),
                goal: env.goal(),
                lidar: &cfg.env.lidar,
                dt: cfg.env.dt,
                mu: 1.0,
            })
        });
        if self.abandoned.len() <= env_index {
            self.abandoned.resize(env_index + 1, false);
        }
        self.abandoned[env_index] = false;
        if let Err(e) = begun {
            self.failed(env_index, e);
            return Ok(false);
        }
        self.log_step(env_index, env, (0.0, 0.0), [-1.0, 0.0], 0.0)?;
        Ok(!self.abandoned[env_index])
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
        if self.abandoned.get(env_index).copied().unwrap_or(false) {
            return Ok(());
        }
        let p = env.pose();
        let written = self.logger(env_index).and_then(|l| {
            l.log_step(&StepLog {
                step: env.steps(),
                pose: [p.x, p.y, p.yaw],
                scan: env.scan(),
                v: command.0,
                omega: command.1,
                action,
                reward,
                goal_distance: env.goal_distance(),
                goal_angle: env.goal_angle(),
                subgoal: env.subgoal(),
                plan: env.planned_path().map(|p| p.points.as_slice()),
            })
        });
        if let Err(e) = written {
            self.failed(env_index, e);
        }
        Ok(())
    }

    /// Ends the open episode with its summary. Returns whether the episode is in the log
    /// (false when a write error abandoned it).
    pub fn end(
        &mut self,
        env_index: usize,
        summary: dvnav_proto::EpisodeSummary,
    ) -> anyhow::Result<bool> {
        if self.abandoned.get(env_index).copied().unwrap_or(false) {
            return Ok(false);
        }
        match self.logger(env_index).and_then(|l| l.end_episode(summary)) {
            Ok(()) => Ok(true),
            Err(e) => {
                self.failed(env_index, e);
                Ok(false)
            }
        }
    }

    /// Finishes the open file. An episode still running is left out of the summary records
    /// but its steps stay in the file.
    pub fn close(self) -> anyhow::Result<()> {
        for l in self.loggers.into_iter().flatten() {
            let path = l.current_file().map(Path::to_path_buf);
            // A file that cannot be finished stays readable up to its last complete episode.
            if let Err(e) = l.close() {
                tracing::error!(path = ?path, error = %format!("{e:#}"), "cannot finish the episode log");
            }
        }
        Ok(())
    }
}
