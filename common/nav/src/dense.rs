//! `x · Wᵀ` for a fully-connected layer on the CPU, with the weight's gradient written in the
//! weight's own layout.
//!
//! Why: through candle, `x.matmul(&w.t())` differentiates the product for `wᵀ` and then the
//! transpose, so the weight's gradient arrives as a transposed view and is copied to make it
//! contiguous before Adam reads it (`copy_strided_src`, ~4 % of an update's profile on two
//! threads; docs/results.md, "Convolutions read in place"). Here the backward pass computes
//! `dW = dYᵀ · x` straight into an `(out, in)` matrix, and `dx = dY · W`, each one product.
//! Weights keep PyTorch's `(out, in)` layout, so checkpoints do not change.

use crate::bf16::{MatRef, Precision, matmul, product};
use crate::fused::f32_slice;
use candle_core::{CpuStorage, CustomOp2, DType, Layout, Result, Shape, Tensor};

/// The ops' name in errors.
const NAME: &str = "dense";

/// `x · wᵀ` for `x` `(batch, in)` and `w` `(out, in)` in `precision`, gradients to both.
/// Off the CPU, or for other dtypes, candle's matmul of the transposed view.
pub fn x_wt(x: &Tensor, w: &Tensor, precision: Precision) -> Result<Tensor> {
    if x.device().is_cpu() && x.dtype() == DType::F32 && w.dtype() == DType::F32 {
        x.contiguous()?.apply_op2(&w.contiguous()?, XWt { precision })
    } else {
        matmul(x, &w.t()?, precision)
    }
}

/// `(rows, cols)` of a 2-D layout.
fn dims2(l: &Layout, what: &str) -> Result<(usize, usize)> {
    match *l.dims() {
        [r, c] => Ok((r, c)),
        ref d => candle_core::bail!("{NAME}: {what} {d:?} is not 2-D"),
    }
}

/// `x · wᵀ`.
#[derive(Clone, Copy)]
struct XWt {
    precision: Precision,
}

impl CustomOp2 for XWt {
    fn name(&self) -> &'static str {
        "dense"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let ((b, k), (o, k2)) = (dims2(l1, "input")?, dims2(l2, "weight")?);
        if k != k2 {
            candle_core::bail!("{NAME}: input {:?}, weight {:?}", l1.dims(), l2.dims());
        }
        let (x, w) = (f32_slice(s1, l1, NAME)?, f32_slice(s2, l2, NAME)?);
        let y = product(MatRef::row_major(x, b, k), MatRef::row_major(w, o, k).t(), self.precision);
        Ok((CpuStorage::F32(y), Shape::from((b, o))))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> Result<(Option<Tensor>, Option<Tensor>)> {
        let grad = grad.contiguous()?;
        // Only the gradients a caller tracks: the policy loss reads the critics' heads with
        // detached weights (`Critic::forward_for_policy`), and their gradients are its waste.
        let dx = x.track_op().then(|| grad.apply_op2_no_bwd(w, &InputGrad(*self))).transpose()?;
        let dw = w.track_op().then(|| grad.apply_op2_no_bwd(x, &WeightGrad(*self))).transpose()?;
        Ok((dx, dw))
    }
}

/// `dx = dY · W`.
struct InputGrad(XWt);

impl CustomOp2 for InputGrad {
    fn name(&self) -> &'static str {
        "dense-input-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let ((b, o), (o2, k)) = (dims2(l1, "gradient")?, dims2(l2, "weight")?);
        if o != o2 {
            candle_core::bail!("{NAME}: gradient {:?}, weight {:?}", l1.dims(), l2.dims());
        }
        let (g, w) = (f32_slice(s1, l1, NAME)?, f32_slice(s2, l2, NAME)?);
        let dx = product(MatRef::row_major(g, b, o), MatRef::row_major(w, o, k), self.0.precision);
        Ok((CpuStorage::F32(dx), Shape::from((b, k))))
    }
}

/// `dW = dYᵀ · x`, `(out, in)` like the weight.
struct WeightGrad(XWt);

impl CustomOp2 for WeightGrad {
    fn name(&self) -> &'static str {
        "dense-weight-grad"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let ((b, o), (b2, k)) = (dims2(l1, "gradient")?, dims2(l2, "input")?);
        if b != b2 {
            candle_core::bail!("{NAME}: gradient {:?}, input {:?}", l1.dims(), l2.dims());
        }
        let (g, x) = (f32_slice(s1, l1, NAME)?, f32_slice(s2, l2, NAME)?);
        let g_t = MatRef::row_major(g, b, o).t();
        let dw = product(g_t, MatRef::row_major(x, b, k), self.0.precision);
        Ok((CpuStorage::F32(dw), Shape::from((o, k))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};

    fn max_abs(t: &Tensor) -> f32 {
        t.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar().unwrap()
    }

    fn max_rel_diff(a: &Tensor, b: &Tensor) -> f32 {
        max_abs(&(a - b).unwrap()) / max_abs(b).max(1.0)
    }

    /// The product and both gradients equal candle's `x.matmul(&w.t())` (fp32) and the bf16
    /// matmul of the transposed view (bf16), and the weight's gradient comes out contiguous.
    #[test]
    fn x_wt_is_the_product_with_the_transposed_weight() {
        let dev = Device::Cpu;
        for (b, k, o) in [(5, 7, 3), (128, 1028, 128), (1, 4, 2), (64, 256, 256)] {
            let x = Var::from_tensor(&Tensor::randn(0f32, 1.0, (b, k), &dev).unwrap()).unwrap();
            let w = Var::from_tensor(&Tensor::randn(0f32, 1.0, (o, k), &dev).unwrap()).unwrap();
            let mix = Tensor::randn(0f32, 1.0, (b, o), &dev).unwrap();
            for p in [Precision::Fp32, Precision::Bf16] {
                let ours = x_wt(&x, &w, p).unwrap();
                let theirs = matmul(&x, &w.t().unwrap(), p).unwrap();
                assert!(max_rel_diff(&ours, &theirs) < 1e-5, "forward {b}x{k}x{o} {p:?}");
                let go = (ours * &mix).unwrap().sum_all().unwrap().backward().unwrap();
                let gt = (theirs * &mix).unwrap().sum_all().unwrap().backward().unwrap();
                for (name, v) in [("dx", &x), ("dw", &w)] {
                    let (a, r) = (go.get(v).unwrap(), gt.get(v).unwrap());
                    assert!(max_rel_diff(a, r) < 1e-5, "{name} {b}x{k}x{o} {p:?}");
                }
                assert!(go.get(&w).unwrap().is_contiguous(), "dw contiguous, {p:?}");
            }
        }
    }

    #[test]
    fn mismatched_shapes_are_refused_with_both_shapes() {
        let dev = Device::Cpu;
        let x = Tensor::zeros((2, 3), DType::F32, &dev).unwrap();
        let w = Tensor::zeros((4, 5), DType::F32, &dev).unwrap();
        let e = x_wt(&x, &w, Precision::Fp32).unwrap_err().to_string();
        assert!(e.contains("[2, 3]") && e.contains("[4, 5]"), "{e}");
    }
}
