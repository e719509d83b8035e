//! bf16 mixed precision for the networks' matrix products (`learner.precision = "bf16"`, or
//! `"auto"`, the default, where the learner measured bf16 faster).
//!
//! [`matmul`] rounds both operands to bfloat16 (round to nearest even) and sums their products
//! in fp32, in forward and in backward (dA = G·Bᵀ and dB = Aᵀ·G are bf16 products again).
//! Everything else stays fp32: master weights, Adam moments, the losses and the element-wise
//! work; the recipe of mixed-precision training (Micikevicius et al., ICLR 2018) and of
//! `torch.autocast` on CPUs.
//!
//! Two kernels, the same arithmetic up to the order of the fp32 sums:
//! - [`Kernel::Avx512Bf16`], where the CPU has AVX512-BF16 (detected at run time): operands
//!   packed as bf16 pairs and multiplied with `vdpbf16ps`, 32 products into 16 fp32 sums per
//!   instruction, twice the fp32 FMA's rate;
//! - [`Kernel::RoundedF32`] elsewhere: the rounded operands multiplied by gemm in fp32. A
//!   product of two bf16 numbers (8 significant bits each) is exact in fp32, so this computes
//!   what the bf16 kernel computes, at the fp32 rate: on such a CPU bf16 mode is slower than
//!   fp32 (the rounding pass), and exists so that its numerics are the same and testable on
//!   every machine.
//!
//! On other devices (CUDA) the operands are cast to bf16 and candle's matmul runs there.

use candle_core::{CpuStorage, CustomOp2, DType, Layout, Result, Shape, Tensor};
pub use dvnav_config::Precision;

/// `a · b` for 2-D `a` `(m, k)` and `b` `(k, n)` in the given precision; gradients flow to
/// both operands in the same precision. `auto` is the learner's to resolve by measuring
/// before it builds its networks (`dvnav_learner::bench::precision`); a product given `auto`
/// itself runs in fp32.
pub fn matmul(a: &Tensor, b: &Tensor, precision: Precision) -> Result<Tensor> {
    match precision {
        Precision::Fp32 | Precision::Auto => a.matmul(b),
        Precision::Bf16 if a.device().is_cpu() => {
            if a.dtype() != DType::F32 || b.dtype() != DType::F32 {
                candle_core::bail!("bf16 matmul: f32 tensors only, got {:?}", a.dtype());
            }
            a.apply_op2(b, MatmulBf16)
        }
        Precision::Bf16 => {
            a.to_dtype(DType::BF16)?.matmul(&b.to_dtype(DType::BF16)?)?.to_dtype(a.dtype())
        }
    }
}

/// The bf16 bits of `x`, rounded to nearest even (NaN stays a quiet NaN).
#[inline]
pub fn to_bf16_bits(x: f32) -> u16 {
    let bits = x.to_bits();
    if bits & 0x7fff_ffff > 0x7f80_0000 {
        return ((bits >> 16) | 0x40) as u16;
    }
    ((bits + 0x7fff + ((bits >> 16) & 1)) >> 16) as u16
}

/// `x` rounded to the nearest bf16 number, as an f32.
#[inline]
pub fn round_to_bf16(x: f32) -> f32 {
    f32::from_bits((to_bf16_bits(x) as u32) << 16)
}

/// A read-only view of a 2-D f32 matrix with any strides (a transposed view included).
#[derive(Clone, Copy, Debug)]
pub struct MatRef<'a> {
    pub(crate) data: &'a [f32],
    pub(crate) rows: usize,
    pub(crate) cols: usize,
    pub(crate) row_stride: usize,
    pub(crate) col_stride: usize,
}

impl<'a> MatRef<'a> {
    /// A row-major `rows × cols` matrix.
    pub fn row_major(data: &'a [f32], rows: usize, cols: usize) -> Self {
        assert!(data.len() >= rows * cols, "{} values for a {rows}x{cols} matrix", data.len());
        Self { data, rows, cols, row_stride: cols, col_stride: 1 }
    }

    /// A `rows × cols` matrix whose element `(i, j)` is `data[i·row_stride + j·col_stride]`;
    /// rows may overlap (a convolution's input read in place, [`crate::conv`]).
    ///
    /// # Panics
    /// If the last element lies past `data`.
    pub fn strided(
        data: &'a [f32],
        rows: usize,
        cols: usize,
        row_stride: usize,
        col_stride: usize,
    ) -> Self {
        if rows > 0 && cols > 0 {
            let last = (rows - 1) * row_stride + (cols - 1) * col_stride;
            assert!(last < data.len(), "a {rows}x{cols} view reaches {last} of {}", data.len());
        }
        Self { data, rows, cols, row_stride, col_stride }
    }

    /// The transposed view.
    pub fn t(self) -> Self {
        Self {
            data: self.data,
            rows: self.cols,
            cols: self.rows,
            row_stride: self.col_stride,
            col_stride: self.row_stride,
        }
    }

    /// The element at row `i`, column `j`.
    #[inline]
    fn at(&self, i: usize, j: usize) -> f32 {
        self.data[i * self.row_stride + j * self.col_stride]
    }

    /// bf16 bits of `(i, 2q)` in the low half and of `(i, 2q + 1)` in the high half, zero past
    /// the last column: the operand pairs `vdpbf16ps` multiplies.
    #[inline]
    fn row_pair(&self, i: usize, q: usize) -> u32 {
        let j = 2 * q;
        let lo = to_bf16_bits(self.at(i, j)) as u32;
        let hi = if j + 1 < self.cols { to_bf16_bits(self.at(i, j + 1)) as u32 } else { 0 };
        lo | hi << 16
    }

