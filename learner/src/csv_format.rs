//! How numbers are spelled in the learner's CSV files (`metrics.csv`, `eval.csv`): serde
//! `serialize_with` helpers, so the row types keep plain `f64` fields and readers parse them
//! back with serde. The spellings are the files' own from before the csv crate: fixed decimals
//! for times and rates, `NaN` where there is no value yet, Prometheus' `+Inf`/`-Inf`. And how
//! rows are appended to them ([`append_rows`]).

use serde::Serializer;
use std::path::Path;

/// `NaN`, `+Inf`, `-Inf` or the shortest decimal that reads back as `v` (Prometheus' spelling).
pub fn number(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else if v.is_infinite() {
        if v > 0.0 { "+Inf".into() } else { "-Inf".into() }
    } else {
        format!("{v}")
    }
}

/// A field spelled by [`number`].
pub fn ser_number<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&number(*v))
}

/// A sequence of fields, each spelled by [`number`].
pub fn ser_numbers<S: Serializer>(v: &[f64], s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(v.iter().map(|&x| number(x)))
}

/// A field with two decimals.
pub fn ser_2_decimals<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(&format_args!("{v:.2}"))
}

/// A field with three decimals.
pub fn ser_3_decimals<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(&format_args!("{v:.3}"))
}

/// A field with four decimals, `NaN` when it is not finite.
pub fn ser_4_decimals_or_nan<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    if v.is_finite() { s.collect_str(&format_args!("{v:.4}")) } else { s.serialize_str("NaN") }
}

/// Appends `rows` to the CSV file at `path`, the header first when the file is new or empty:
/// one write, so a reader never sees half a batch of rows from this process.
pub fn append_rows<T: serde::Serialize>(
    path: &Path,
    rows: impl IntoIterator<Item = T>,
) -> anyhow::Result<()> {
    let mut file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| anyhow::anyhow!("cannot open {}: {e}", path.display()))?;
    let new = file.metadata()?.len() == 0;
    let mut w = csv::WriterBuilder::new().has_headers(new).from_writer(Vec::new());
    for r in rows {
        w.serialize(r)?;
    }
    std::io::Write::write_all(&mut file, &w.into_inner().map_err(|e| e.into_error())?)?;
    Ok(())
}
