//! What the `msr-host` integration tests share: running the `msr` binary, and the published real
//! frames beside the checkout.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;

/// Runs `msr` with `args`: (success, stdout, stderr).
pub fn msr(args: &[&str]) -> (bool, String, String) {
    let (code, out, err) = msr_code(args);
    (code == 0, out, err)
}

/// Runs `msr` with `args`: (exit code, -1 when killed by a signal; stdout; stderr).
pub fn msr_code(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_msr")).args(args).output().unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs `msr` with `args`, which must succeed: its stdout.
pub fn msr_ok(args: &[&str]) -> String {
    let (ok, out, err) = msr(args);
    assert!(ok, "msr {args:?}: {err}");
    out
}

/// `../shared/data/nao-red-real` beside the checkout, or `None` (said on stderr) when absent.
pub fn real_dir() -> Option<PathBuf> {
    let d = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/nao-red-real");
    if d.join("manifest.json").is_file() {
        Some(d.canonicalize().unwrap())
    } else {
        eprintln!("SKIP: real data folder {} is absent", d.display());
        None
    }
}

/// Whether `qemu-system-arm` and the board image are here (said on stderr when not, and the
/// test returns: `cargo xtask test` sets both up).
pub fn qemu_board_ready() -> bool {
    let ready = msr_sim::qemu::qemu_available() && msr_sim::qemu::find_image(msr_sim::qemu::BOARD_IMAGE).is_ok();
    if !ready {
        eprintln!("SKIPPED: qemu-system-arm or the board image is missing (`cargo xtask test` sets both up)");
    }
    ready
}
