//! Adam (Kingma & Ba 2015) over a set of candle variables, with its moments exposed so a
//! checkpoint can hold everything the next update depends on (candle-nn's optimizers keep
//! theirs private).

use candle_core::backprop::GradStore;
use candle_core::{Result, Tensor, Var};

/// Adam with bias correction and no weight decay (the policy's L2 term is part of its loss).
#[derive(Debug)]
pub struct Adam {
    vars: Vec<(String, Var)>,
    first: Vec<Tensor>,
    second: Vec<Tensor>,
    step: u64,
    lr: f64,
    beta1: f64,
    beta2: f64,
    eps: f64,
}

impl Adam {
    /// An optimizer for `vars` (named, for checkpoints) with learning rate `lr`.
    pub fn new(vars: Vec<(String, Var)>, lr: f64) -> Result<Self> {
        let first = vars.iter().map(|(_, v)| v.zeros_like()).collect::<Result<Vec<_>>>()?;
        let second = first.clone();
        Ok(Self { vars, first, second, step: 0, lr, beta1: 0.9, beta2: 0.999, eps: 1e-8 })
    }

    /// One Adam step from the gradients of a backward pass; variables without a gradient are
    /// left alone.
    pub fn step(&mut self, grads: &GradStore) -> Result<()> {
        self.step += 1;
        let t = self.step as i32;
        let bias1 = 1.0 - self.beta1.powi(t);
        let bias2 = 1.0 - self.beta2.powi(t);
        for (i, (_, var)) in self.vars.iter().enumerate() {
            let Some(g) = grads.get(var.as_tensor()) else { continue };
            // candle detaches inner gradients but not those of the leaves: a variable's gradient
            // can still reference the forward graph. Detached here, the moments never chain one
            // update's graph to the next (without this the learner grew by ~7 MB per update
            // until the OOM killer stopped it; see tests/issue_2_adam_memory.rs).
            let g = g.detach();
            let m = ((&self.first[i] * self.beta1)? + (&g * (1.0 - self.beta1))?)?.detach();
            let v = ((&self.second[i] * self.beta2)? + (g.sqr()? * (1.0 - self.beta2))?)?.detach();
            let denom = ((&v / bias2)?.sqrt()? + self.eps)?;
            let update = ((&m / bias1)? / denom)?;
            var.set(&(var.as_tensor() - (update * self.lr)?)?)?;
            self.first[i] = m;
            self.second[i] = v;
        }
        Ok(())
    }

    /// The variables it steps.
    pub fn vars(&self) -> impl Iterator<Item = &Var> + Clone {
        self.vars.iter().map(|(_, v)| v)
    }

    /// Steps taken so far.
    pub fn steps(&self) -> u64 {
        self.step
    }

    /// The optimizer state as named tensors: `{name}.m`, `{name}.v` per variable.
    pub fn state_tensors(&self, prefix: &str) -> Vec<(String, Tensor)> {
        let mut out = Vec::with_capacity(2 * self.vars.len());
        for (i, (name, _)) in self.vars.iter().enumerate() {
            out.push((format!("{prefix}.{name}.m"), self.first[i].clone()));
            out.push((format!("{prefix}.{name}.v"), self.second[i].clone()));
        }
        out
    }

    /// Restores moments saved by [`Adam::state_tensors`] and the step count.
    pub fn load_state(
        &mut self,
        prefix: &str,
        tensors: &std::collections::HashMap<String, Tensor>,
        step: u64,
    ) -> anyhow::Result<()> {
        for (i, (name, var)) in self.vars.iter().enumerate() {
            for (slot, kind) in [(&mut self.first[i], "m"), (&mut self.second[i], "v")] {
                let key = format!("{prefix}.{name}.{kind}");
                let t = tensors
                    .get(&key)
                    .ok_or_else(|| anyhow::anyhow!("checkpoint lacks optimizer tensor `{key}`"))?;
                if t.dims() != var.dims() {
                    anyhow::bail!("optimizer tensor `{key}` has the wrong shape");
                }
                *slot = t.clone();
            }
        }
        self.step = step;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Tensor};

    #[test]
    fn moments_hold_no_graph() {
        // A gradient taken through an activation reaches the variable with an op attached; the
        // stored moments must not keep it (or the whole graph of every earlier update) alive.
        let w = Var::new(&[[0.5f32, -0.3], [0.2, 0.8]], &Device::Cpu).unwrap();
        let x = Tensor::new(&[[1.0f32, 2.0]], &Device::Cpu).unwrap();
        let mut opt = Adam::new(vec![("w".into(), w.clone())], 0.01).unwrap();
        for _ in 0..3 {
            let y = x.matmul(w.as_tensor()).unwrap().relu().unwrap();
            let loss = (&y * &y).unwrap().sum_all().unwrap();
            opt.step(&loss.backward().unwrap()).unwrap();
        }
        assert!(opt.first.iter().chain(&opt.second).all(|t| !t.track_op()));
    }

    #[test]
    fn minimizes_a_quadratic() {
        let x = Var::new(&[3.0f32, -2.0], &Device::Cpu).unwrap();
        let mut opt = Adam::new(vec![("x".into(), x.clone())], 0.1).unwrap();
        for _ in 0..300 {
            let loss = x.as_tensor().sqr().unwrap().sum_all().unwrap();
            opt.step(&loss.backward().unwrap()).unwrap();
        }
        let v: Vec<f32> = x.as_tensor().to_vec1().unwrap();
        assert!(v.iter().all(|x| x.abs() < 0.05), "{v:?}");
    }

    #[test]
    fn first_step_moves_each_weight_by_the_learning_rate() {
        // With bias correction, Adam's first step is lr·sign(g) (up to eps).
        let x = Var::new(&[1.0f32, -1.0], &Device::Cpu).unwrap();
        let mut opt = Adam::new(vec![("x".into(), x.clone())], 0.01).unwrap();
        let loss = (x.as_tensor() * 5.0).unwrap().sum_all().unwrap();
        opt.step(&loss.backward().unwrap()).unwrap();
        let v: Vec<f32> = x.as_tensor().to_vec1().unwrap();
        assert!((v[0] - 0.99).abs() < 1e-6 && (v[1] + 1.01).abs() < 1e-6, "{v:?}");
    }
}
