//! A channels-last 1-D convolution that reads its input in place on the CPU: no im2col matrix.
//!
//! Why: [`crate::fused::unfold`] copies each output position's input window into a row of its
//! own, `kernel / stride` times the input (3.3x for the second convolution, ~5 MB per network at
//! batch 128), and its gradient folds a matrix as large back. With two learner threads each job
//! ran 10-20 % slower than alone, and what the cores share (cache, memory bandwidth) was the
//! suspect (docs/results.md, "Twin critics as jobs of their own").
//!
//! When the input length is a multiple of the stride, the window of output position `j` of
//! sample `b` starts at `(b·len/stride + j)·stride·channels` in the contiguous input: the
//! windows are the rows of one strided matrix, row stride `stride·channels`, rows
//! `kernel·channels` wide and overlapping. The rows `out_len..len/stride` of each sample's
//! period straddle two samples; they are computed and dropped (3 of 35 rows for the second
//! convolution, 3 of 108 for the first), cheaper than the copy. So:
//! - forward: one product of that view with the `(kernel·channels, out)` weight, then the
//!   valid rows kept;
//! - the weight's gradient: the view's transpose times the output gradient spread over the
//!   view's rows (zeros at the dropped ones);
//! - the input's gradient in fp32: for each group of `stride` kernel taps, the output gradient
//!   times that group's weights, accumulated by gemm straight into the input gradient's rows
//!   (a strided destination; `ceil(kernel/stride)` products and no col2im matrix); in bf16 the
//!   product as one matrix through the bf16 kernel, then the col2im.
//!
//! [`products_bias_act`] is the layer as the networks run it: the bias and the leaky ReLU are
//! applied in the same pass that keeps the valid rows (no copy of them first), and in backward
//! one pass writes the activation's gradient straight onto the view's rows (the spread, zeros
//! at the dropped rows) that both gradients read.

use crate::bf16::{Kernel, MatRef, Precision, gemm_f32, product};
use crate::fused::{ColumnSum, bias_leaky, f32_slice, leaky_grad};
use candle_core::{
    CpuStorage, CustomOp1, CustomOp2, CustomOp3, DType, Layout, Result, Shape, Tensor,
};

/// The ops' name in errors.
const NAME: &str = "conv in place";

/// The geometry of a convolution whose input windows are read in place.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InPlace {
    len: usize,
    channels: usize,
    kernel: usize,
    stride: usize,
    out_len: usize,
    out_channels: usize,
}

impl InPlace {
    /// The geometry for inputs of `len` positions, or `None` when the windows cannot be read
    /// in place (`len` not a multiple of `stride`, or shorter than the kernel).
    pub fn new(
        len: usize,
        channels: usize,
        kernel: usize,
        stride: usize,
        out_channels: usize,
    ) -> Option<Self> {
        (stride > 0 && kernel > 0 && channels > 0 && len >= kernel && len.is_multiple_of(stride))
            .then(|| Self {
                len,
                channels,
                kernel,
                stride,
                out_len: (len - kernel) / stride + 1,
                out_channels,
            })
    }

    /// View rows per sample.
    fn period(&self) -> usize {
        self.len / self.stride
    }

    /// Floats from one window to the next.
    fn step(&self) -> usize {
        self.stride * self.channels
    }

    /// Floats in one window.
    fn width(&self) -> usize {
        self.kernel * self.channels
    }

    /// Rows of the view over `batch` samples: whole periods but for the last sample, whose
    /// dropped rows would reach past the input.
    fn view_rows(&self, batch: usize) -> usize {
        if batch == 0 { 0 } else { (batch - 1) * self.period() + self.out_len }
    }

