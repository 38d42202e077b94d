//! Compiles tilefarm.proto with the vendored protoc, so no system install is needed.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let protoc = protoc_bin_vendored::protoc_bin_path()?;
    // SAFETY: build scripts are single-threaded; prost-build reads PROTOC from the env.
    unsafe { std::env::set_var("PROTOC", protoc) };
    println!("cargo:rerun-if-changed=tilefarm.proto");
    tonic_prost_build::configure().compile_protos(&["tilefarm.proto"], &["."])?;
    Ok(())
}
