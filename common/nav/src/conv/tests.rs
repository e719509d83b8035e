use super::*;
use crate::bf16::matmul;
use candle_core::{Device, Var};

fn max_diff(a: &Tensor, b: &Tensor) -> f32 {
    (a - b).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar().unwrap()
}

fn max_abs(a: &Tensor) -> f32 {
    a.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar().unwrap()
}

/// The same convolution through the im2col unfold and one product: the reference.
fn unfolded(x: &Tensor, w: &Tensor, kernel: usize, stride: usize, p: Precision) -> Tensor {
    let cols = crate::fused::unfold(x, kernel, stride).unwrap();
    let (b, out_len, width) = cols.dims3().unwrap();
    matmul(&cols.reshape((b * out_len, width)).unwrap(), w, p).unwrap()
}

/// Forward products and both gradients equal the unfold path's, for the networks' two
/// convolutions and for kernels shorter than, equal to and not a multiple of the stride.
#[test]
fn reading_in_place_is_the_unfolded_convolution() {
    // (len, channels, kernel, stride, out, batch)
    let shapes = [
        (540, 1, 20, 5, 32, 3),
        (105, 32, 10, 3, 32, 2),
        (12, 2, 5, 3, 3, 4),
        (12, 2, 6, 3, 3, 1),
        (8, 1, 2, 4, 2, 3),
        (9, 3, 9, 3, 2, 2),
    ];
    let dev = Device::Cpu;
    for (i, &(len, c, k, s, o, b)) in shapes.iter().enumerate() {
        let g = InPlace::new(len, c, k, s, o).unwrap();
        let x = Var::from_tensor(&Tensor::randn(0f32, 1.0, (b, len, c), &dev).unwrap()).unwrap();
        let w = Var::from_tensor(&Tensor::randn(0f32, 1.0, (k * c, o), &dev).unwrap()).unwrap();
        // Weights on the output so every gradient row differs.
        let out_len = (len - k) / s + 1;
        let mix = Tensor::randn(0f32, 1.0, (b * out_len, o), &dev).unwrap();
        for p in [Precision::Fp32, Precision::Bf16] {
            let ours = products(&x, &w, g, p).unwrap();
            let theirs = unfolded(&x, &w, k, s, p);
            assert_eq!(ours.dims(), theirs.dims(), "shape {i}, {p:?}");
            let scale = max_abs(&theirs).max(1.0);
            // The same products summed in another order (bf16 products are exact in fp32).
            assert!(max_diff(&ours, &theirs) / scale < 1e-5, "forward, shape {i}, {p:?}");
            let go = (ours * &mix).unwrap().sum_all().unwrap().backward().unwrap();
            let gt = (theirs * &mix).unwrap().sum_all().unwrap().backward().unwrap();
            for (name, v) in [("dx", &x), ("dw", &w)] {
                let (a, r) = (go.get(v).unwrap(), gt.get(v).unwrap());
                let scale = max_abs(r).max(1.0);
                assert!(max_diff(a, r) / scale < 1e-5, "{name}, shape {i}, {p:?}");
            }
        }
    }
}

/// The fused layer equals the products followed by the fused bias and activation: the same
/// values and all three gradients, bit for bit, ReLU and leaky, fp32 and bf16.
#[test]
fn the_fused_bias_and_activation_equal_the_separate_ops() {
    let shapes = [(540, 1, 20, 5, 32, 3), (105, 32, 10, 3, 32, 2), (12, 2, 5, 3, 3, 1)];
    let dev = Device::Cpu;
    for (i, &(len, c, k, s, o, b)) in shapes.iter().enumerate() {
        let g = InPlace::new(len, c, k, s, o).unwrap();
        let x = Var::from_tensor(&Tensor::randn(0f32, 1.0, (b, len, c), &dev).unwrap()).unwrap();
        let w = Var::from_tensor(&Tensor::randn(0f32, 1.0, (k * c, o), &dev).unwrap()).unwrap();
        let bias = Var::from_tensor(&Tensor::randn(0f32, 1.0, o, &dev).unwrap()).unwrap();
        let out_len = (len - k) / s + 1;
        let mix = Tensor::randn(0f32, 1.0, (b * out_len, o), &dev).unwrap();
        for p in [Precision::Fp32, Precision::Bf16] {
            for slope in [0.0, 0.01] {
                let fused = products_bias_act(&x, &w, &bias, g, p, slope).unwrap();
                let separate =
                    crate::fused::bias_act(&products(&x, &w, g, p).unwrap(), &bias, slope).unwrap();
                let what = format!("shape {i}, {p:?}, slope {slope}");
                assert_eq!(fused.dims(), separate.dims(), "{what}");
                assert_eq!(max_diff(&fused, &separate), 0.0, "forward, {what}");
                let gf = (fused * &mix).unwrap().sum_all().unwrap().backward().unwrap();
                let gs = (separate * &mix).unwrap().sum_all().unwrap().backward().unwrap();
                for (name, v) in [("dx", &x), ("dw", &w), ("dbias", &bias)] {
                    let d = max_diff(gf.get(v).unwrap(), gs.get(v).unwrap());
                    assert_eq!(d, 0.0, "{name}, {what}");
                }
            }
        }
    }
}

/// An input that is data (not tracked) gets no gradient; the weights still do.
#[test]
fn the_fused_layer_gives_untracked_input_no_gradient() {
    let dev = Device::Cpu;
    let g = InPlace::new(12, 2, 5, 3, 3).unwrap();
    let x = Tensor::randn(0f32, 1.0, (2, 12, 2), &dev).unwrap();
    let w = Var::from_tensor(&Tensor::randn(0f32, 1.0, (10, 3), &dev).unwrap()).unwrap();
    let bias = Var::from_tensor(&Tensor::zeros(3, DType::F32, &dev).unwrap()).unwrap();
    let y = products_bias_act(&x, &w, &bias, g, Precision::Fp32, 0.01).unwrap();
    let grads = y.sum_all().unwrap().backward().unwrap();
    assert!(grads.get(&x).is_none());
    assert!(grads.get(&w).is_some() && grads.get(&bias).is_some());
}

#[test]
fn lengths_that_are_not_a_multiple_of_the_stride_are_not_read_in_place() {
    assert!(InPlace::new(23, 3, 5, 2, 4).is_none());
    assert!(InPlace::new(4, 1, 5, 1, 4).is_none(), "shorter than the kernel");
    assert!(InPlace::new(105, 32, 10, 3, 32).is_some());
    assert!(InPlace::new(540, 1, 20, 5, 32).is_some());
}

#[test]
fn a_tensor_of_another_shape_is_refused_with_its_shape() {
    let dev = Device::Cpu;
    let g = InPlace::new(12, 2, 5, 3, 3).unwrap();
    let x = Tensor::zeros((2, 11, 2), DType::F32, &dev).unwrap();
    let w = Tensor::zeros((10, 3), DType::F32, &dev).unwrap();
    let e = products(&x, &w, g, Precision::Fp32).unwrap_err().to_string();
    assert!(e.contains("[2, 11, 2]"), "{e}");
    let x = Tensor::zeros((2, 12, 2), DType::F32, &dev).unwrap();
    let w = Tensor::zeros((9, 3), DType::F32, &dev).unwrap();
    let e = products(&x, &w, g, Precision::Fp32).unwrap_err().to_string();
    assert!(e.contains("[9, 3]"), "{e}");
}