    /// The windows of `x` (`batch` samples) as the rows of one matrix.
    fn view<'a>(&self, x: &'a [f32], batch: usize) -> MatRef<'a> {
        MatRef::strided(x, self.view_rows(batch), self.width(), self.step(), 1)
    }

    /// Each sample's valid rows (`out_len · out` floats) of a product over the view's rows.
    fn valid_rows<'a>(&self, z: &'a [f32], batch: usize) -> impl Iterator<Item = &'a [f32]> {
        let (period, valid) = (self.period() * self.out_channels, self.out_len * self.out_channels);
        (0..batch).map(move |b| &z[b * period..b * period + valid])
    }

    /// The output gradient `(batch·out_len, out)` on the view's rows, zeros at dropped rows.
    fn spread(&self, g: &[f32], batch: usize) -> Vec<f32> {
        let o = self.out_channels;
        let mut out = vec![0f32; self.view_rows(batch) * o];
        for (b, rows) in g.chunks_exact(self.out_len * o).enumerate() {
            let at = b * self.period() * o;
            out[at..at + rows.len()].copy_from_slice(rows);
        }
        out
    }

    /// Samples in an input of `dims`, checked against the geometry.
    fn batch_of_input(&self, dims: &[usize]) -> Result<usize> {
        match *dims {
            [b, l, c] if l == self.len && c == self.channels => Ok(b),
            _ => candle_core::bail!(
                "conv in place: input {dims:?}, expected (batch, {}, {})",
                self.len,
                self.channels
            ),
        }
    }

    /// Samples in an output (gradient) of `dims`, checked against the geometry.
    fn batch_of_output(&self, dims: &[usize]) -> Result<usize> {
        match *dims {
            [rows, o] if o == self.out_channels && rows % self.out_len == 0 => {
                Ok(rows / self.out_len)
            }
            _ => candle_core::bail!(
                "conv in place: output {dims:?}, expected (batch·{}, {})",
                self.out_len,
                self.out_channels
            ),
        }
    }

    /// Checks a spread output gradient of `dims` for `batch` samples.
    fn check_spread(&self, dims: &[usize], batch: usize) -> Result<()> {
        if dims != [self.view_rows(batch), self.out_channels] {
            candle_core::bail!(
                "conv in place: spread gradient {dims:?}, expected ({}, {}) for {batch} samples",
                self.view_rows(batch),
                self.out_channels
            );
        }
        Ok(())
    }

    /// Checks a weight of `dims`.
    fn check_weight(&self, dims: &[usize]) -> Result<()> {
        if dims != [self.width(), self.out_channels] {
            candle_core::bail!(
                "conv in place: weight {dims:?}, expected ({}, {})",
                self.width(),
                self.out_channels
            );
        }
        Ok(())
    }
}

/// The products of a channels-last convolution with its kernel, before the bias:
/// `x` `(batch, len, channels)` and `w` `(kernel·channels, out)` (rows in the window's
/// (position, channel) order) → `(batch·out_len, out)`, gradients to both. CPU and f32 only.
pub fn products(x: &Tensor, w: &Tensor, geometry: InPlace, precision: Precision) -> Result<Tensor> {
    if !x.device().is_cpu() || x.dtype() != DType::F32 || w.dtype() != DType::F32 {
        candle_core::bail!("conv in place: f32 tensors on the CPU only");
    }
    x.contiguous()?.apply_op2(&w.contiguous()?, Forward { g: geometry, precision })
}

/// The forward products.
#[derive(Clone, Copy)]
struct Forward {
    g: InPlace,
    precision: Precision,
}

impl CustomOp2 for Forward {
    fn name(&self) -> &'static str {
        "conv-in-place"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let g = self.g;
        let batch = g.batch_of_input(l1.dims())?;
        g.check_weight(l2.dims())?;
        let (x, w) = (f32_slice(s1, l1, NAME)?, f32_slice(s2, l2, NAME)?);
        let o = g.out_channels;
        let z = product(g.view(x, batch), MatRef::row_major(w, g.width(), o), self.precision);
        let mut y = Vec::with_capacity(batch * g.out_len * o);
        for rows in g.valid_rows(&z, batch) {
            y.extend_from_slice(rows);
        }
        Ok((CpuStorage::F32(y), Shape::from((batch * g.out_len, o))))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        // The output gradient on the view's rows, once for both gradients.
        let dz = grad.contiguous()?.apply_op1_no_bwd(&Spread(self.g))?;
        let dw = x.apply_op2_no_bwd(&dz, &WeightGrad(*self))?;
        let dx = dz.apply_op2_no_bwd(w, &InputGrad { f: *self, batch: x.dim(0)? })?;
        Ok((Some(dx), Some(dw)))
    }
}