    /// As [`Self::row_pair`], down column `j`: rows `2q` and `2q + 1`.
    #[inline]
    fn col_pair(&self, q: usize, j: usize) -> u32 {
        let i = 2 * q;
        let lo = to_bf16_bits(self.at(i, j)) as u32;
        let hi = if i + 1 < self.rows { to_bf16_bits(self.at(i + 1, j)) as u32 } else { 0 };
        lo | hi << 16
    }

    /// Row `i` when its elements are adjacent in memory.
    fn contiguous_row(&self, i: usize) -> Option<&'a [f32]> {
        (self.col_stride == 1 || self.cols <= 1)
            .then(|| &self.data[i * self.row_stride..i * self.row_stride + self.cols])
    }

    /// The operand rounded to bf16 for gemm, with its (row, column) strides. A matrix that
    /// fills its span (row-major, or a transposed view of one) is rounded in place order, one
    /// pass over memory; any other view is gathered row-major.
    fn rounded(&self) -> (Vec<f32>, usize, usize) {
        let n = self.rows * self.cols;
        let (rs, cs) = (self.row_stride, self.col_stride);
        if (rs == self.cols && cs == 1) || (rs == 1 && cs == self.rows) {
            (self.data[..n].iter().map(|&x| round_to_bf16(x)).collect(), rs, cs)
        } else {
            let mut out = Vec::with_capacity(n);
            for i in 0..self.rows {
                out.extend((0..self.cols).map(|j| round_to_bf16(self.at(i, j))));
            }
            (out, self.cols, 1)
        }
    }
}

/// Which implementation multiplies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// `vdpbf16ps` on packed bf16 pairs.
    Avx512Bf16,
    /// The rounded operands through gemm's fp32 kernels.
    RoundedF32,
}

impl Kernel {
    /// The fastest kernel this CPU runs.
    pub fn detect() -> Self {
        if Self::Avx512Bf16.available() { Self::Avx512Bf16 } else { Self::RoundedF32 }
    }

    /// The kernel's name in reports: `avx512-bf16` or `rounded-fp32`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Avx512Bf16 => "avx512-bf16",
            Self::RoundedF32 => "rounded-fp32",
        }
    }

    /// True when this CPU can run the kernel.
    pub fn available(self) -> bool {
        match self {
            Self::RoundedF32 => true,
            #[cfg(target_arch = "x86_64")]
            Self::Avx512Bf16 => {
                std::is_x86_feature_detected!("avx512f")
                    && std::is_x86_feature_detected!("avx512bf16")
            }
            #[cfg(not(target_arch = "x86_64"))]
            Self::Avx512Bf16 => false,
        }
    }

    /// `a · b`, row-major `(a.rows, b.cols)`, bf16 operands and fp32 sums.
    ///
    /// # Panics
    /// If the inner dimensions differ or the kernel is not [`Self::available`].
    pub fn gemm(self, a: MatRef, b: MatRef) -> Vec<f32> {
        assert_eq!(
            a.cols, b.rows,
            "bf16 gemm: ({}, {}) x ({}, {})",
            a.rows, a.cols, b.rows, b.cols
        );
        assert!(self.available(), "the {self:?} kernel needs a CPU with AVX512-BF16");
        if a.rows == 0 || b.cols == 0 || a.cols == 0 {
            return vec![0.0; a.rows * b.cols];
        }
        match self {
            Self::RoundedF32 => rounded_f32(a, b),
            // SAFETY: available() checked above that the CPU has AVX512F and AVX512-BF16.
            #[cfg(target_arch = "x86_64")]
            Self::Avx512Bf16 => unsafe { blocked::gemm(a, b, avx512::tile, avx512::PACK) },
            #[cfg(not(target_arch = "x86_64"))]
            Self::Avx512Bf16 => unreachable!("checked by available()"),
        }
    }
}

fn rounded_f32(a: MatRef, b: MatRef) -> Vec<f32> {
    let (m, k, n) = (a.rows, a.cols, b.cols);
    let ((a, a_rs, a_cs), (b, b_rs, b_cs)) = (a.rounded(), b.rounded());
    let mut out = vec![0f32; m * n];
    // SAFETY: `out` is m×n row-major; `a` (m×k) and `b` (k×n) hold every element their
    // strides reach ([`MatRef::rounded`]).
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            out.as_mut_ptr(),
            1,
            n as isize,
            false,
            a.as_ptr(),
            a_cs as isize,
            a_rs as isize,
            b.as_ptr(),
            b_cs as isize,
            b_rs as isize,
            0.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
    out
}

/// `a · b`, row-major, in the given precision.
pub(crate) fn product(a: MatRef, b: MatRef, precision: Precision) -> Vec<f32> {
    match precision {
        Precision::Bf16 => Kernel::detect().gemm(a, b),
        Precision::Fp32 | Precision::Auto => {
            assert_eq!(a.cols, b.rows, "gemm: ({}, {}) x ({}, {})", a.rows, a.cols, b.rows, b.cols);
            let len = a.rows * b.cols;
            // Not zero-filled first: gemm overwrites (`read_dst = false`) every element, zeros
            // where the inner dimension is empty, and a zero fill of every layer's output was
            // memset the update paid for nothing.
            let mut out = Vec::with_capacity(len);
            if len > 0 {
                // SAFETY: `out` has room for the (a.rows, b.cols) row-major product, and gemm
                // reads only `a.data` and `b.data` (checked by MatRef's constructors).
                unsafe { gemm_raw(out.as_mut_ptr(), b.cols, a, b, false) };
            }
            // SAFETY: gemm wrote all `len` elements above.
            unsafe { out.set_len(len) };
            out
        }
    }
}

