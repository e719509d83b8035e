//! Flush-to-zero for the learner's threads.
//!
//! As SAC trains, some weights, Adam moments and gradients shrink into the subnormal range
//! (|x| < 1.2e-38), and every multiply that touches one takes a slow microcode path on x86:
//! the same update then runs up to several times slower than on fresh weights. Treating
//! subnormal inputs and results as zero (MXCSR's DAZ and FTZ bits) changes values far below
//! anything the losses can resolve, and is what oneDNN, and so PyTorch's CPU kernels, do.
//! MXCSR is per thread: every thread that runs updates calls [`flush_denormals_to_zero`].

/// Sets FTZ and DAZ on the calling thread; `false` where the CPU has no such mode (not x86-64).
pub fn flush_denormals_to_zero() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        const FTZ: u32 = 1 << 15;
        const DAZ: u32 = 1 << 6;
        let mut csr: u32 = 0;
        // SAFETY: stmxcsr/ldmxcsr read and write this thread's SSE control register; setting
        // FTZ and DAZ (supported by every x86-64 CPU) changes only how subnormals round.
        unsafe {
            std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack));
            csr |= FTZ | DAZ;
            std::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack));
        }
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subnormals_become_zero_on_this_thread_only() {
        // Run on a thread of its own: the mode must not leak into the test harness's threads.
        let flushed = std::thread::spawn(|| {
            let set = flush_denormals_to_zero();
            let tiny = std::hint::black_box(1e-30f32);
            (set, tiny * std::hint::black_box(1e-10f32))
        })
        .join()
        .unwrap();
        let tiny = std::hint::black_box(1e-30f32);
        let kept = tiny * std::hint::black_box(1e-10f32);
        if flushed.0 {
            assert_eq!(flushed.1, 0.0, "FTZ: a subnormal product reads as zero");
        }
        assert!(kept > 0.0 && kept < f32::MIN_POSITIVE, "other threads keep subnormals: {kept}");
    }
}
