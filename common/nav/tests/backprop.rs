//! candle's backward pass, as patched in `vendor/candle-core` (PATCH.md: the first gradient
//! reaching a node is stored rather than added into zeros), against central differences.
//!
//! The expressions are built so that every way a gradient can arrive is exercised: a node used
//! twice by one op (`a + a`), a variable first reached as the right-hand side of a subtraction
//! and then again (the negated path, empty and occupied), a variable reached through several
//! ops, broadcasting, reductions, and the rules that subtract (`neg`, `cos`, `tanh`, `recip`,
//! `div`).

use candle_core::{D, DType, Device, Result, Tensor, Var};

fn var(values: &[f64], shape: &[usize]) -> Var {
    Var::from_tensor(&Tensor::from_slice(values, shape, &Device::Cpu).unwrap()).unwrap()
}

/// Values spread out enough that no `max` or `minimum` ties within the finite-difference step.
fn spread(n: usize, seed: f64) -> Vec<f64> {
    (0..n).map(|i| ((i as f64 + 1.0) * seed).sin() * 0.9 + 0.05 * i as f64).collect()
}

/// A scalar loss of `x` (3x4), `w` (4x2), `b` (2) and `v` (3x2).
fn loss(x: &Tensor, w: &Tensor, b: &Tensor, v: &Tensor) -> Result<Tensor> {
    let a = x.matmul(w)?.broadcast_add(b)?; // matmul, broadcast
    let twice = (&a + &a)?.tanh()?; // one op using a node twice; tanh subtracts
    let k = a.affine(0.5, 1.0)?;
    let first_sub = (&k - v)?; // v first reached as a subtrahend...
    let second_sub = (&a - v)?.sqr()?; // ...and again
    let ratio = (&twice / (v.sqr()? + 2.0)?)?; // div: the divisor's gradient subtracts
    let inverse = (v.sqr()? + 1.0)?.recip()?; // recip subtracts
    let waves = x.cos()?.neg()?.exp()?; // cos and neg subtract
    let peak = a.max_keepdim(D::Minus1)?.broadcast_as(a.shape())?; // max, broadcast back
    let low = twice.minimum(&second_sub)?;
    let parts = [
        first_sub.sum_all()?,
        second_sub.sum_all()?,
        ratio.sum_all()?,
        inverse.sum_all()?,
        (waves.sum_keepdim(1)? * 0.3)?.sum_all()?,
        (peak * &a)?.sum_all()?,
        low.sum_all()?,
        (x.sqr()?.mean_all()? * w.sum_all()?)?,
    ];
    let mut total = parts[0].clone();
    for p in &parts[1..] {
        total = (total + p)?;
    }
    Ok(total)
}

#[test]
fn gradients_through_fan_in_subtraction_and_broadcasts_match_central_differences() {
    let x = var(&spread(12, 0.7), &[3, 4]);
    let w = var(&spread(8, 1.3), &[4, 2]);
    let b = var(&spread(2, 2.1), &[2]);
    let v = var(&spread(6, 0.37), &[3, 2]);
    let vars = [&x, &w, &b, &v];
    let total = loss(&x, &w, &b, &v).unwrap();
    let grads = total.backward().unwrap();

    let h = 1e-6;
    for (which, target) in vars.iter().enumerate() {
        let analytic: Vec<f64> = grads
            .get(target)
            .expect("a gradient for every variable")
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        let base: Vec<f64> = target.as_tensor().flatten_all().unwrap().to_vec1().unwrap();
        for i in 0..base.len() {
            let at = |delta: f64| {
                let mut moved = base.clone();
                moved[i] += delta;
                let moved = Tensor::from_slice(&moved, target.shape(), &Device::Cpu).unwrap();
                let mut args: Vec<Tensor> = vars.iter().map(|v| v.as_tensor().clone()).collect();
                args[which] = moved;
                loss(&args[0], &args[1], &args[2], &args[3])
                    .unwrap()
                    .to_dtype(DType::F64)
                    .unwrap()
                    .to_scalar::<f64>()
                    .unwrap()
            };
            let numeric = (at(h) - at(-h)) / (2.0 * h);
            let tolerance = 1e-6 * (1.0 + numeric.abs());
            assert!(
                (analytic[i] - numeric).abs() < tolerance,
                "variable {which}, element {i}: backward {} against central difference {numeric}",
                analytic[i]
            );
        }
    }
}

#[test]
fn a_variable_reached_only_as_a_subtrahend_gets_the_negated_gradient() {
    // The empty-slot path of the subtracting rules: v's first and only gradient comes from
    // `k - v`, so it must be stored negated.
    let v = var(&[1.0, -2.0, 3.5], &[3]);
    let k = Tensor::from_slice(&[0.5f64, 0.25, 2.0], 3, &Device::Cpu).unwrap();
    let loss = ((&k - v.as_tensor()).unwrap() * 2.0).unwrap().sum_all().unwrap();
    let g: Vec<f64> = loss.backward().unwrap().get(&v).unwrap().to_vec1().unwrap();
    assert_eq!(g, vec![-2.0, -2.0, -2.0]);
    // And through `neg` alone.
    let loss = v.as_tensor().neg().unwrap().sum_all().unwrap();
    let g: Vec<f64> = loss.backward().unwrap().get(&v).unwrap().to_vec1().unwrap();
    assert_eq!(g, vec![-1.0, -1.0, -1.0]);
}

#[test]
fn a_node_used_twice_by_one_op_gets_both_gradients() {
    let v = var(&[1.5, -0.5], &[2]);
    let t = v.as_tensor();
    // d/dv (v + v) = 2, d/dv (v * v) = 2v: the second arrival adds to the stored first.
    let g: Vec<f64> =
        (t + t).unwrap().sum_all().unwrap().backward().unwrap().get(&v).unwrap().to_vec1().unwrap();
    assert_eq!(g, vec![2.0, 2.0]);
    let g: Vec<f64> =
        (t * t).unwrap().sum_all().unwrap().backward().unwrap().get(&v).unwrap().to_vec1().unwrap();
    assert_eq!(g, vec![3.0, -1.0]);
}
