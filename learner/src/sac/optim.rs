//! Adam (Kingma & Ba 2015) over a set of candle variables, with its moments exposed so a
//! checkpoint can hold everything the next update depends on (candle-nn's optimizers keep
//! theirs private).
//!
//! On the CPU each variable's step is three in-place passes (each moment, then the weight)
//! rather than a dozen tensor operations that each allocate and write a new tensor; the
//! arithmetic is the same, bit for bit (tested).

use super::shards::Workers;
use candle_core::backprop::GradStore;
use candle_core::{CpuStorage, DType, InplaceOp2, InplaceOp3, Layout, Result, Tensor, Var};

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
    /// Step with the fused in-place passes where [`fusable`] (off only to test them against
    /// the tensor expressions).
    fuse: bool,
}

impl Adam {
    /// An optimizer for `vars` (named, for checkpoints) with learning rate `lr`.
    pub fn new(vars: Vec<(String, Var)>, lr: f64) -> Result<Self> {
        // Two allocations each: the moments are updated in place, so no two may share storage.
        let first = vars.iter().map(|(_, v)| v.zeros_like()).collect::<Result<Vec<_>>>()?;
        let second = vars.iter().map(|(_, v)| v.zeros_like()).collect::<Result<Vec<_>>>()?;
        Ok(Self {
            vars,
            first,
            second,
            step: 0,
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            fuse: true,
        })
    }

    /// One Adam step from the gradients of a backward pass; variables without a gradient are
    /// left alone.
    pub fn step(&mut self, grads: &GradStore) -> Result<()> {
        let corrections = self.count_step_corrections();
        self.apply(grads, corrections)
    }

