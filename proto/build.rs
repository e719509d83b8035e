//! Compiles dvnav's .proto files with protox (pure Rust, no system `protoc`), generates the prost
//! messages and the tonic service, and keeps the encoded `FileDescriptorSet` so MCAP files can
//! embed the exact schemas that the wire uses. The controller service (`dvnav serve`,
//! package `dvnav.controller.v1`) is compiled on its own, so the episode logs' descriptor set
//! stays that of `dvnav/v1/`.
use prost::Message;
use std::{env, path::PathBuf};

const PROTOS: &[&str] = &["dvnav/v1/learner.proto", "dvnav/v1/episode.proto"];
const CONTROLLER_PROTOS: &[&str] = &["dvnav/controller/v1/controller.proto"];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    for p in PROTOS.iter().chain(CONTROLLER_PROTOS) {
        println!("cargo:rerun-if-changed=proto/{p}");
    }
    let fds = protox::compile(PROTOS, ["proto"])?;
    let out = PathBuf::from(env::var("OUT_DIR")?);
    std::fs::write(out.join("dvnav_descriptor.bin"), fds.encode_to_vec())?;
    // The weights go out as `Bytes`: serialized once per version, shared by every actor's stream.
    tonic_prost_build::configure()
        .build_server(true)
        .build_client(true)
        .bytes(".dvnav.v1.VariablesUpdate.safetensors")
        .compile_fds(fds)?;
    let controller = protox::compile(CONTROLLER_PROTOS, ["proto"])?;
    tonic_prost_build::configure().build_server(true).build_client(true).compile_fds(controller)?;
    Ok(())
}