/// The convolution with its bias and a leaky ReLU of `slope` (0: ReLU): `x` `(batch, len,
/// channels)`, `w` `(kernel·channels, out)`, `bias` `(out)` → `act(products + bias)`
/// `(batch·out_len, out)`, gradients to all three. The same values and gradients as
/// [`products`] followed by [`crate::fused::bias_act`], in fewer passes. CPU and f32 only.
pub fn products_bias_act(
    x: &Tensor,
    w: &Tensor,
    bias: &Tensor,
    geometry: InPlace,
    precision: Precision,
    slope: f32,
) -> Result<Tensor> {
    if !x.device().is_cpu() || [x.dtype(), w.dtype(), bias.dtype()].iter().any(|&d| d != DType::F32)
    {
        candle_core::bail!("conv in place: f32 tensors on the CPU only");
    }
    let f = Forward { g: geometry, precision };
    x.contiguous()?.apply_op3(&w.contiguous()?, &bias.contiguous()?, ForwardAct { f, slope })
}

/// [`Forward`] with the bias and activation applied as the valid rows are kept.
struct ForwardAct {
    f: Forward,
    slope: f32,
}

impl CustomOp3 for ForwardAct {
    fn name(&self) -> &'static str {
        "conv-in-place-bias-act"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let g = self.f.g;
        let batch = g.batch_of_input(l1.dims())?;
        g.check_weight(l2.dims())?;
        let o = g.out_channels;
        if l3.dims() != [o] {
            candle_core::bail!("conv in place: bias {:?}, expected ({o})", l3.dims());
        }
        let (x, w) = (f32_slice(s1, l1, NAME)?, f32_slice(s2, l2, NAME)?);
        let bias = f32_slice(s3, l3, NAME)?;
        let z = product(g.view(x, batch), MatRef::row_major(w, g.width(), o), self.f.precision);
        let slope = self.slope;
        let mut y = Vec::with_capacity(batch * g.out_len * o);
        for row in g.valid_rows(&z, batch).flat_map(|rows| rows.chunks_exact(o)) {
            y.extend(row.iter().zip(bias).map(|(&v, &b)| bias_leaky(v, b, slope)));
        }
        Ok((CpuStorage::F32(y), Shape::from((batch * g.out_len, o))))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _bias: &Tensor,
        res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let g = self.f.g;
        // The activation's gradient on the view's rows, once for every gradient below.
        let dz =
            grad.contiguous()?.apply_op2_no_bwd(res, &SpreadActGrad { g, slope: self.slope })?;
        // The dropped rows are zeros, so the column sum over the view is the bias gradient.
        let dbias = dz.apply_op1_no_bwd(&ColumnSum)?;
        let dw = x.apply_op2_no_bwd(&dz, &WeightGrad(self.f))?;
        let dx = if x.track_op() {
            Some(dz.apply_op2_no_bwd(w, &InputGrad { f: self.f, batch: x.dim(0)? })?)
        } else {
            None
        };
        Ok((dx, Some(dw), Some(dbias)))
    }
}

/// `grad · act'(y)` spread over the view's rows, zeros at the dropped rows: the output gradient
/// of [`ForwardAct`] as [`Spread`] lays it out.
struct SpreadActGrad {
    g: InPlace,
    slope: f32,
}

