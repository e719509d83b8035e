//! Where the learner's networks live: `cpu` (default) or `cuda[:N]` (an NVIDIA GPU, with the
//! `cuda` cargo feature). Actors always act on the CPU; weights travel as safetensors either
//! way.

pub use candle_core::Device;

/// Parses `--device`: `cpu`, `cuda` (GPU 0) or `cuda:N`.
pub fn parse(spec: &str) -> anyhow::Result<Device> {
    let spec = spec.trim();
    if spec.eq_ignore_ascii_case("cpu") {
        return Ok(Device::Cpu);
    }
    let ordinal = match spec.split_once(':') {
        Some((kind, n)) if kind.eq_ignore_ascii_case("cuda") => {
            n.parse::<usize>().map_err(|_| {
                anyhow::anyhow!("--device {spec}: `{n}` is not a GPU number (cuda:0, cuda:1, …)")
            })?
        }
        None if spec.eq_ignore_ascii_case("cuda") => 0,
        _ => anyhow::bail!("--device {spec}: expected `cpu`, `cuda` or `cuda:N`"),
    };
    if !cfg!(feature = "cuda") {
        anyhow::bail!(
            "--device {spec}: this dvnav was built without CUDA; build one with `make build-cuda` \
             (CUDA 13.0 from PyPI, into target/cuda/release/dvnav), or with your own toolkit \
             `cargo build --release --features cuda`; or use --device cpu"
        );
    }
    Device::new_cuda(ordinal).map_err(|e| anyhow::anyhow!("--device {spec}: {e}"))
}

/// A short name for logs and benchmark JSON: `cpu` or `cuda:N`.
pub fn name(dev: &Device) -> String {
    match dev.location() {
        candle_core::DeviceLocation::Cpu => "cpu".into(),
        candle_core::DeviceLocation::Cuda { gpu_id } => format!("cuda:{gpu_id}"),
        candle_core::DeviceLocation::Metal { gpu_id } => format!("metal:{gpu_id}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_parses_and_bad_specs_say_what_is_expected() {
        assert!(parse("cpu").unwrap().is_cpu());
        assert!(parse(" CPU ").unwrap().is_cpu());
        let e = parse("gpu").unwrap_err().to_string();
        assert!(e.contains("expected `cpu`, `cuda` or `cuda:N`"), "{e}");
        let e = parse("cuda:x").unwrap_err().to_string();
        assert!(e.contains("not a GPU number"), "{e}");
        assert_eq!(name(&Device::Cpu), "cpu");
    }

    #[cfg(not(feature = "cuda"))]
    #[test]
    fn cuda_without_the_feature_says_how_to_get_it() {
        let e = parse("cuda").unwrap_err().to_string();
        assert!(e.contains("--features cuda"), "{e}");
    }
}
