//! Reading back floats from JSON that serde_json wrote: it writes NaN and ±∞ as `null`.

use serde::{Deserialize, Deserializer};

/// The default of a float field a file lacks (an older file, a missing number): NaN, not measured.
pub fn nan() -> f64 {
    f64::NAN
}

/// An `f64` field that may hold `null` (a non-finite value when it was written): read as NaN,
/// so the summary of a run whose losses diverged still reads.
pub fn f64_or_nan<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}
