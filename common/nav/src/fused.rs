//! Fused CPU kernels for the networks' hottest element-wise work, as candle custom ops.
//!
//! Why: in a SAC update on the CPU, candle's generic element-wise machinery (one pass and one
//! fresh buffer per op, masks built from several comparison ops in backward) cost as much as the
//! matrix products themselves (the profile is in docs/results.md, "Fused kernels"). Each op
//! here does its work in one pass, in forward and in backward:
//!
//! - [`bias_act`]: `act(x + bias)` with a leaky slope (0: ReLU), the layer epilogue of every
//!   convolution and hidden linear layer. Backward: one pass for dx, a row sum for dbias.
//! - [`unfold`]: the im2col of a channels-last 1-D convolution: each output row is a contiguous
//!   slice of the input (positions `j·stride .. j·stride + kernel`, all channels), so forward
//!   is a memcpy per row and backward a strided accumulation (col2im), where candle's
//!   `index_select` + `index_add` went through generic gather/scatter.
//!
//! - [`reciprocal_scan`]: the scan encoder's input `1 / max(d + a, floor)` with a learnable
//!   offset `a`. Backward: the offset's gradient summed in the same pass, where candle's
//!   `broadcast_add`, `clamp` and `recip` made about twenty passes over the batch's ranges
//!   (two masks from comparisons per clamp bound, each cast, multiplied and divided).
//!
//! On devices other than the CPU (the `cuda` feature) the same functions fall back to
//! composite candle ops with identical results, so a model is defined once.

use candle_core::{
    CpuStorage, CustomOp1, CustomOp2, CustomOp3, DType, Device, Layout, Result, Shape, Tensor,
};

/// `act(v + b)`: a leaky ReLU of `slope` (0: ReLU) after the bias, the epilogue every fused
/// layer applies.
#[inline]
pub(crate) fn bias_leaky(v: f32, b: f32, slope: f32) -> f32 {
    let y = v + b;
    if y > 0.0 { y } else { slope * y }
}

/// `g · act'` read from the activation's output `y` (`y > 0` exactly where its input was, for
/// `slope ≥ 0`).
#[inline]
pub(crate) fn leaky_grad(g: f32, y: f32, slope: f32) -> f32 {
    if y > 0.0 { g } else { slope * g }
}

/// `x + bias` (bias broadcast over the last dimension) through a leaky ReLU of `slope`
/// (0: ReLU).
pub fn bias_act(x: &Tensor, bias: &Tensor, slope: f32) -> Result<Tensor> {
    if x.device().is_cpu() && x.dtype() == DType::F32 {
        x.contiguous()?.apply_op2(&bias.contiguous()?, BiasAct { slope })
    } else {
        let y = x.broadcast_add(bias)?;
        if slope == 0.0 { y.relu() } else { y.maximum(&(&y * slope as f64)?) }
    }
}

/// `1 / max(scan + offset, floor)`: ranges `(…)` with a learnable `(1,)` offset, the scan
/// encoder's reciprocal preprocessing. Values and gradients are candle's
/// `scan.broadcast_add(offset)?.clamp(floor, f64::MAX)?.recip()` (at `scan + offset == floor`
/// the gradient is halved, as candle's `maximum` splits it between equal arguments); the
/// offset's gradient is summed in another order, so it agrees to rounding.
pub fn reciprocal_scan(scan: &Tensor, offset: &Tensor, floor: f32) -> Result<Tensor> {
    if scan.device().is_cpu() && scan.dtype() == DType::F32 {
        scan.contiguous()?.apply_op2(&offset.contiguous()?, ReciprocalScan { floor })
    } else {
        scan.broadcast_add(offset)?.clamp(floor as f64, f64::MAX)?.recip()
    }
}

/// The rows of a channels-last 1-D convolution's input, `(batch, len, channels)` →
/// `(batch, out_len, kernel·channels)` with `out_len = (len − kernel)/stride + 1`.
pub fn unfold(x: &Tensor, kernel: usize, stride: usize) -> Result<Tensor> {
    unfold_at(x, kernel, stride, None)
}

