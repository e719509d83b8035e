//! The CPU's measured matrix-product peak, the yardstick of `dvnav bench learner`'s GFLOP/s.
//!
//! Measured, not looked up: `threads` threads each multiply their own 512×512 fp32 matrices with
//! candle's CPU matmul (the gemm crate, the kernels the learner's layers run on) on one thread
//! each, which is how the learner spreads an update (row shards, candle single-threaded).
//! The bf16 peak is the same measurement with dvnav's AVX512-BF16 kernel
//! ([`dvnav_nav::bf16`]), on CPUs that have it.

use candle_core::{Device, Tensor};
use dvnav_nav::bf16::{Kernel, Precision, matmul};
use std::time::{Duration, Instant};

/// Side of the square matrices: big enough to reach the kernels' steady state, small enough
/// to stay in L2 as the learner's operands do.
pub const GEMM_SIDE: usize = 512;

/// Aggregate fp32 GFLOP/s of `threads` concurrent single-threaded 512³ products, each thread
/// running for about `per_thread` after two untimed products.
pub fn gemm_fp32_gflops(threads: usize, per_thread: Duration) -> candle_core::Result<f64> {
    gemm_gflops(threads, per_thread, Precision::Fp32)
}

/// As [`gemm_fp32_gflops`] with bf16 operands and fp32 sums through dvnav's AVX512-BF16
/// kernel; `None` where the CPU lacks it (the portable bf16 kernel is fp32 plus rounding, not a
/// peak of its own).
pub fn gemm_bf16_gflops(threads: usize, per_thread: Duration) -> candle_core::Result<Option<f64>> {
    if !Kernel::Avx512Bf16.available() {
        return Ok(None);
    }
    gemm_gflops(threads, per_thread, Precision::Bf16).map(Some)
}

fn gemm_gflops(threads: usize, per_thread: Duration, p: Precision) -> candle_core::Result<f64> {
    let threads = threads.max(1);
    let start = Instant::now();
    let flops = std::thread::scope(|s| {
        let workers: Vec<_> =
            (0..threads).map(|i| s.spawn(move || one_thread(i as u64, per_thread, p))).collect();
        workers
            .into_iter()
            .map(|w| w.join().expect("gemm worker panicked"))
            .sum::<candle_core::Result<f64>>()
    })?;
    Ok(flops / start.elapsed().as_secs_f64() / 1e9)
}

/// FLOPs done by one thread.
fn one_thread(seed: u64, run_for: Duration, p: Precision) -> candle_core::Result<f64> {
    let dev = Device::Cpu;
    let n = GEMM_SIDE;
    let a = Tensor::rand(-1f32, 1.0, (n, n), &dev)?;
    let b = Tensor::rand(-1f32, 1.0, (n, n), &dev)?.affine(1.0, seed as f64 * 1e-3)?;
    for _ in 0..2 {
        matmul(&a, &b, p)?;
    }
    let t = Instant::now();
    let mut done = 0usize;
    while done == 0 || t.elapsed() < run_for {
        matmul(&a, &b, p)?;
        done += 1;
    }
    Ok(done as f64 * 2.0 * (n * n * n) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_peak_is_a_positive_rate() {
        // Only that the measurement runs and divides the right way round: a 512³ product is
        // 0.27 GFLOP, and no CPU does one in under a microsecond or over ten seconds.
        let g = gemm_fp32_gflops(1, Duration::from_millis(20)).unwrap();
        assert!(g > 0.027 && g < 268_000.0, "{g}");
        match gemm_bf16_gflops(1, Duration::from_millis(20)).unwrap() {
            Some(g) => assert!(g > 0.027 && g < 268_000.0, "{g}"),
            None => assert!(!Kernel::Avx512Bf16.available()),
        }
    }
}
