//! `learner.precision = "auto"`: the learner's matrix-product precision, chosen by timing the
//! real update in both before training starts.
//!
//! Why timed and not read off the CPU's flags: AVX512-BF16 alone does not make bf16 faster.
//! On a Zen 4 EPYC (512-bit vectors on 256-bit datapaths) `vdpbf16ps` doubles the fp32 FMA's
//! rate, and the bf16 update reached the skill in 105 s against 131 s; on a Zen 5 EPYC
//! (full-width 512-bit FMAs: fp32 matrix products at ~220 GFLOP/s a core against ~104) the
//! same bf16 update runs at 0.7-0.97x fp32, its operand packing no longer paid for
//! (docs/results.md, "bf16 mixed precision"). The update itself is what is timed: a few
//! updates of fresh networks of the configured shape, batch and threads, on random data, the
//! two precisions alternated, about a second of a learner's start.

use super::random_replay;
use crate::replay::{Batch, Returns};
use crate::sac::{SacLearner, SacNetworks};
use candle_core::Device;
use dvnav_config::{Config, Precision};
use dvnav_nav::bf16::Kernel;
use rand::SeedableRng;
use serde::Serialize;
use std::time::Instant;

/// bf16 is chosen only when it is at least this much faster: within the timing noise, fp32's
/// exact products win.
pub const BF16_MARGIN: f64 = 1.05;
/// Timed rounds, each one burst of updates per precision, alternated.
const ROUNDS: usize = 3;
/// Updates per precision in a round.
const UPDATES_PER_ROUND: usize = 3;

/// What `auto` chose and why.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct PrecisionChoice {
    /// The precision the learner trains in: `fp32` or `bf16`.
    pub precision: Precision,
    /// Why: `timed` (both measured), `no-avx512-bf16` (the CPU multiplies bf16 at the fp32
    /// rate, so bf16 cannot be faster), or `not-a-cpu` (on a GPU bf16 is unmeasured).
    pub reason: &'static str,
    /// Timed fp32 updates per second (when timed).
    pub fp32_updates_per_s: Option<f64>,
    /// Timed bf16 updates per second (when timed).
    pub bf16_updates_per_s: Option<f64>,
}

impl PrecisionChoice {
    /// Chooses from two timed rates: bf16 when it is at least [`BF16_MARGIN`] times faster.
    pub fn from_rates(fp32_updates_per_s: f64, bf16_updates_per_s: f64) -> Self {
        let bf16 = bf16_updates_per_s >= BF16_MARGIN * fp32_updates_per_s;
        Self {
            precision: if bf16 { Precision::Bf16 } else { Precision::Fp32 },
            reason: "timed",
            fp32_updates_per_s: Some(fp32_updates_per_s),
            bf16_updates_per_s: Some(bf16_updates_per_s),
        }
    }

    fn untimed(reason: &'static str) -> Self {
        Self {
            precision: Precision::Fp32,
            reason,
            fp32_updates_per_s: None,
            bf16_updates_per_s: None,
        }
    }
}

/// `fp32 (timed: fp32 69.5 against bf16 67.9 updates/s)`, or `fp32 (no-avx512-bf16)`.
impl std::fmt::Display for PrecisionChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({}", self.precision, self.reason)?;
        if let (Some(fp32), Some(bf16)) = (self.fp32_updates_per_s, self.bf16_updates_per_s) {
            write!(f, ": fp32 {fp32:.1} against bf16 {bf16:.1} updates/s")?;
        }
        f.write_str(")")
    }
}

/// The precision `cfg.learner.precision` asks for on `dev`: fp32 and bf16 as given (`None`),
/// `auto` chosen by [`choose`].
pub fn resolve(cfg: &Config, dev: &Device) -> anyhow::Result<(Precision, Option<PrecisionChoice>)> {
    match cfg.learner.precision {
        Precision::Auto => {
            let choice = choose(cfg, dev)?;
            Ok((choice.precision, Some(choice)))
        }
        p => Ok((p, None)),
    }
}