/// [`unfold`] with the gather positions of devices other than the CPU made beforehand by
/// [`unfold_index`] (made here when `None`).
pub fn unfold_at(
    x: &Tensor,
    kernel: usize,
    stride: usize,
    index: Option<&Tensor>,
) -> Result<Tensor> {
    let (b, len, c) = x.dims3()?;
    if len < kernel {
        candle_core::bail!("unfold: {len} positions are fewer than the kernel {kernel}");
    }
    let out_len = (len - kernel) / stride + 1;
    if x.device().is_cpu() && x.dtype() == DType::F32 {
        x.contiguous()?.apply_op1(Unfold { kernel, stride, len, channels: c, out_len })
    } else {
        let idx = match index {
            Some(idx) => idx.clone(),
            None => unfold_index(len, kernel, stride, x.device())?,
        };
        x.index_select(&idx, 1)?.reshape((b, out_len, kernel * c))
    }
}

/// The input positions [`unfold`] gathers off the CPU, `(out_len·kernel,)` u32 on `dev`. A
/// layer makes them once: an upload from host memory in every forward pass is what a CUDA
/// graph capture of the update cannot contain (8.4 kB for the first convolution, above the
/// small uploads candle caches for captures).
pub fn unfold_index(len: usize, kernel: usize, stride: usize, dev: &Device) -> Result<Tensor> {
    if len < kernel {
        candle_core::bail!("unfold: {len} positions are fewer than the kernel {kernel}");
    }
    let out_len = (len - kernel) / stride + 1;
    let idx: Vec<u32> =
        (0..out_len).flat_map(|j| (0..kernel).map(move |k| (j * stride + k) as u32)).collect();
    Tensor::from_vec(idx, out_len * kernel, dev)
}

/// The f32 values of a contiguous CPU tensor; `what` names the op in errors.
pub(crate) fn f32_slice<'a>(s: &'a CpuStorage, l: &Layout, what: &str) -> Result<&'a [f32]> {
    let CpuStorage::F32(data) = s else {
        candle_core::bail!("{what}: f32 tensors only");
    };
    match l.contiguous_offsets() {
        Some((a, b)) => Ok(&data[a..b]),
        None => candle_core::bail!("{what}: contiguous tensors only"),
    }
}

/// `act(x + bias)`.
struct BiasAct {
    slope: f32,
}

impl CustomOp2 for BiasAct {
    fn name(&self) -> &'static str {
        "bias-act"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let x = f32_slice(s1, l1, "bias-act")?;
        let bias = f32_slice(s2, l2, "bias-act")?;
        let n = bias.len();
        if l1.dims().last() != Some(&n) || l2.dims().len() != 1 {
            candle_core::bail!("bias-act: bias {:?} for input {:?}", l2.dims(), l1.dims());
        }
        let s = self.slope;
        let mut out = Vec::with_capacity(x.len());
        for row in x.chunks_exact(n) {
            out.extend(row.iter().zip(bias).map(|(&v, &b)| bias_leaky(v, b, s)));
        }
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        _x: &Tensor,
        bias: &Tensor,
        res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        // y > 0 exactly where x + bias > 0 (slope ≥ 0), so the result serves as the mask.
        let dx = grad.contiguous()?.apply_op2_no_bwd(res, &ActGrad { slope: self.slope })?;
        let dbias = bias.track_op().then(|| dx.apply_op1_no_bwd(&ColumnSum)).transpose()?;
        Ok((Some(dx), dbias))
    }
}

/// `1 / max(scan + offset, floor)`.
#[derive(Clone, Copy)]
struct ReciprocalScan {
    floor: f32,
}

impl ReciprocalScan {
    /// The offset of a `(1,)` tensor, checked.
    fn offset(s: &CpuStorage, l: &Layout) -> Result<f32> {
        match f32_slice(s, l, "reciprocal-scan")? {
            [a] => Ok(*a),
            _ => candle_core::bail!("reciprocal-scan: offset {:?}, expected one value", l.dims()),
        }
    }

