//! [`StallEscape`]: the stall escape's progress watch for Python, one per robot or environment.

use crate::setup::value_error;
use pyo3::prelude::*;

/// Watches one robot's goal distance; after `after_s` seconds without `progress_m` of progress
/// its `noise` is the ε for the policy's sampled action, for `after_s` seconds
/// ([`dvnav_nav::escape`], as `dvnav eval --escape-after` and `dvnav serve --escape-after`).
#[pyclass(module = "dvnav._core")]
pub struct StallEscape {
    inner: dvnav_nav::escape::StallEscape,
}

#[pymethods]
impl StallEscape {
    #[new]
    #[pyo3(signature = (after_s, progress_m, seed=0))]
    fn new(after_s: f64, progress_m: f64, seed: u64) -> PyResult<Self> {
        let inner =
            dvnav_nav::escape::StallEscape::new(after_s, progress_m, seed).map_err(value_error)?;
        Ok(Self { inner })
    }

    /// An escape for a robot of (bounding) radius `radius_m`: progress is half of it, as in
    /// `dvnav eval` and `dvnav serve`.
    #[staticmethod]
    #[pyo3(signature = (after_s, radius_m, seed=0))]
    fn for_radius(after_s: f64, radius_m: f64, seed: u64) -> PyResult<Self> {
        let inner = dvnav_nav::escape::StallEscape::for_radius(after_s, radius_m, seed)
            .map_err(value_error)?;
        Ok(Self { inner })
    }

    /// The cycle at `t_s` seconds, `goal_distance_m` from the goal: ε (two floats) while an
    /// escape runs, else None.
    fn noise(&mut self, t_s: f64, goal_distance_m: f64) -> Option<(f32, f32)> {
        self.inner.noise(t_s, goal_distance_m).map(|[a, b]| (a, b))
    }

    /// A goal distance that moved further than a robot at `v_max_mps` could drive since the
    /// last call is a new goal: the watch starts over.
    fn follow_goal(&mut self, t_s: f64, goal_distance_m: f64, v_max_mps: f64) {
        self.inner.follow_goal(t_s, goal_distance_m, v_max_mps)
    }

    /// A new goal: forget the progress seen.
    fn reset(&mut self) {
        self.inner.reset()
    }

    /// Whether an escape runs at `t_s`.
    fn escaping(&self, t_s: f64) -> bool {
        self.inner.escaping(t_s)
    }
}
