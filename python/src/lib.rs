//! # dvnav-python
//!
//! The extension module `dvnav._core`: dvnav's simulator and trained agents for Python. It only
//! translates: rooms, environments, DVST and the policy are the Rust crates' own
//! ([`dvnav_sim`], [`dvnav_nav`]); frames are [`dvnav_render`]'s. The Gymnasium classes around
//! it are plain Python (`python/dvnav/`).
//!
//! - [`env::Env`]: one [`dvnav_sim::NavEnv`] with Gymnasium's reset/step semantics.
//! - [`vec_env::VecEnv`]: many, stepped on rayon's threads with the GIL released, autoreset
//!   on the step after an episode ends (Gymnasium's `NEXT_STEP`), observations written
//!   straight into the numpy arrays returned.
//! - [`policy::Policy`]: a trained meta agent, alone or in DVST for a footprint file.
//! - [`route::Route`]: a path followed by subgoals, as `dvnav serve`'s `SetRoute` follows it.
//! - [`escape::StallEscape`]: the stall escape's progress watch, one per robot.
//!
//! Errors in what the caller gave (a room name, a config key, a footprint file, an array's
//! shape) are `ValueError`s that say what was wrong.

mod env;
mod escape;
mod policy;
mod route;
mod setup;
mod vec_env;

use pyo3::prelude::*;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<env::Env>()?;
    m.add_class::<vec_env::VecEnv>()?;
    m.add_class::<policy::Policy>()?;
    m.add_class::<route::Route>()?;
    m.add_class::<escape::StallEscape>()?;
    m.add_function(wrap_pyfunction!(setup::room_names, m)?)?;
    m.add_function(wrap_pyfunction!(setup::default_env_config, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
