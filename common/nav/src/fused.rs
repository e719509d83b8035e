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
//! On devices other than the CPU (the `cuda` feature) the same functions fall back to
//! composite candle ops with identical results, so a model is defined once.

use candle_core::{CpuStorage, CustomOp1, CustomOp2, DType, Device, Layout, Result, Shape, Tensor};

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
            out.extend(row.iter().zip(bias).map(|(&v, &b)| {
                let y = v + b;
                if y > 0.0 { y } else { s * y }
            }));
        }
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }

    fn bwd(
        &self,
        _x: &Tensor,
        _bias: &Tensor,
        res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        // y > 0 exactly where x + bias > 0 (slope ≥ 0), so the result serves as the mask.
        let dx = grad.contiguous()?.apply_op2_no_bwd(res, &ActGrad { slope: self.slope })?;
        let dbias = dx.apply_op1_no_bwd(&ColumnSum)?;
        Ok((Some(dx), Some(dbias)))
    }
}

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
        let out = g.iter().zip(y).map(|(&g, &y)| if y > 0.0 { g } else { s * g }).collect();
        Ok((CpuStorage::F32(out), l1.shape().clone()))
    }
}

/// im2col of a channels-last 1-D convolution.
/// The bias gradient: the sum of a contiguous `(…, n)` tensor over every axis but the last,
/// in one pass over rows (candle's `sum(0)` goes through its generic strided reduction, a
/// visible share of an update's profile).
struct ColumnSum;

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
