//! The SAC learner's numerical and behavioural tests, one binary with a module per topic:
//! golden values against a NumPy reference (`golden`), a learning test with a known answer
//! (`pendulum`), and exact resume from a checkpoint (`resume`).

mod golden;
mod pendulum;
mod resume;