    /// Counts a step and gives its bias corrections 1 − β₁ᵗ, 1 − β₂ᵗ.
    fn count_step_corrections(&mut self) -> Corrections<'static> {
        self.step += 1;
        let t = self.step as i32;
        Corrections::Numbers { bias1: 1.0 - self.beta1.powi(t), bias2: 1.0 - self.beta2.powi(t) }
    }

    /// One Adam step whose bias corrections 1/(1 − β₁ᵗ), 1/(1 − β₂ᵗ) are read from `inv_bias`,
    /// a 2-element f32 tensor on the variables' device, rather than computed from the step
    /// count: a captured update (CUDA graph) replays the same kernels with the same arguments
    /// every time, so what changes per step must live in device memory. The caller writes
    /// [`Adam::next_corrections`] there before each replay and calls [`Adam::count_step`] after.
    /// Does not count the step itself (a capture runs this without stepping anything).
    pub fn step_corrected(&mut self, grads: &GradStore, inv_bias: &Tensor) -> Result<()> {
        let (inv1, inv2) = (inv_bias.get(0)?, inv_bias.get(1)?);
        self.apply(grads, Corrections::Tensors { inv1: &inv1, inv2: &inv2 })
    }

    /// 1/(1 − β₁ᵗ) and 1/(1 − β₂ᵗ) of the next step, as f32 (what [`Adam::step`] uses).
    pub fn next_corrections(&self) -> [f32; 2] {
        let t = (self.step + 1) as i32;
        [(1.0 / (1.0 - self.beta1.powi(t))) as f32, (1.0 / (1.0 - self.beta2.powi(t))) as f32]
    }

    /// Counts a step done by a replay of [`Adam::step_corrected`].
    pub fn count_step(&mut self) {
        self.step += 1;
    }

    fn apply(&mut self, grads: &GradStore, corrections: Corrections) -> Result<()> {
        for (i, (_, var)) in self.vars.iter().enumerate() {
            let Some(g) = grads.get(var.as_tensor()) else { continue };
            self.step_var(i, g, corrections)?;
        }
        Ok(())
    }

    /// One Adam step from the gradients of several backward passes (the shards of one
    /// minibatch, [`super::shards`]) added up, each variable's sum and step as one job on
    /// `workers`: the variables are independent, so the step needs no second core's worth
    /// of waiting on the main thread. Each sum is [`super::shards::grad_sum`], as
    /// [`super::shards::sum_grads`] adds them, so the result is the same bit for bit.
    pub fn step_shards(&mut self, stores: &[GradStore], workers: &Workers) -> Result<()> {
        let corrections = self.count_step_corrections();
        workers.for_each(self.vars.len(), |i| {
            match super::shards::grad_sum(stores, self.vars[i].1.as_tensor())? {
                Some(g) => self.step_var(i, &g, corrections),
                None => Ok(()),
            }
        })
    }

    /// Steps variable `i` by its gradient `g`.
    fn step_var(&self, i: usize, g: &Tensor, corrections: Corrections) -> Result<()> {
        let var = &self.vars[i].1;
        // candle detaches inner gradients but not those of the leaves: a variable's gradient
        // can still reference the forward graph. Detached here, the moments never chain one
        // update's graph to the next (without this the learner grew by ~7 MB per update
        // until the OOM killer stopped it; see tests/issue_2_adam_memory.rs).
        let g = g.detach();
        if let Corrections::Numbers { bias1, bias2 } = corrections
            && self.fuse
            && fusable(&[var.as_tensor(), &g, &self.first[i], &self.second[i]])
        {
            let ema =
                |beta: f64, square| Ema { beta: beta as f32, rest: (1.0 - beta) as f32, square };
            self.first[i].inplace_op2(&g, &ema(self.beta1, false))?;
            self.second[i].inplace_op2(&g, &ema(self.beta2, true))?;
            let apply = Apply {
                inv_bias1: (1.0 / bias1) as f32,
                inv_bias2: (1.0 / bias2) as f32,
                eps: self.eps as f32,
                lr: self.lr as f32,
            };
            var.as_tensor().inplace_op3(&self.first[i], &self.second[i], &apply)?;
            return Ok(());
        }
        let m = ((&self.first[i] * self.beta1)? + (&g * (1.0 - self.beta1))?)?.detach();
        let v = ((&self.second[i] * self.beta2)? + (g.sqr()? * (1.0 - self.beta2))?)?.detach();
        let (m_hat, v_hat) = match corrections {
            Corrections::Numbers { bias1, bias2 } => ((&m / bias1)?, (&v / bias2)?),
            Corrections::Tensors { inv1, inv2 } => (m.broadcast_mul(inv1)?, v.broadcast_mul(inv2)?),
        };
        let update = (m_hat / (v_hat.sqrt()? + self.eps)?)?;
        var.set(&(var.as_tensor() - (update * self.lr)?)?)?;
        // Written into the moments' own storage: a captured update must leave every
        // tensor it outlives where it found it.
        self.first[i].slice_set(&m, 0, 0)?;
        self.second[i].slice_set(&v, 0, 0)?;
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

    /// The optimizer state as named tensors: `{name}.m`, `{name}.v` per variable. Copies: the
    /// moments are updated in place, and a snapshot must not move with them.
    pub fn state_tensors(&self, prefix: &str) -> Result<Vec<(String, Tensor)>> {
        let mut out = Vec::with_capacity(2 * self.vars.len());
        for (i, (name, _)) in self.vars.iter().enumerate() {
            out.push((format!("{prefix}.{name}.m"), self.first[i].copy()?));
            out.push((format!("{prefix}.{name}.v"), self.second[i].copy()?));
        }
        Ok(out)
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
                // Copied into the moments' own storage: they are updated in place, `tensors`
                // may be another learner's state, and a captured update (CUDA graph) holds
                // their addresses.
                slot.slice_set(&t.to_dtype(var.dtype())?.to_device(var.device())?.copy()?, 0, 0)?;
            }
        }
        self.step = step;
        Ok(())
    }
}

/// `target ← (1 − τ)·target + τ·online` in place: one pass on the CPU (the same f32 operations
/// as [`super::average::polyak`], bit for bit), the tensor expression written back elsewhere.
pub fn polyak_in_place(target: &Var, online: &Tensor, tau: f64) -> Result<()> {
    if fusable(&[target.as_tensor(), online]) {
        // θ̄ ← (1 − τ)·θ̄ + τ·θ is a moving average: Adam's first-moment pass with β = 1 − τ.
        let op = Ema { beta: (1.0 - tau) as f32, rest: tau as f32, square: false };
        return target.as_tensor().inplace_op2(online, &op);
    }
    target.set(&super::average::polyak(target.as_tensor(), online, tau)?)
}

/// Where a step's bias corrections come from.
#[derive(Clone, Copy)]
enum Corrections<'a> {
    /// 1 − β₁ᵗ and 1 − β₂ᵗ from the step count.
    Numbers { bias1: f64, bias2: f64 },
    /// 1/(1 − β₁ᵗ) and 1/(1 − β₂ᵗ) as scalar tensors on the device.
    Tensors { inv1: &'a Tensor, inv2: &'a Tensor },
}

/// Whether one Adam step can run as the fused in-place passes: f32, contiguous, on the CPU
/// (elsewhere, such as CUDA, the tensor operations below them).
fn fusable(ts: &[&Tensor]) -> bool {
    ts.iter().all(|t| t.device().is_cpu() && t.dtype() == DType::F32 && t.is_contiguous())
}

