//! What the learner's own tests of an agent drive and where: the meta agent through DVST for
//! circular robots of given radii, in the run's simulator made clean (no sensor noise, training
//! robustness, varied training robots or subgoals). Shared by the gate test in the
//! training-time evaluation ([`crate::evaluator`]) and the best agent's selection
//! ([`crate::selection`]), so both judge the agent as `dvnav eval` does.

use dvnav_config::{Config, EnvConfig};
use dvnav_nav::dvst::{Dvst, MetaRobot, VariedRobot};
use dvnav_nav::policy::MetaAgent;
use dvnav_sim::Footprint;

/// One agent per radius of `radii` from the weights `policy` (safetensors bytes), each driving a
/// circular robot of that radius through DVST at μ = R / R_m.
pub fn dvst_agents(
    cfg: &Config,
    policy: &[u8],
    radii: &[f64],
) -> anyhow::Result<Vec<Dvst<MetaAgent>>> {
    let meta = MetaRobot::trained(&cfg.env)?;
    radii
        .iter()
        .map(|&r| {
            let agent = MetaAgent::from_safetensors(policy, cfg)?;
            let robot = VariedRobot { meta, ..VariedRobot::new(Footprint::circle(r)) };
            Dvst::for_run(agent, &cfg.env, robot)
        })
        .collect()
}

/// The run's environment, clean ([`EnvConfig::clean`]).
pub fn clean_env(cfg: &Config) -> EnvConfig {
    cfg.env.clean()
}