impl CustomOp2 for SpreadActGrad {
    fn name(&self) -> &'static str {
        "conv-in-place-spread-act-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let g = self.g;
        let batch = g.batch_of_output(l1.dims())?;
        if l1.dims() != l2.dims() {
            candle_core::bail!("conv in place: gradient {:?} vs output {:?}", l1.dims(), l2.dims());
        }
        let (grad, y) = (f32_slice(s1, l1, NAME)?, f32_slice(s2, l2, NAME)?);
        let (o, slope) = (g.out_channels, self.slope);
        let (valid, dropped) = (g.out_len * o, (g.period() - g.out_len) * o);
        let mut out = Vec::with_capacity(g.view_rows(batch) * o);
        for (b, (grad, y)) in grad.chunks_exact(valid).zip(y.chunks_exact(valid)).enumerate() {
            if b > 0 {
                out.resize(out.len() + dropped, 0.0);
            }
            out.extend(grad.iter().zip(y).map(|(&g, &y)| leaky_grad(g, y, slope)));
        }
        Ok((CpuStorage::F32(out), Shape::from((g.view_rows(batch), o))))
    }
}

/// The output gradient `(batch·out_len, out)` spread over the view's rows, `(view rows, out)`
/// with zeros at the dropped rows.
struct Spread(InPlace);

impl CustomOp1 for Spread {
    fn name(&self) -> &'static str {
        "conv-in-place-spread"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let g = self.0;
        let batch = g.batch_of_output(l.dims())?;
        let dz = g.spread(f32_slice(s, l, NAME)?, batch);
        Ok((CpuStorage::F32(dz), Shape::from((g.view_rows(batch), g.out_channels))))
    }
}

/// The weight's gradient from the input and the spread output gradient.
struct WeightGrad(Forward);

impl CustomOp2 for WeightGrad {
    fn name(&self) -> &'static str {
        "conv-in-place-weight-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let g = self.0.g;
        let batch = g.batch_of_input(l1.dims())?;
        g.check_spread(l2.dims(), batch)?;
        let (x, dz) = (f32_slice(s1, l1, NAME)?, f32_slice(s2, l2, NAME)?);
        let o = g.out_channels;
        let dz = MatRef::row_major(dz, g.view_rows(batch), o);
        let dw = product(g.view(x, batch).t(), dz, self.0.precision);
        Ok((CpuStorage::F32(dw), Shape::from((g.width(), o))))
    }
}

/// The input's gradient from the spread output gradient and the weight.
struct InputGrad {
    f: Forward,
    /// Samples (the view's row count does not give it back when it is 0).
    batch: usize,
}

impl CustomOp2 for InputGrad {
    fn name(&self) -> &'static str {
        "conv-in-place-input-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let (g, batch) = (self.f.g, self.batch);
        g.check_spread(l1.dims(), batch)?;
        g.check_weight(l2.dims())?;
        let (dz, w) = (f32_slice(s1, l1, NAME)?, f32_slice(s2, l2, NAME)?);
        let (o, c, step, rows) = (g.out_channels, g.channels, g.step(), g.view_rows(batch));
        let dz = MatRef::row_major(dz, rows, o);
        let mut dx = vec![0f32; batch * g.len * c];
        match self.f.precision {
            Precision::Fp32 | Precision::Auto => {
                // Taps q·stride .. (q+1)·stride of every window are the input rows one window
                // step further for each q: gemm adds dZ · W_qᵀ into dx's rows from q steps on.
                for t0 in (0..g.kernel).step_by(g.stride) {
                    let cols = (t0 + g.stride).min(g.kernel) - t0;
                    let w_q = MatRef::strided(&w[t0 * c * o..], o, cols * c, 1, o);
                    let from = t0 / g.stride * step;
                    gemm_f32(&mut dx[from..], step, dz, w_q);
                }
            }
            Precision::Bf16 => {
                let w = MatRef::row_major(w, g.width(), o).t();
                let cols = Kernel::detect().gemm(dz, w);
                for (r, row) in cols.chunks_exact(g.width()).enumerate() {
                    for (d, &v) in dx[r * step..r * step + row.len()].iter_mut().zip(row) {
                        *d += v;
                    }
                }
            }
        }
        Ok((CpuStorage::F32(dx), Shape::from((batch, g.len, c))))
    }
}

#[cfg(test)]
mod tests;