/// The contiguous f32 slice of a storage, for the fused passes ([`fusable`] checked it).
fn f32s<'a>(s: &'a CpuStorage, l: &Layout) -> Result<&'a [f32]> {
    match (s, l.contiguous_offsets()) {
        (CpuStorage::F32(x), Some((a, b))) => Ok(&x[a..b]),
        _ => candle_core::bail!("fused Adam: not a contiguous f32 tensor"),
    }
}

fn f32s_mut<'a>(s: &'a mut CpuStorage, l: &Layout) -> Result<&'a mut [f32]> {
    match (s, l.contiguous_offsets()) {
        (CpuStorage::F32(x), Some((a, b))) => Ok(&mut x[a..b]),
        _ => candle_core::bail!("fused Adam: not a contiguous f32 tensor"),
    }
}

/// A moving average in place, one pass: `m ← β·m + (1 − β)·g` (or `g²`), for Adam's moments
/// and [`polyak_in_place`]. The same f32 operations, in the same order, as the tensor
/// expressions of [`Adam::step`]'s other path and of `average::polyak`.
struct Ema {
    beta: f32,
    /// 1 − β, computed in f64 as the tensor expression's scalar is (1 − 0.9f32 is not 0.1f32).
    rest: f32,
    square: bool,
}

impl InplaceOp2 for Ema {
    fn name(&self) -> &'static str {
        "adam-moment"
    }

    fn cpu_fwd(&self, m: &mut CpuStorage, lm: &Layout, g: &CpuStorage, lg: &Layout) -> Result<()> {
        let (m, g) = (f32s_mut(m, lm)?, f32s(g, lg)?);
        let (beta, rest) = (self.beta, self.rest);
        if self.square {
            m.iter_mut().zip(g).for_each(|(m, g)| *m = *m * beta + (g * g) * rest);
        } else {
            m.iter_mut().zip(g).for_each(|(m, g)| *m = *m * beta + g * rest);
        }
        Ok(())
    }
}

/// The weight's step in place, one pass: `w ← w − lr · (m / b₁) / (√(v / b₂) + ε)`.
struct Apply {
    inv_bias1: f32,
    inv_bias2: f32,
    eps: f32,
    lr: f32,
}