    /// `d/dx` of the clamp and reciprocal at `x = d + a`, times `g`, as candle's backward
    /// computes it: `−g / c²` with `c = max(x, floor)`, all of it where `x > floor`, half at
    /// `x == floor`, none below.
    fn grad(self, x: f32, g: f32) -> f32 {
        let c = x.max(self.floor);
        let dc = -(g / (c * c));
        if x > self.floor {
            dc
        } else if x == self.floor {
            dc / 2.0
        } else {
            0.0 * dc
        }
    }
}

impl CustomOp2 for ReciprocalScan {
    fn name(&self) -> &'static str {
        "reciprocal-scan"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let scan = f32_slice(s1, l1, "reciprocal-scan")?;
        let a = Self::offset(s2, l2)?;
        let out = scan.iter().map(|&d| 1.0 / (d + a).max(self.floor)).collect();
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        scan: &Tensor,
        offset: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let grad = grad.contiguous()?;
        let grad_of = |summed| ReciprocalScanGrad { op: *self, summed };
        let d_offset = scan.apply_op3_no_bwd(offset, &grad, &grad_of(true))?;
        // The ranges are data in training; their gradient only where a caller tracks them.
        let d_scan = if scan.track_op() {
            Some(scan.apply_op3_no_bwd(offset, &grad, &grad_of(false))?)
        } else {
            None
        };
        Ok((d_scan, Some(d_offset)))
    }
}

/// The gradients of [`ReciprocalScan`] from `(scan, offset, grad)`: the ranges' (element-wise)
/// or, `summed`, the offset's (their sum).
struct ReciprocalScanGrad {
    op: ReciprocalScan,
    summed: bool,
}

impl CustomOp3 for ReciprocalScanGrad {
    fn name(&self) -> &'static str {
        if self.summed { "reciprocal-scan-offset-grad" } else { NAME_GRAD }
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
        let (scan, g) = (f32_slice(s1, l1, NAME_GRAD)?, f32_slice(s3, l3, NAME_GRAD)?);
        let a = ReciprocalScan::offset(s2, l2)?;
        if scan.len() != g.len() {
            candle_core::bail!("{NAME_GRAD}: {:?} vs {:?}", l1.dims(), l3.dims());
        }
        let grads = scan.iter().zip(g).map(|(&d, &g)| self.op.grad(d + a, g));
        if self.summed {
            // Summed in f64: a batch is ~70k terms of both signs.
            let sum: f64 = grads.map(f64::from).sum();
            Ok((CpuStorage::F32(vec![sum as f32]), l2.shape().clone()))
        } else {
            Ok((CpuStorage::F32(grads.collect()), l1.shape().clone()))
        }
    }
}

const NAME_GRAD: &str = "reciprocal-scan-grad";

/// `grad · act'(y)` from the activation's output `y`.
struct ActGrad {
    slope: f32,
}

impl CustomOp2 for ActGrad {
    fn name(&self) -> &'static str {
        "act-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let g = f32_slice(s1, l1, "act-grad")?;
        let y = f32_slice(s2, l2, "act-grad")?;
        if g.len() != y.len() {
            candle_core::bail!("act-grad: {:?} vs {:?}", l1.dims(), l2.dims());
        }
        let s = self.slope;
        let out = g.iter().zip(y).map(|(&g, &y)| leaky_grad(g, y, s)).collect();
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }
}

/// im2col of a channels-last 1-D convolution.
/// The bias gradient: the sum of a contiguous `(…, n)` tensor over every axis but the last,
/// in one pass over rows (candle's `sum(0)` goes through its generic strided reduction, a
/// visible share of an update's profile).
pub(crate) struct ColumnSum;

impl CustomOp1 for ColumnSum {
    fn name(&self) -> &'static str {
        "column-sum"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let g = f32_slice(s, l, "column-sum")?;
        let n = *l.dims().last().unwrap_or(&1);
        let mut out = vec![0f32; n];
        for row in g.chunks_exact(n.max(1)) {
            for (o, &v) in out.iter_mut().zip(row) {
                *o += v;
            }
        }
        Ok((CpuStorage::F32(out), Shape::from(n)))
    }
}