/// Times fp32 and bf16 updates of `cfg`'s networks at its batch size and learner threads on
/// `dev` (CPU with AVX512-BF16), alternated, and picks the faster; fp32 without timing where
/// bf16 cannot win.
pub fn choose(cfg: &Config, dev: &Device) -> anyhow::Result<PrecisionChoice> {
    if !dev.is_cpu() {
        return Ok(PrecisionChoice::untimed("not-a-cpu"));
    }
    if !Kernel::Avx512Bf16.available() {
        return Ok(PrecisionChoice::untimed("no-avx512-bf16"));
    }
    let batch = cfg.sac.batch_size;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
    let replay = random_replay(cfg, 4 * batch, &mut rng);
    let returns = Returns::for_config(&cfg.sac);
    let learner = |precision: Precision| -> anyhow::Result<SacLearner> {
        let mut c = cfg.clone();
        c.learner.precision = precision;
        let nets = SacNetworks::new(&c, 0, dev)?;
        Ok(SacLearner::new(nets, cfg.sac.clone(), dev.clone(), 0)?
            .with_threads(cfg.learner.threads)?)
    };
    let mut sides = [(learner(Precision::Fp32)?, 0.0), (learner(Precision::Bf16)?, 0.0)];
    let mut b = Batch::default();
    // One untimed update each: the first allocates and warms the caches.
    for (l, _) in &mut sides {
        replay.sample_into(batch, returns, &mut rng, &mut b);
        l.update(&b)?;
    }
    for _ in 0..ROUNDS {
        for (l, secs) in &mut sides {
            let t = Instant::now();
            for _ in 0..UPDATES_PER_ROUND {
                replay.sample_into(batch, returns, &mut rng, &mut b);
                l.update(&b)?;
            }
            *secs += t.elapsed().as_secs_f64();
        }
    }
    let rate = |secs: f64| (ROUNDS * UPDATES_PER_ROUND) as f64 / secs;
    Ok(PrecisionChoice::from_rates(rate(sides[0].1), rate(sides[1].1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bf16_is_chosen_only_when_clearly_faster() {
        assert_eq!(PrecisionChoice::from_rates(40.0, 60.0).precision, Precision::Bf16);
        assert_eq!(PrecisionChoice::from_rates(40.0, 30.0).precision, Precision::Fp32);
        // Within the margin: a tie goes to fp32's exact products.
        assert_eq!(PrecisionChoice::from_rates(40.0, 41.0).precision, Precision::Fp32);
        let c = PrecisionChoice::from_rates(40.0, 42.0);
        assert_eq!((c.precision, c.reason), (Precision::Bf16, "timed"));
        assert_eq!((c.fp32_updates_per_s, c.bf16_updates_per_s), (Some(40.0), Some(42.0)));
        assert_eq!(c.to_string(), "bf16 (timed: fp32 40.0 against bf16 42.0 updates/s)");
        assert_eq!(PrecisionChoice::untimed("not-a-cpu").to_string(), "fp32 (not-a-cpu)");
    }

    #[test]
    fn given_precisions_are_kept_and_auto_becomes_fp32_or_bf16() {
        let mut cfg = Config::default();
        let dev = Device::Cpu;
        for p in [Precision::Fp32, Precision::Bf16] {
            cfg.learner.precision = p;
            assert_eq!(resolve(&cfg, &dev).unwrap(), (p, None), "{p} is not timed");
        }
        cfg.learner.precision = Precision::Auto;
        cfg.learner.threads = 1;
        let (p, choice) = resolve(&cfg, &dev).unwrap();
        let choice = choice.expect("auto says how it chose");
        assert_eq!(p, choice.precision);
        assert_ne!(p, Precision::Auto);
        if Kernel::Avx512Bf16.available() {
            assert_eq!(choice.reason, "timed");
            assert!(choice.fp32_updates_per_s.unwrap() > 0.0);
            assert!(choice.bf16_updates_per_s.unwrap() > 0.0);
        } else {
            assert_eq!((p, choice.reason), (Precision::Fp32, "no-avx512-bf16"));
        }
    }
}