impl InplaceOp3 for Apply {
    fn name(&self) -> &'static str {
        "adam-apply"
    }

    fn cpu_fwd(
        &self,
        w: &mut CpuStorage,
        lw: &Layout,
        m: &CpuStorage,
        lm: &Layout,
        v: &CpuStorage,
        lv: &Layout,
    ) -> Result<()> {
        let (w, m, v) = (f32s_mut(w, lw)?, f32s(m, lm)?, f32s(v, lv)?);
        for ((w, m), v) in w.iter_mut().zip(m).zip(v) {
            let denom = (v * self.inv_bias2).sqrt() + self.eps;
            *w -= ((m * self.inv_bias1) / denom) * self.lr;
        }
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
    fn the_fused_step_is_the_tensor_step() {
        // The same variables and gradients through the fused in-place passes and through the
        // tensor expressions: bit for bit the same weights and moments (the same f32 operations
        // in the same order).
        let dev = Device::Cpu;
        let init = Tensor::randn(0f32, 1.0, (37, 23), &dev).unwrap();
        let xs: Vec<Tensor> =
            (0..5).map(|_| Tensor::randn(0f32, 1.0, (8, 37), &dev).unwrap()).collect();
        let run = |fuse: bool| {
            let w = Var::from_tensor(&init.copy().unwrap()).unwrap();
            let b = Var::from_tensor(&Tensor::zeros(23, DType::F32, &dev).unwrap()).unwrap();
            let mut opt =
                Adam::new(vec![("w".into(), w.clone()), ("b".into(), b.clone())], 3e-3).unwrap();
            opt.fuse = fuse;
            for (k, x) in xs.iter().enumerate() {
                let y = (x.matmul(w.as_tensor()).unwrap().broadcast_add(b.as_tensor()).unwrap()
                    * (k as f64 + 1.0))
                    .unwrap();
                let loss = y.tanh().unwrap().sqr().unwrap().mean_all().unwrap();
                opt.step(&loss.backward().unwrap()).unwrap();
            }
            opt.state_tensors("o")
                .unwrap()
                .into_iter()
                .chain([("w".into(), w.as_tensor().clone()), ("b".into(), b.as_tensor().clone())])
                .map(|(n, t)| (n, t.flatten_all().unwrap().to_vec1::<f32>().unwrap()))
                .collect::<Vec<_>>()
        };
        let (fused, tensors) = (run(true), run(false));
        for ((name, a), (_, b)) in fused.iter().zip(&tensors) {
            assert_eq!(a, b, "{name}");
        }
        assert_ne!(fused[4].1, init.flatten_all().unwrap().to_vec1::<f32>().unwrap(), "it moved");
    }

    /// The shards' gradients summed and stepped per variable on two workers give the same
    /// weights and moments, bit for bit, as the sum on one thread and the sequential step.
    #[test]
    fn a_step_from_shards_on_workers_is_the_summed_step() {
        let dev = Device::Cpu;
        let make = || {
            let vars: Vec<(String, Var)> = (0..5)
                .map(|k| {
                    let t = Tensor::arange(0f32, 40.0 + k as f32, &dev).unwrap();
                    let t = ((t * 0.37).unwrap().sin().unwrap() * (k as f64 + 1.0)).unwrap();
                    (format!("w{k}"), Var::from_tensor(&t).unwrap())
                })
                .collect();
            let opt = Adam::new(vars.clone(), 3e-3).unwrap();
            (vars, opt)
        };
        let (va, mut a) = make();
        let (vb, mut b) = make();
        let workers = Workers::new(2).unwrap();
        for step in 0..4 {
            // Three shards' losses, each reaching every variable but the last.
            let stores = |vars: &[(String, Var)]| -> Vec<GradStore> {
                (0..3)
                    .map(|s| {
                        let loss = vars[..4]
                            .iter()
                            .map(|(_, v)| {
                                let k = (s + step) as f64 * 0.3 + 1.0;
                                (v.as_tensor() * k).unwrap().sqr().unwrap().sum_all().unwrap()
                            })
                            .reduce(|x, y| (x + y).unwrap())
                            .unwrap();
                        loss.backward().unwrap()
                    })
                    .collect()
            };
            let summed =
                super::super::shards::sum_grads(stores(&va), va.iter().map(|(_, v)| v)).unwrap();
            a.step(&summed).unwrap();
            b.step_shards(&stores(&vb), &workers).unwrap();
        }
        let bits = |t: &Tensor| -> Vec<u32> {
            t.to_vec1::<f32>().unwrap().iter().map(|x| x.to_bits()).collect()
        };
        for i in 0..5 {
            assert_eq!(bits(va[i].1.as_tensor()), bits(vb[i].1.as_tensor()), "w{i}");
            assert_eq!(bits(&a.first[i]), bits(&b.first[i]), "m of w{i}");
            assert_eq!(bits(&a.second[i]), bits(&b.second[i]), "v of w{i}");
        }
        assert_eq!(a.steps(), b.steps());
        // The variable no loss reached has not moved.
        let untouched = make().0;
        assert_eq!(bits(vb[4].1.as_tensor()), bits(untouched[4].1.as_tensor()));
    }

    #[test]
    fn the_polyak_pass_is_the_tensor_expression() {
        let dev = Device::Cpu;
        let target = Tensor::randn(0f32, 1.0, (41, 17), &dev).unwrap();
        let online = Tensor::randn(0f32, 1.0, (41, 17), &dev).unwrap();
        let want = super::super::average::polyak(&target, &online, 0.005).unwrap();
        let var = Var::from_tensor(&target).unwrap();
        polyak_in_place(&var, &online, 0.005).unwrap();
        let (got, want) = (var.as_tensor().flatten_all().unwrap(), want.flatten_all().unwrap());
        assert_eq!(got.to_vec1::<f32>().unwrap(), want.to_vec1::<f32>().unwrap());
        assert_ne!(
            got.to_vec1::<f32>().unwrap(),
            target.flatten_all().unwrap().to_vec1::<f32>().unwrap()
        );
    }

    #[test]
    fn snapshots_and_restores_do_not_move_with_the_moments() {
        let x = Var::new(&[1.0f32, -1.0], &Device::Cpu).unwrap();
        let mut opt = Adam::new(vec![("x".into(), x.clone())], 0.01).unwrap();
        let step = |opt: &mut Adam| {
            let loss = (x.as_tensor() * 5.0).unwrap().sum_all().unwrap();
            opt.step(&loss.backward().unwrap()).unwrap();
        };
        step(&mut opt);
        let saved: std::collections::HashMap<String, Tensor> =
            opt.state_tensors("o").unwrap().into_iter().collect();
        let before: Vec<f32> = saved["o.x.m"].to_vec1().unwrap();
        let mut other = Adam::new(vec![("x".into(), x.clone())], 0.01).unwrap();
        other.load_state("o", &saved, 1).unwrap();
        step(&mut opt);
        step(&mut other);
        assert_eq!(saved["o.x.m"].to_vec1::<f32>().unwrap(), before, "the snapshot stayed");
        assert_ne!(opt.first[0].to_vec1::<f32>().unwrap(), before);
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
