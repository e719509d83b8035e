//! How one observation is stored: the LiDAR ranges as `u16` fixed-point (half the bytes of
//! `f32`), the few scalars after them (goal, velocities) as `f32`.
//!
//! Resolution: the full scale `scan_max` over 65,535 steps, 0.15 mm for the default 10 m LiDAR,
//! far below any real scanner's noise and below the simulator's collision sub-step. Ranges are
//! already clamped to `[range_min, range_max]` by the LiDAR and checked finite and non-negative
//! by the wire validation, so nothing is lost by clamping to `[0, scan_max]` here.

use dvnav_config::Config;

/// The split of an observation into a quantized scan and plain scalars.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObsCodec {
    /// Length of one observation.
    pub obs_dim: usize,
    /// Leading values stored as `u16` (0 stores everything as `f32`).
    pub scan_len: usize,
    /// Metres per `u16` step.
    scale: f32,
}

impl ObsCodec {
    /// The layout of the run's observations: `beams` ranges up to the LiDAR's `range_max`,
    /// then the scalars.
    pub fn for_config(cfg: &Config) -> Self {
        Self::new(cfg.obs_dim(), cfg.env.lidar.beams, cfg.env.lidar.range_max as f32)
    }

    /// `scan_len` leading values in `[0, scan_max]` stored as `u16`, the rest as `f32`.
    pub fn new(obs_dim: usize, scan_len: usize, scan_max: f32) -> Self {
        assert!(scan_len <= obs_dim, "scan longer than the observation");
        assert!(scan_max > 0.0 && scan_max.is_finite(), "scan full scale must be positive");
        Self { obs_dim, scan_len, scale: scan_max / u16::MAX as f32 }
    }

    /// Everything as `f32` (observations that are not LiDAR scans).
    pub fn plain(obs_dim: usize) -> Self {
        Self { obs_dim, scan_len: 0, scale: 1.0 }
    }

    /// Metres per stored scan step.
    pub fn scale(&self) -> f32 {
        self.scale
    }

    /// Values after the scan.
    pub fn extra_len(&self) -> usize {
        self.obs_dim - self.scan_len
    }

    /// Bytes one stored observation takes.
    pub fn bytes_per_obs(&self) -> usize {
        2 * self.scan_len + 4 * self.extra_len()
    }

    /// Appends the stored form of `obs` to `scan` and `extra`.
    pub fn encode(&self, obs: &[f32], scan: &mut Vec<u16>, extra: &mut Vec<f32>) {
        debug_assert_eq!(obs.len(), self.obs_dim);
        let inv = 1.0 / self.scale;
        // Rounding half away from zero and clamping to [0, u16::MAX], as `(d * inv).round()
        // .clamp(..) as u16` does, bit for bit (in f64 `x + 0.5` is exact, and `max` turns NaN
        // into 0), but without a call to `roundf` per value, so it vectorizes.
        let q = |d: f32| (f64::from(d * inv) + 0.5).max(0.0).min(u16::MAX as f64) as u16;
        scan.extend(obs[..self.scan_len].iter().map(|&d| q(d)));
        extra.extend_from_slice(&obs[self.scan_len..]);
    }

    /// Appends the observation stored as `scan`, `extra` to `out`.
    pub fn decode(&self, scan: &[u16], extra: &[f32], out: &mut Vec<f32>) {
        out.extend(scan.iter().map(|&q| q as f32 * self.scale));
        out.extend_from_slice(extra);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_round_trip_within_half_a_step_and_scalars_exactly() {
        let c = ObsCodec::new(6, 3, 10.0);
        let obs = [0.02, 4.567_89, 10.0, 1.25, -0.7, 0.3];
        let (mut s, mut e, mut out) = (Vec::new(), Vec::new(), Vec::new());
        c.encode(&obs, &mut s, &mut e);
        c.decode(&s, &e, &mut out);
        for i in 0..3 {
            assert!((out[i] - obs[i]).abs() <= 0.5 * 10.0 / 65535.0 + 1e-6, "{i}: {}", out[i]);
        }
        assert_eq!(&out[3..], &obs[3..]);
        assert_eq!(c.bytes_per_obs(), 18);
    }

    /// The vectorizable quantization is `round` then `clamp`, bit for bit: ties, the ends of
    /// the scale, negatives, NaN and infinities, and a sweep of values.
    #[test]
    fn quantization_equals_round_then_clamp() {
        let c = ObsCodec::new(1, 1, 10.0);
        let inv = 1.0 / c.scale();
        let mut xs = vec![0.0, -0.0, 1e-9, -1e-9, 10.0, 10.000_1, 1e9, -1e9, f32::NAN];
        xs.extend([f32::INFINITY, f32::NEG_INFINITY, f32::MIN_POSITIVE, -0.5 / inv]);
        // Exact ties of the scale (k + 0.5 steps) and their neighbours.
        for k in [0.0f32, 1.0, 2.0, 1000.0, 65_533.0, 65_534.0, 65_535.0] {
            let t = (k + 0.5) / inv;
            xs.extend([t, f32::from_bits(t.to_bits() - 1), f32::from_bits(t.to_bits() + 1)]);
        }
        xs.extend((0..200_000).map(|i| i as f32 * 5.3e-5 - 0.2));
        for x in xs {
            let (mut s, mut e) = (Vec::new(), Vec::new());
            c.encode(&[x], &mut s, &mut e);
            assert_eq!(s[0], (x * inv).round().clamp(0.0, u16::MAX as f32) as u16, "{x:e}");
        }
    }

    #[test]
    fn out_of_scale_ranges_clamp() {
        let c = ObsCodec::new(2, 2, 10.0);
        let (mut s, mut e) = (Vec::new(), Vec::new());
        c.encode(&[-1.0, 25.0], &mut s, &mut e);
        assert_eq!(s, vec![0, u16::MAX]);
    }

    #[test]
    fn plain_keeps_every_value() {
        let c = ObsCodec::plain(3);
        let (mut s, mut e, mut out) = (Vec::new(), Vec::new(), Vec::new());
        c.encode(&[0.1, 2e7, -3.0], &mut s, &mut e);
        c.decode(&s, &e, &mut out);
        assert_eq!(out, vec![0.1, 2e7, -3.0]);
        assert!(s.is_empty());
    }
}
