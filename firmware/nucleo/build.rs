//! Puts `memory.x` where the linker finds it and copies the optional built-in model blob
//! (`MSR_MODEL_BLOB`) into the build.
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    std::fs::copy("memory.x", out.join("memory.x")).expect("copying memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-env-changed=MSR_MODEL_BLOB");
    let model = out.join("model.bin");
    match std::env::var_os("MSR_MODEL_BLOB") {
        Some(path) => {
            let path = PathBuf::from(path);
            println!("cargo:rerun-if-changed={}", path.display());
            let bytes = std::fs::read(&path)
                .unwrap_or_else(|e| panic!("MSR_MODEL_BLOB={}: {e}", path.display()));
            std::fs::write(&model, bytes).expect("writing the built-in model");
        }
        None => std::fs::write(&model, []).expect("writing the empty built-in model"),
    }
}