#[derive(Clone, Copy)]
struct Unfold {
    kernel: usize,
    stride: usize,
    len: usize,
    channels: usize,
    out_len: usize,
}

impl CustomOp1 for Unfold {
    fn name(&self) -> &'static str {
        "unfold"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let x = f32_slice(s, l, "unfold")?;
        let (c, row) = (self.channels, self.kernel * self.channels);
        let b = x.len() / (self.len * c);
        let mut out = Vec::with_capacity(b * self.out_len * row);
        for sample in x.chunks_exact(self.len * c) {
            for j in 0..self.out_len {
                let start = j * self.stride * c;
                out.extend_from_slice(&sample[start..start + row]);
            }
        }
        Ok((CpuStorage::F32(out), Shape::from((b, self.out_len, row))))
    }

    fn bwd(&self, _x: &Tensor, _res: &Tensor, grad: &Tensor) -> Result<Option<Tensor>> {
        Ok(Some(grad.contiguous()?.apply_op1_no_bwd(&Fold(*self))?))
    }
}

/// col2im: the gradient of [`Unfold`], summing each input position's contributions.
struct Fold(Unfold);

impl CustomOp1 for Fold {
    fn name(&self) -> &'static str {
        "fold"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let u = &self.0;
        let g = f32_slice(s, l, "fold")?;
        let (c, row) = (u.channels, u.kernel * u.channels);
        let b = g.len() / (u.out_len * row);
        let mut out = vec![0f32; b * u.len * c];
        for (sample, grad) in out.chunks_exact_mut(u.len * c).zip(g.chunks_exact(u.out_len * row)) {
            for (j, grow) in grad.chunks_exact(row).enumerate() {
                let start = j * u.stride * c;
                for (o, &v) in sample[start..start + row].iter_mut().zip(grow) {
                    *o += v;
                }
            }
        }
        Ok((CpuStorage::F32(out), Shape::from((b, u.len, c))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};

    fn close(a: &Tensor, b: &Tensor) -> f32 {
        (a - b).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar().unwrap()
    }

    /// Forward and both gradients of the fused op equal those of the composite ops.
    #[test]
    fn bias_act_matches_the_composite_ops() {
        for slope in [0.0f32, 0.01] {
            let x = Var::from_tensor(&Tensor::randn(0f32, 1.0, (7, 5, 6), &Device::Cpu).unwrap())
                .unwrap();
            let b = Var::from_tensor(&Tensor::randn(0f32, 1.0, 6, &Device::Cpu).unwrap()).unwrap();
            let w = Tensor::randn(0f32, 1.0, (7, 5, 6), &Device::Cpu).unwrap();
            let fused = bias_act(&x, &b, slope).unwrap();
            let y = x.broadcast_add(&b).unwrap();
            let composite = if slope == 0.0 {
                y.relu().unwrap()
            } else {
                y.maximum(&(&y * 0.01).unwrap()).unwrap()
            };
            assert!(close(&fused, &composite) < 1e-6);
            let gf = (fused * &w).unwrap().sum_all().unwrap().backward().unwrap();
            let gc = (composite * &w).unwrap().sum_all().unwrap().backward().unwrap();
            assert!(close(gf.get(&x).unwrap(), gc.get(&x).unwrap()) < 1e-6, "dx, slope {slope}");
            assert!(close(gf.get(&b).unwrap(), gc.get(&b).unwrap()) < 1e-4, "dbias, slope {slope}");
        }
    }

    /// Forward and both gradients equal candle's composite ops, ranges below, at and above the
    /// floor included (an offset of −0.3 puts some there).
    #[test]
    fn reciprocal_scan_matches_the_composite_ops() {
        let dev = Device::Cpu;
        let mut d: Vec<f32> = (0..6 * 40).map(|i| (i % 37) as f32 * 0.11).collect();
        d[5] = 0.31; // 0.31 − 0.3 = 0.01 (rounded): at the floor, or next to it
        let scan = Var::from_tensor(&Tensor::from_vec(d, (6, 40), &dev).unwrap()).unwrap();
        for a in [0.0f32, 0.17, -0.3] {
            let offset = Var::from_tensor(&Tensor::new(&[a], &dev).unwrap()).unwrap();
            let w = Tensor::randn(0f32, 1.0, (6, 40), &dev).unwrap();
            let fused = reciprocal_scan(&scan, &offset, 0.01).unwrap();
            let composite = scan
                .broadcast_add(&offset)
                .unwrap()
                .clamp(0.01f64, f64::MAX)
                .unwrap()
                .recip()
                .unwrap();
            assert_eq!(close(&fused, &composite), 0.0, "values, offset {a}");
            let gf = (fused * &w).unwrap().sum_all().unwrap().backward().unwrap();
            let gc = (composite * &w).unwrap().sum_all().unwrap().backward().unwrap();
            assert_eq!(close(gf.get(&scan).unwrap(), gc.get(&scan).unwrap()), 0.0, "dscan, {a}");
            let (f, c): (f32, f32) = (
                gf.get(&offset).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap()[0],
                gc.get(&offset).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap()[0],
            );
            // A sum of terms of both signs in another order: within rounding of their size.
            let size: f32 =
                gc.get(&scan).unwrap().abs().unwrap().sum_all().unwrap().to_scalar().unwrap();
            assert!((f - c).abs() <= 1e-6 * size, "doffset, {a}: {f} vs {c} (terms {size})");
        }
    }

    /// Ranges that are data (not tracked) get no gradient, and the offset still does.
    #[test]
    fn reciprocal_scan_of_untracked_ranges_gives_the_offset_its_gradient() {
        let dev = Device::Cpu;
        let scan = Tensor::from_vec(vec![0.5f32, 1.0, 2.0, 0.001], (2, 2), &dev).unwrap();
        let offset = Var::from_tensor(&Tensor::new(&[0.0f32], &dev).unwrap()).unwrap();
        let g =
            reciprocal_scan(&scan, &offset, 0.01).unwrap().sum_all().unwrap().backward().unwrap();
        assert!(g.get(&scan).is_none());
        let got = g.get(&offset).unwrap().to_vec1::<f32>().unwrap()[0];
        // −Σ 1/x² over the ranges above the floor; 0.001 is below it.
        assert!((got - -(4.0 + 1.0 + 0.25)).abs() < 1e-5, "{got}");
    }

    #[test]
    fn unfold_and_its_gradient_match_index_select() {
        let (k, s) = (4, 3);
        let x =
            Var::from_tensor(&Tensor::randn(0f32, 1.0, (3, 17, 2), &Device::Cpu).unwrap()).unwrap();
        let out_len = (17 - k) / s + 1;
        let idx: Vec<u32> =
            (0..out_len).flat_map(|j| (0..k).map(move |i| (j * s + i) as u32)).collect();
        let idx = Tensor::from_vec(idx, out_len * k, &Device::Cpu).unwrap();
        let reference = x.index_select(&idx, 1).unwrap().reshape((3, out_len, k * 2)).unwrap();
        let fused = unfold(&x, k, s).unwrap();
        assert_eq!(fused.dims(), reference.dims());
        assert_eq!(close(&fused, &reference), 0.0);
        let w = Tensor::randn(0f32, 1.0, fused.dims(), &Device::Cpu).unwrap();
        let gf = (fused * &w).unwrap().sum_all().unwrap().backward().unwrap();
        let gr = (reference * &w).unwrap().sum_all().unwrap().backward().unwrap();
        assert!(close(gf.get(&x).unwrap(), gr.get(&x).unwrap()) < 1e-5);
    }

    #[test]
    fn unfold_refuses_an_input_shorter_than_the_kernel() {
        let x = Tensor::zeros((1, 3, 1), DType::F32, &Device::Cpu).unwrap();
        assert!(unfold(&x, 4, 1).is_err());
    }
}