/// `dst += a · b` in fp32, `dst` row `i` starting at `i·dst_row_stride`.
///
/// # Panics
/// If the inner dimensions differ or `dst` is too short.
pub(crate) fn gemm_f32(dst: &mut [f32], dst_row_stride: usize, a: MatRef, b: MatRef) {
    assert_eq!(a.cols, b.rows, "gemm: ({}, {}) x ({}, {})", a.rows, a.cols, b.rows, b.cols);
    let (m, n, k) = (a.rows, b.cols, a.cols);
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    assert!((m - 1) * dst_row_stride + n <= dst.len(), "gemm: destination too short");
    // SAFETY: every element gemm reads lies in `a.data` and `b.data` (MatRef's constructors
    // check the last one) and every element it touches in `dst` (checked above).
    unsafe { gemm_raw(dst.as_mut_ptr(), dst_row_stride, a, b, true) }
}

/// `dst = a · b` (`accumulate = false`: `dst` is only written, so it may be uninitialized) or
/// `dst += a · b` in fp32, `dst` row `i` starting at `i·dst_row_stride`.
///
/// # Safety
/// `dst` must be valid for writes (and reads, when accumulating) of `(a.rows - 1) ·
/// dst_row_stride + b.cols` floats, and `a.cols == b.rows`.
unsafe fn gemm_raw(dst: *mut f32, dst_row_stride: usize, a: MatRef, b: MatRef, accumulate: bool) {
    // SAFETY: the caller's contract; MatRef's constructors check that `a.data` and `b.data`
    // hold every element their strides reach.
    unsafe {
        gemm::gemm(
            a.rows,
            b.cols,
            a.cols,
            dst,
            1,
            dst_row_stride as isize,
            accumulate,
            a.data.as_ptr(),
            a.col_stride as isize,
            a.row_stride as isize,
            b.data.as_ptr(),
            b.col_stride as isize,
            b.row_stride as isize,
            if accumulate { 1.0 } else { 0.0 },
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

/// The blocked product behind the `vdpbf16ps` kernel, kept apart from the instruction so that
/// its packing and blocking run (with [`blocked::scalar_tile`]) on every machine's tests.
///
/// Blocking: the shared dimension in blocks of `KC` pairs; per block, `b` packed once into
/// panels of `NR` columns (pair-interleaved: lane j of a vector holds rows 2q and 2q + 1 of
/// column j), then `MR` rows of `a` at a time packed as pairs and multiplied against each
/// panel into `MR × NR` fp32 sums held in registers.
mod blocked {
    use super::{MatRef, to_bf16_bits};

    /// Columns per panel: two vectors of 16 fp32 sums.
    pub(super) const NR: usize = 32;
    /// Rows per tile: 12 accumulators, 2 `b` vectors and a broadcast out of 32 registers.
    pub(super) const MR: usize = 6;
    /// Pairs of the shared dimension per block: a 32-column panel block is 32 KiB, in L2.
    const KC: usize = 256;

    /// `tile = a_pack · panel` over `kc` pairs: `a_pack` is `MR × kc` pairs, row-major, the
    /// panel `kc × NR` pairs. Unsafe: an implementation may need CPU features the caller
    /// checked.
    pub(super) type TileKernel = unsafe fn(&[u32], &[u32], usize, &mut [f32; MR * NR]);

    /// How operands are packed: [`pack_rows`] and [`pack_panels`]'s signatures and results
    /// (bit for bit), perhaps with CPU features the caller checked.
    #[derive(Clone, Copy)]
    pub(super) struct Pack {
        pub rows: unsafe fn(&MatRef, usize, usize, usize, &mut [u32]),
        pub panels: unsafe fn(&MatRef, usize, usize, usize, &mut [u32]),
    }

    /// The plain-Rust packing, on every CPU (the tests' reference).
    #[cfg(test)]
    pub(super) const PORTABLE: Pack = Pack { rows: pack_rows, panels: pack_panels };

    #[inline]
    fn pair(lo: f32, hi: f32) -> u32 {
        to_bf16_bits(lo) as u32 | (to_bf16_bits(hi) as u32) << 16
    }

    /// Rows `r0 .. r0 + MR` of `a` (zero past `a.rows`), pairs `q0 .. q0 + kc`, into `out`
    /// (`MR × kc`).
    pub(super) fn pack_rows(a: &MatRef, r0: usize, q0: usize, kc: usize, out: &mut [u32]) {
        for (r, row) in out[..MR * kc].chunks_exact_mut(kc).enumerate() {
            let i = r0 + r;
            match (i < a.rows).then(|| a.contiguous_row(i)) {
                None => row.fill(0),
                Some(Some(values)) => {
                    let seg = &values[(2 * q0).min(a.cols)..(2 * (q0 + kc)).min(a.cols)];
                    let mut pairs = seg.chunks_exact(2);
                    let mut filled = 0;
                    for (o, p) in row.iter_mut().zip(&mut pairs) {
                        *o = pair(p[0], p[1]);
                        filled += 1;
                    }
                    if let [last] = pairs.remainder() {
                        row[filled] = to_bf16_bits(*last) as u32;
                        filled += 1;
                    }
                    row[filled..].fill(0);
                }
                Some(None) => {
                    for (q, o) in row.iter_mut().enumerate() {
                        *o = if 2 * (q0 + q) < a.cols { a.row_pair(i, q0 + q) } else { 0 };
                    }
                }
            }
        }
    }

    /// Pairs `q0 .. q0 + kc` of `b`, every column, into `panels` panels (`kc × NR` each,
    /// zero past `b.cols` and past `b.rows`).
    pub(super) fn pack_panels(b: &MatRef, q0: usize, kc: usize, panels: usize, out: &mut [u32]) {
        for p in 0..panels {
            let (j0, cols) = (p * NR, NR.min(b.cols - p * NR));
            for (q, lanes) in out[p * kc * NR..(p + 1) * kc * NR].chunks_exact_mut(NR).enumerate() {
                let i = 2 * (q0 + q);
                if i >= b.rows {
                    lanes.fill(0);
                    continue;
                }
                let next = (i + 1 < b.rows).then(|| b.contiguous_row(i + 1)).flatten();
                match (b.contiguous_row(i), next) {
                    (Some(lo), Some(hi)) => {
                        for ((o, &l), &h) in lanes.iter_mut().zip(&lo[j0..j0 + cols]).zip(&hi[j0..])
                        {
                            *o = pair(l, h);
                        }
                    }
                    _ => {
                        for (jj, o) in lanes[..cols].iter_mut().enumerate() {
                            *o = b.col_pair(q0 + q, j0 + jj);
                        }
                    }
                }
                lanes[cols..].fill(0);
            }
        }
    }

    /// `a · b` with bf16 operand pairs and fp32 sums, the tiles computed by `tile`.
    ///
    /// # Safety
    /// `tile` and `pack` must be callable on this CPU.
    pub(super) unsafe fn gemm(a: MatRef, b: MatRef, tile: TileKernel, pack: Pack) -> Vec<f32> {
        let (m, n) = (a.rows, b.cols);
        let pairs = a.cols.div_ceil(2);
        let panels = n.div_ceil(NR);
        let mut out = vec![0f32; m * n];
        let mut b_pack = vec![0u32; KC.min(pairs) * panels * NR];
        let mut a_pack = vec![0u32; MR * KC.min(pairs)];
        let mut sums = [0f32; MR * NR];
        for q0 in (0..pairs).step_by(KC) {
            let kc = KC.min(pairs - q0);
            // SAFETY: the caller vouches for `pack`.
            unsafe { (pack.panels)(&b, q0, kc, panels, &mut b_pack) };
            for r0 in (0..m).step_by(MR) {
                let mr = MR.min(m - r0);
                // SAFETY: as above.
                unsafe { (pack.rows)(&a, r0, q0, kc, &mut a_pack) };
                for p in 0..panels {
                    // SAFETY: the caller vouches for `tile`; the slices hold MR·kc and kc·NR
                    // pairs.
                    unsafe { tile(&a_pack[..MR * kc], &b_pack[p * kc * NR..], kc, &mut sums) };
                    let cols = NR.min(n - p * NR);
                    for r in 0..mr {
                        let dst = &mut out[(r0 + r) * n + p * NR..][..cols];
                        for (d, s) in dst.iter_mut().zip(&sums[r * NR..r * NR + cols]) {
                            *d += s;
                        }
                    }
                }
            }
        }
        out
    }

    /// What `vdpbf16ps` computes, lane by lane in plain Rust: the tests' stand-in for the
    /// instruction on CPUs without it.
    #[cfg(test)]
    pub(super) unsafe fn scalar_tile(
        a_pack: &[u32],
        panel: &[u32],
        kc: usize,
        t: &mut [f32; MR * NR],
    ) {
        let f = |bits: u32| f32::from_bits(bits << 16);
        t.fill(0.0);
        for q in 0..kc {
            for r in 0..MR {
                let a = a_pack[r * kc + q];
                for j in 0..NR {
                    let b = panel[q * NR + j];
                    t[r * NR + j] += f(a & 0xffff) * f(b & 0xffff) + f(a >> 16) * f(b >> 16);
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    //! The tile kernel on `vdpbf16ps`, and the packing 16 values at a time.
    //!
    //! The packing was as costly as the products (32 % of a bf16 update in `perf` against the
    //! tile's 27 %: one rounding and one bounds-checked load per element). The vector packers
    //! round with the same integer arithmetic as [`super::to_bf16_bits`] (not `vcvtne2ps2bf16`,
    //! which reads subnormal inputs as zero), so they pack the same bits as the portable ones.

    use super::MatRef;
    use super::blocked::{MR, NR, Pack, pack_panels, pack_rows};
    use std::arch::x86_64::*;

    /// The packing with AVX-512F.
    pub(super) const PACK: Pack = Pack { rows: pack_rows_avx512, panels: pack_panels_avx512 };

    /// bf16 bits of 16 floats, each in the low half of its 32-bit lane: round to nearest even,
    /// NaN to a quiet NaN, as [`super::to_bf16_bits`].
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn bf16_lanes(x: __m512) -> __m512i {
        let bits = _mm512_castps_si512(x);
        let abs = _mm512_and_si512(bits, _mm512_set1_epi32(0x7fff_ffff));
        let nan = _mm512_cmpgt_epu32_mask(abs, _mm512_set1_epi32(0x7f80_0000));
        let high = _mm512_srli_epi32::<16>(bits);
        let odd = _mm512_and_si512(high, _mm512_set1_epi32(1));
        let rounded = _mm512_srli_epi32::<16>(_mm512_add_epi32(
            _mm512_add_epi32(bits, _mm512_set1_epi32(0x7fff)),
            odd,
        ));
        let quiet = _mm512_or_si512(high, _mm512_set1_epi32(0x40));
        _mm512_mask_blend_epi32(nan, rounded, quiet)
    }

    /// Lanes `0..n` set (n ≤ 16).
    #[inline]
    fn first(n: usize) -> __mmask16 {
        if n >= 16 { 0xffff } else { (1u16 << n) - 1 }
    }

    /// `values[..n]` (n ≤ 32, zero past it) as 16 bf16 pairs: pair q holds values 2q and
    /// 2q + 1, the layout of [`super::blocked::pack_rows`].
    ///
    /// # Safety
    /// `values` must hold `n` readable floats.
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn pairs_of(values: *const f32, n: usize) -> __m512i {
        // SAFETY: masked loads read only lanes below `n`, which the caller vouches for.
        let (lo, hi) = unsafe {
            (
                _mm512_maskz_loadu_ps(first(n), values),
                _mm512_maskz_loadu_ps(first(n.saturating_sub(16)), values.add(16.min(n))),
            )
        };
        // Each 32-bit lane's low half is a bf16; truncating to 16 bits and concatenating puts
        // values 2q and 2q + 1 side by side in 32-bit pair q.
        let lo = _mm512_cvtepi32_epi16(bf16_lanes(lo));
        let hi = _mm512_cvtepi32_epi16(bf16_lanes(hi));
        _mm512_inserti64x4::<1>(_mm512_castsi256_si512(lo), hi)
    }

    /// [`pack_rows`], a contiguous row 32 values at a time.
    ///
    /// # Safety
    /// The CPU must have AVX-512F.
    #[target_feature(enable = "avx512f")]
    unsafe fn pack_rows_avx512(a: &MatRef, r0: usize, q0: usize, kc: usize, out: &mut [u32]) {
        if a.contiguous_row(0).is_none() {
            if a.row_stride == 1 {
                // SAFETY: the caller vouches for AVX-512F.
                return unsafe { pack_rows_of_columns(a, r0, q0, kc, out) };
            }
            return pack_rows(a, r0, q0, kc, out);
        }
        for (r, row) in out[..MR * kc].chunks_exact_mut(kc).enumerate() {
            let Some(values) = (r0 + r < a.rows).then(|| a.contiguous_row(r0 + r)).flatten() else {
                row.fill(0);
                continue;
            };
            let seg = &values[(2 * q0).min(a.cols)..(2 * (q0 + kc)).min(a.cols)];
            for (c, chunk) in row.chunks_mut(16).enumerate() {
                let start = (32 * c).min(seg.len());
                let n = (seg.len() - start).min(32);
                // SAFETY: `seg[start..start + n]` is in bounds; the store writes `chunk.len()`
                // ≤ 16 lanes into `chunk`.
                unsafe {
                    let pairs = pairs_of(seg.as_ptr().add(start), n);
                    _mm512_mask_storeu_epi32(chunk.as_mut_ptr().cast(), first(chunk.len()), pairs);
                }
            }
        }
    }

    /// [`pack_rows`] for a transposed view (`row_stride` 1: `xᵀ` in a weight gradient
    /// `xᵀ·dy`), whose `MR` rows at pair q are adjacent values of two rows of memory.
    ///
    /// # Safety
    /// The CPU must have AVX-512F.
    #[target_feature(enable = "avx512f")]
    unsafe fn pack_rows_of_columns(a: &MatRef, r0: usize, q0: usize, kc: usize, out: &mut [u32]) {
        let mask = first(MR.min(a.rows.saturating_sub(r0)));
        let mut lanes = [0u32; 16];
        for q in 0..kc {
            let j = 2 * (q0 + q);
            let pairs = if j >= a.cols {
                _mm512_setzero_si512()
            } else {
                let at = |j: usize| &a.data[r0 + j * a.col_stride..];
                // SAFETY: the masked loads read the rows below `a.rows`, in `a.data` at
                // column j (and j + 1 when it exists).
                unsafe {
                    let lo = bf16_lanes(_mm512_maskz_loadu_ps(mask, at(j).as_ptr()));
                    let hi = if j + 1 < a.cols {
                        bf16_lanes(_mm512_maskz_loadu_ps(mask, at(j + 1).as_ptr()))
                    } else {
                        _mm512_setzero_si512()
                    };
                    _mm512_or_si512(lo, _mm512_slli_epi32::<16>(hi))
                }
            };
            // SAFETY: 16 lanes into a 16-lane scratch.
            unsafe { _mm512_storeu_si512(lanes.as_mut_ptr().cast(), pairs) };
            for (r, &pair) in lanes.iter().take(MR).enumerate() {
                out[r * kc + q] = pair;
            }
        }
    }

    /// [`pack_panels`]: for contiguous rows two rows' values interleaved 16 at a time; for a
    /// transposed view (`row_stride` 1: the weights `Wᵀ` of `x·Wᵀ`, whose pairs are adjacent
    /// in a row of `W`) each column's pairs 16 at a time, then scattered down its lane.
    ///
    /// # Safety
    /// The CPU must have AVX-512F.
    #[target_feature(enable = "avx512f")]
    unsafe fn pack_panels_avx512(b: &MatRef, q0: usize, kc: usize, panels: usize, out: &mut [u32]) {
        if b.contiguous_row(0).is_some() {
            for p in 0..panels {
                let (j0, cols) = (p * NR, NR.min(b.cols - p * NR));
                let block = &mut out[p * kc * NR..(p + 1) * kc * NR];
                for (q, lanes) in block.chunks_exact_mut(NR).enumerate() {
                    let i = 2 * (q0 + q);
                    if i >= b.rows {
                        lanes.fill(0);
                        continue;
                    }
                    let lo = &b.contiguous_row(i).expect("checked above")[j0..j0 + cols];
                    let hi = (i + 1 < b.rows)
                        .then(|| &b.contiguous_row(i + 1).expect("checked above")[j0..j0 + cols]);
                    for (h, half) in lanes.chunks_exact_mut(16).enumerate() {
                        let start = (16 * h).min(cols);
                        let mask = first(cols - start);
                        // SAFETY: masked loads read lanes below `cols - start` of rows that
                        // hold `cols` values from `j0`; the store writes 16 lanes into `half`.
                        unsafe {
                            let l = bf16_lanes(_mm512_maskz_loadu_ps(mask, lo.as_ptr().add(start)));
                            let h = match hi {
                                Some(hi) => {
                                    bf16_lanes(_mm512_maskz_loadu_ps(mask, hi.as_ptr().add(start)))
                                }
                                None => _mm512_setzero_si512(),
                            };
                            let pairs = _mm512_or_si512(l, _mm512_slli_epi32::<16>(h));
                            _mm512_storeu_si512(half.as_mut_ptr().cast(), pairs);
                        }
                    }
                }
            }
            return;
        }
        if b.row_stride != 1 {
            return pack_panels(b, q0, kc, panels, out);
        }
        // Column j of `b` is contiguous: values (2q, j) and (2q + 1, j) are adjacent.
        let lo_row = (2 * q0).min(b.rows);
        let n = (2 * (q0 + kc)).min(b.rows) - lo_row;
        let mut column = [0u32; 16];
        for p in 0..panels {
            let (j0, cols) = (p * NR, NR.min(b.cols - p * NR));
            let block = &mut out[p * kc * NR..(p + 1) * kc * NR];
            for jj in 0..NR {
                if jj >= cols {
                    for q in 0..kc {
                        block[q * NR + jj] = 0;
                    }
                    continue;
                }
                let start = (j0 + jj) * b.col_stride + lo_row;
                let values = &b.data[start..start + n];
                for c in 0..kc.div_ceil(16) {
                    let from = (32 * c).min(n);
                    // SAFETY: `values[from..from + m]` is in bounds (m ≤ 32); the store fills
                    // the 16-pair scratch.
                    unsafe {
                        let pairs = pairs_of(values.as_ptr().add(from), (n - from).min(32));
                        _mm512_storeu_si512(column.as_mut_ptr().cast(), pairs);
                    }
                    for (k, &pair) in column.iter().enumerate().take(kc - 16 * c) {
                        block[(16 * c + k) * NR + jj] = pair;
                    }
                }
            }
        }
    }

    /// `tile = a_pack · panel` ([`super::blocked::TileKernel`]) with AVX512-BF16.
    ///
    /// # Safety
    /// The CPU must have AVX512F and AVX512-BF16.
    #[target_feature(enable = "avx512f,avx512bf16")]
    pub(super) unsafe fn tile(a_pack: &[u32], panel: &[u32], kc: usize, tile: &mut [f32; MR * NR]) {
        assert!(a_pack.len() >= MR * kc && panel.len() >= kc * NR);
        let mut acc = [[_mm512_setzero_ps(); 2]; MR];
        let (a, b) = (a_pack.as_ptr(), panel.as_ptr());
        for q in 0..kc {
            // SAFETY: q < kc, so the reads stay inside the lengths asserted above.
            unsafe {
                let lo: __m512bh = std::mem::transmute(_mm512_loadu_si512(b.add(q * NR).cast()));
                let hi: __m512bh =
                    std::mem::transmute(_mm512_loadu_si512(b.add(q * NR + 16).cast()));
                for (r, sums) in acc.iter_mut().enumerate() {
                    let pair: __m512bh =
                        std::mem::transmute(_mm512_set1_epi32(*a.add(r * kc + q) as i32));
                    sums[0] = _mm512_dpbf16_ps(sums[0], pair, lo);
                    sums[1] = _mm512_dpbf16_ps(sums[1], pair, hi);
                }
            }
        }
        for (r, sums) in acc.iter().enumerate() {
            // SAFETY: the tile holds MR rows of NR = 32 values.
            unsafe {
                _mm512_storeu_ps(tile.as_mut_ptr().add(r * NR), sums[0]);
                _mm512_storeu_ps(tile.as_mut_ptr().add(r * NR + 16), sums[1]);
            }
        }
    }
}

/// The custom op behind [`matmul`] on the CPU.
struct MatmulBf16;

fn mat_ref<'a>(s: &'a CpuStorage, l: &Layout) -> Result<MatRef<'a>> {
    let CpuStorage::F32(data) = s else {
        candle_core::bail!("bf16 matmul: f32 tensors only");
    };
    let (dims, stride) = (l.dims(), l.stride());
    if dims.len() != 2 {
        candle_core::bail!("bf16 matmul: 2-D operands only, got {dims:?}");
    }
    Ok(MatRef {
        data: &data[l.start_offset()..],
        rows: dims[0],
        cols: dims[1],
        row_stride: stride[0],
        col_stride: stride[1],
    })
}

impl CustomOp2 for MatmulBf16 {
    fn name(&self) -> &'static str {
        "matmul-bf16"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (a, b) = (mat_ref(s1, l1)?, mat_ref(s2, l2)?);
        if a.cols != b.rows {
            candle_core::bail!("bf16 matmul: {:?} x {:?}", l1.dims(), l2.dims());
        }
        Ok((CpuStorage::F32(Kernel::detect().gemm(a, b)), Shape::from((a.rows, b.cols))))
    }

    fn bwd(
        &self,
        a: &Tensor,
        b: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let da = grad.apply_op2_no_bwd(&b.t()?, &MatmulBf16)?;
        let db = a.t()?.apply_op2_no_bwd(grad, &MatmulBf16)?;
        Ok((Some(da), Some(db)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};
    use rand::{Rng, SeedableRng};

    /// The fp32 product writes every element of its output, which it allocates without a
    /// zero fill: over memory that held NaNs (freed just before, so the allocator likely
    /// hands it back) it equals a naive product, and an empty inner dimension gives zeros.
    #[test]
    fn the_fp32_product_overwrites_its_output() {
        for (m, k, n) in [(37, 19, 23), (128, 64, 1), (1, 300, 5), (9, 0, 7)] {
            let (a, b) = (random(m, k, 1), random(k, n, 2));
            drop(std::hint::black_box(vec![f32::NAN; m * n]));
            let out =
                product(MatRef::row_major(&a, m, k), MatRef::row_major(&b, k, n), Precision::Fp32);
            assert_eq!(out.len(), m * n);
            for i in 0..m {
                for j in 0..n {
                    let want: f32 = (0..k).map(|t| a[i * k + t] * b[t * n + j]).sum();
                    let got = out[i * n + j];
                    assert!(
                        (got - want).abs() <= 1e-4 * (1.0 + want.abs()),
                        "({m},{k},{n}) [{i},{j}]: {got} vs {want}"
                    );
                }
            }
        }
    }

    fn random(rows: usize, cols: usize, seed: u64) -> Vec<f32> {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        (0..rows * cols).map(|_| rng.random_range(-1.0f32..1.0)).collect()
    }

    fn fp64_product(a: &[f32], b: &[f32], m: usize, k: usize, n: usize) -> Vec<f64> {
        let mut out = vec![0f64; m * n];
        for i in 0..m {
            for p in 0..k {
                for j in 0..n {
                    out[i * n + j] += a[i * k + p] as f64 * b[p * n + j] as f64;
                }
            }
        }
        out
    }

    #[test]
    fn rounding_is_to_nearest_even() {
        assert_eq!(round_to_bf16(1.0), 1.0);
        // 1 + 2^-8 lies halfway between 1 and 1 + 2^-7: ties go to the even mantissa, 1.
        assert_eq!(round_to_bf16(1.0 + 2f32.powi(-8)), 1.0);
        // 1 + 3·2^-8 lies halfway between 1 + 2^-7 and 1 + 2^-6: the even one is 1 + 2^-6.
        assert_eq!(round_to_bf16(1.0 + 3.0 * 2f32.powi(-8)), 1.0 + 2f32.powi(-6));
        assert_eq!(round_to_bf16(1.0 + 2f32.powi(-8) + 2f32.powi(-20)), 1.0 + 2f32.powi(-7));
        assert_eq!(round_to_bf16(-3.0), -3.0);
        assert!(round_to_bf16(f32::NAN).is_nan());
        assert_eq!(round_to_bf16(f32::INFINITY), f32::INFINITY);
        assert_eq!(round_to_bf16(f32::MAX), f32::INFINITY, "rounds past the largest bf16");
    }

    /// The bf16 product against an exact one, within the bound of bf16 operand rounding:
    /// each operand is off by at most 2^-8 relatively (8 significant bits), so each product by
    /// at most about 2^-7, and a sum of k such products by 2^-7 · Σ|a||b| (plus fp32's own
    /// rounding of the sums, far below).
    #[test]
    fn bf16_products_stay_within_the_rounding_bound_of_fp32() {
        for (m, k, n) in [(1, 1, 1), (7, 3, 5), (13, 20, 32), (6, 513, 33), (130, 64, 70)] {
            let (a, b) = (random(m, k, 1), random(k, n, 2));
            let exact = fp64_product(&a, &b, m, k, n);
            let abs: Vec<f32> = a.iter().map(|v| v.abs()).collect();
            let babs: Vec<f32> = b.iter().map(|v| v.abs()).collect();
            let bound = fp64_product(&abs, &babs, m, k, n);
            for kernel in [Kernel::RoundedF32, Kernel::Avx512Bf16] {
                if !kernel.available() {
                    continue;
                }
                let got = kernel.gemm(MatRef::row_major(&a, m, k), MatRef::row_major(&b, k, n));
                for ((g, e), s) in got.iter().zip(&exact).zip(&bound) {
                    let err = (*g as f64 - e).abs();
                    assert!(err <= s * 2f64.powi(-7) + 1e-6, "{kernel:?} {m}x{k}x{n}: {g} vs {e}");
                }
                // And it is not simply fp32: somewhere the rounding shows.
                let worst =
                    got.iter().zip(&exact).map(|(g, e)| (*g as f64 - e).abs()).fold(0.0, f64::max);
                assert!(k < 8 || worst > 1e-5, "{kernel:?} {m}x{k}x{n} looks like fp32 ({worst})");
            }
        }
    }

    /// Where the CPU has AVX512-BF16, its kernel computes the same bf16 arithmetic as the
    /// portable one, up to the order of fp32 sums.
    #[test]
    fn the_avx512_kernel_matches_the_portable_one_where_the_cpu_has_it() {
        if !Kernel::Avx512Bf16.available() {
            eprintln!("this CPU has no AVX512-BF16; only the portable kernel is checked");
            return;
        }
        for (m, k, n) in [(1, 1, 1), (5, 7, 31), (6, 512, 32), (7, 1025, 65), (129, 20, 32)] {
            let (a, b) = (random(m, k, 3), random(k, n, 4));
            let (a, b) = (MatRef::row_major(&a, m, k), MatRef::row_major(&b, k, n));
            let fast = Kernel::Avx512Bf16.gemm(a, b);
            let portable = Kernel::RoundedF32.gemm(a, b);
            for (f, p) in fast.iter().zip(&portable) {
                assert!((f - p).abs() <= 1e-5 * (k as f32).sqrt(), "{m}x{k}x{n}: {f} vs {p}");
            }
        }
    }

    /// The packing and blocking of the AVX512 kernel, with a plain-Rust stand-in for the
    /// instruction, against the portable kernel: shapes across the tile, panel and block edges
    /// (MR = 6, NR = 32, KC = 256 pairs), row-major and transposed operands (the backward
    /// pass's views).
    #[test]
    fn the_blocked_kernel_matches_the_portable_one_on_every_layout() {
        for (m, k, n) in [(1, 1, 1), (5, 7, 31), (6, 512, 32), (7, 1025, 65), (13, 20, 33)] {
            let (a, b) = (random(m, k, 8), random(k, n, 9));
            // The same matrices stored transposed: a view with strides (1, rows).
            let transpose = |v: &[f32], r: usize, c: usize| -> Vec<f32> {
                (0..c).flat_map(|j| (0..r).map(move |i| v[i * c + j])).collect()
            };
            let (at, bt) = (transpose(&a, m, k), transpose(&b, k, n));
            fn views<'a>(x: &'a [f32], xt: &'a [f32], r: usize, c: usize) -> [MatRef<'a>; 2] {
                let t = MatRef { data: xt, rows: r, cols: c, row_stride: 1, col_stride: r };
                [MatRef::row_major(x, r, c), t]
            }
            let portable =
                Kernel::RoundedF32.gemm(MatRef::row_major(&a, m, k), MatRef::row_major(&b, k, n));
            for av in views(&a, &at, m, k) {
                for bv in views(&b, &bt, k, n) {
                    // SAFETY: the scalar tile needs no CPU feature.
                    let blocked =
                        unsafe { blocked::gemm(av, bv, blocked::scalar_tile, blocked::PORTABLE) };
                    let strided = Kernel::RoundedF32.gemm(av, bv);
                    for ((x, y), z) in blocked.iter().zip(&portable).zip(&strided) {
                        let tol = 1e-5 * (k as f32).sqrt();
                        assert!((x - y).abs() <= tol, "blocked {m}x{k}x{n}: {x} vs {y}");
                        assert!((z - y).abs() <= tol, "strided {m}x{k}x{n}: {z} vs {y}");
                    }
                }
            }
        }
    }

    /// Where the CPU has AVX-512F, the vector packers pack the same bits as the portable ones:
    /// row-major and transposed operands, across the tile, panel and block edges, odd shared
    /// dimensions, NaN, infinities, subnormals and ties.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_vector_packing_is_the_portable_packing() {
        if !std::is_x86_feature_detected!("avx512f") {
            eprintln!("this CPU has no AVX-512F; the vector packing is not checked");
            return;
        }
        let specials = [
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            1e-40,
            -1e-45,
            1.0 + 2f32.powi(-8),
            1.0 + 3.0 * 2f32.powi(-8),
            f32::MAX,
            0.0,
            -0.0,
        ];
        for (rows, cols) in [(1, 1), (7, 5), (13, 33), (40, 64), (513, 70), (6, 1025)] {
            let mut x = random(rows, cols, 11);
            for (v, s) in x.iter_mut().step_by(7).zip(specials.iter().cycle()) {
                *v = *s;
            }
            let xt: Vec<f32> = (0..cols)
                .flat_map(|j| (0..rows).map(|i| x[i * cols + j]).collect::<Vec<_>>())
                .collect();
            let views = [
                MatRef::row_major(&x, rows, cols),
                MatRef { data: &xt, rows, cols, row_stride: 1, col_stride: rows },
            ];
            for v in views {
                let pairs = cols.div_ceil(2);
                for q0 in (0..pairs).step_by(256) {
                    let kc = 256.min(pairs - q0);
                    for r0 in (0..rows).step_by(6) {
                        let (mut a, mut b) = (vec![7u32; 6 * kc], vec![9u32; 6 * kc]);
                        // SAFETY: AVX-512F checked above; the portable packer needs nothing.
                        unsafe {
                            (blocked::PORTABLE.rows)(&v, r0, q0, kc, &mut a);
                            (avx512::PACK.rows)(&v, r0, q0, kc, &mut b);
                        }
                        assert_eq!(a, b, "rows {rows}x{cols} r0 {r0} q0 {q0}");
                    }
                }
                // As panels: the same matrix as the right operand (its rows are the pairs').
                let pairs = rows.div_ceil(2);
                let panels = cols.div_ceil(32);
                for q0 in (0..pairs).step_by(256) {
                    let kc = 256.min(pairs - q0);
                    let (mut a, mut b) =
                        (vec![7u32; kc * panels * 32], vec![9u32; kc * panels * 32]);
                    // SAFETY: as above.
                    unsafe {
                        (blocked::PORTABLE.panels)(&v, q0, kc, panels, &mut a);
                        (avx512::PACK.panels)(&v, q0, kc, panels, &mut b);
                    }
                    assert_eq!(a, b, "panels {rows}x{cols} q0 {q0}");
                }
            }
        }
    }

    /// Forward and both gradients through the op against fp32 matmul, transposed operands
    /// included (the backward pass multiplies by views).
    #[test]
    fn the_op_and_its_gradients_follow_fp32_within_bf16_tolerance() {
        let dev = Device::Cpu;
        let a =
            Var::from_tensor(&Tensor::from_vec(random(9, 40, 5), (9, 40), &dev).unwrap()).unwrap();
        let w = Var::from_tensor(&Tensor::from_vec(random(24, 40, 6), (24, 40), &dev).unwrap())
            .unwrap();
        let g = Tensor::from_vec(random(9, 24, 7), (9, 24), &dev).unwrap();
        let run = |p: Precision| {
            let y = matmul(&a, &w.t().unwrap(), p).unwrap();
            let grads = (&y * &g).unwrap().sum_all().unwrap().backward().unwrap();
            let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            (flat(&y), flat(grads.get(&a).unwrap()), flat(grads.get(&w).unwrap()))
        };
        let (y32, da32, dw32) = run(Precision::Fp32);
        let (y16, da16, dw16) = run(Precision::Bf16);
        // |values| ≤ 1 over sums of 40 (y), 24 (da) and 9 (dw) products.
        for (what, x32, x16, k) in
            [("y", &y32, &y16, 40.0), ("da", &da32, &da16, 24.0), ("dw", &dw32, &dw16, 9.0)]
        {
            let worst = x32.iter().zip(x16).map(|(p, q)| (p - q).abs()).fold(0f32, f32::max);
            assert!(worst <= k * 2f32.powi(-7), "{what}: off by {worst}");
            assert!(worst > 0.0, "{what}: bf16 mode computed exactly fp32");
        }
    }
}
