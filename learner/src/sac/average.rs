//! A Polyak average of the policy's weights (`sac.policy_average_tau`): θ̄ ← τ_π θ + (1 − τ_π) θ̄
//! after each policy update, the run's agent when it is on.
//!
//! Why: in the generalist's runs (docs/results.md, g19–g21) the policy learned and unlearned
//! the detour of the gate test within a few thousand updates, so a run's last checkpoint fell
//! on either side by chance. An average of the last ~1/τ_π policies is what Polyak and
//! Juditsky (1992) averaged SGD iterates for, and what stochastic weight averaging and the EMA
//! weights of diffusion models use: an estimate with less of the last steps' noise. The actors
//! keep acting with the online θ, so exploration is unchanged; only the agent that is saved and
//! evaluated is θ̄.
//!
//! The average holds plain tensors with the policy's variable names (nothing trains it), so it
//! serializes to the same safetensors layout as the policy and loads wherever a policy does.

use candle_core::{Result, Tensor, Var};

/// One Polyak step, `τ·online + (1 − τ)·average`: the policy average's and the target
/// critics' (`super::learning::soft_update`) update.
///
/// Detached: an op on a variable records its inputs for backprop, so an undetached average
/// would hold the previous one, and so on back to the start: a copy of the weights per update
/// kept alive (g22's first run grew to 23 GB in 16k updates and was killed for memory).
pub fn polyak(average: &Tensor, online: &Tensor, tau: f64) -> Result<Tensor> {
    Ok(((average * (1.0 - tau))? + (online * tau)?)?.detach())
}

/// θ̄ and its rate τ_π.
pub struct PolicyAverage {
    /// `(name, θ̄ tensor)`, sorted by name like [`super::networks::Owned::named_vars`].
    tensors: Vec<(String, Tensor)>,
    tau: f64,
}

impl PolicyAverage {
    /// An average starting at the policy's current weights (a copy, not a view).
    pub fn start(policy: &[(String, Var)], tau: f64) -> Result<Self> {
        let tensors = policy
            .iter()
            .map(|(n, v)| Ok((n.clone(), v.as_tensor().copy()?.detach())))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self { tensors, tau })
    }

    /// θ̄ ← τ_π θ + (1 − τ_π) θ̄, with `policy` the online variables in the same (name) order.
    pub fn update(&mut self, policy: &[(String, Var)]) -> Result<()> {
        debug_assert_eq!(self.tensors.len(), policy.len());
        for ((name, avg), (pname, v)) in self.tensors.iter_mut().zip(policy) {
            debug_assert_eq!(name, pname);
            *avg = polyak(avg, v.as_tensor(), self.tau)?;
        }
        Ok(())
    }

    /// θ̄ by name, for a checkpoint's state (prefix them there).
    pub fn tensors(&self) -> &[(String, Tensor)] {
        &self.tensors
    }

    /// Replaces θ̄ with saved tensors; `get(name)` gives each one. Fails, naming it, when one is
    /// missing or has another shape.
    pub fn load(&mut self, get: impl Fn(&str) -> Option<Tensor>) -> anyhow::Result<()> {
        for (name, avg) in &mut self.tensors {
            let t = get(name).ok_or_else(|| anyhow::anyhow!("lacks tensor `{name}`"))?;
            if t.dims() != avg.dims() {
                anyhow::bail!(
                    "tensor `{name}` has shape {:?}, expected {:?}",
                    t.dims(),
                    avg.dims()
                );
            }
            *avg = t.to_device(avg.device())?.to_dtype(avg.dtype())?.detach();
        }
        Ok(())
    }

    /// θ̄ as safetensors bytes, laid out as the policy's own (`dvnav eval` loads either).
    pub fn safetensors(&self) -> anyhow::Result<Vec<u8>> {
        Ok(safetensors::tensor::serialize(self.tensors.iter().cloned(), None)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    fn var(name: &str, v: &[f32]) -> (String, Var) {
        (name.into(), Var::new(v, &Device::Cpu).unwrap())
    }

    fn values(a: &PolicyAverage) -> Vec<Vec<f32>> {
        a.tensors().iter().map(|(_, t)| t.to_vec1::<f32>().unwrap()).collect()
    }

    #[test]
    fn the_average_follows_the_polyak_recursion_and_owns_its_copy() {
        let policy = [var("a.weight", &[1.0, 2.0]), var("b.bias", &[-4.0])];
        let mut avg = PolicyAverage::start(&policy, 0.25).unwrap();
        // The start is a copy: moving the policy does not move θ̄ until an update.
        policy[0].1.set(&Tensor::new(&[5.0f32, 6.0], &Device::Cpu).unwrap()).unwrap();
        policy[1].1.set(&Tensor::new(&[0.0f32], &Device::Cpu).unwrap()).unwrap();
        assert_eq!(values(&avg), vec![vec![1.0, 2.0], vec![-4.0]]);
        // θ̄ = 0.25·θ + 0.75·θ̄: (0.25·5 + 0.75·1, 0.25·6 + 0.75·2), 0.75·(−4).
        avg.update(&policy).unwrap();
        assert_eq!(values(&avg), vec![vec![2.0, 3.0], vec![-3.0]]);
        avg.update(&policy).unwrap();
        assert_eq!(values(&avg), vec![vec![2.75, 3.75], vec![-2.25]]);
        // No backprop graph behind θ̄: nothing of earlier updates is kept alive by it.
        assert!(avg.tensors().iter().all(|(_, t)| !t.track_op()));
        // τ = 1 is the online policy itself.
        let mut same = PolicyAverage::start(&policy, 1.0).unwrap();
        policy[1].1.set(&Tensor::new(&[7.0f32], &Device::Cpu).unwrap()).unwrap();
        same.update(&policy).unwrap();
        assert_eq!(values(&same), vec![vec![5.0, 6.0], vec![7.0]]);
    }

    #[test]
    fn the_average_saves_as_a_policy_file_and_loads_back() {
        let policy = [var("a.weight", &[1.0, 2.0]), var("b.bias", &[-4.0])];
        let avg = PolicyAverage::start(&policy, 0.5).unwrap();
        let bytes = avg.safetensors().unwrap();
        let read = candle_core::safetensors::load_buffer(&bytes, &Device::Cpu).unwrap();
        assert_eq!(read["a.weight"].to_vec1::<f32>().unwrap(), vec![1.0, 2.0]);
        let mut other =
            PolicyAverage::start(&[var("a.weight", &[0.0, 0.0]), var("b.bias", &[0.0])], 0.5)
                .unwrap();
        other.load(|n| read.get(n).cloned()).unwrap();
        assert_eq!(values(&other), values(&avg));
        let e = other.load(|n| (n == "a.weight").then(|| read[n].clone())).unwrap_err();
        assert!(e.to_string().contains("`b.bias`"), "{e}");
        let e = other.load(|_| Some(read["b.bias"].clone())).unwrap_err();
        assert!(e.to_string().contains("shape"), "{e}");
    }
}
