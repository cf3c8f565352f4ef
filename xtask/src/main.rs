//! `cargo xtask test`: everything the test suite needs, from a fresh machine.
//!
//! 1. checks (and installs when it can) the `thumbv7em-none-eabihf` target, `qemu-system-arm`,
//!    `ffmpeg` and headless Chromium, and makes the Python venv `target/pyenv` with `rosbags` and
//!    `mcap` (pip);
//! 2. builds `msr-shared` and `msr-firmware` for the bare-metal target without std;
//! 3. builds the QEMU and NUCLEO-F429ZI firmware images, side by side;
//! 4. runs every test of the workspace (the QEMU tests use the image from step 3), with
//!    cargo-nextest where it is installed (`.config/nextest.toml`; then the doctests with
//!    `cargo test --doc`), else with `cargo test`; `XTASK_RUNNER=cargo` asks for `cargo test`.
//!
//! `cargo xtask setup` does steps 1 only. Every step says what it runs.

#[cfg(test)]
mod imports;

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

const TARGET: &str = "thumbv7em-none-eabihf";
/// Bare-metal images: (crate folder, what it is).
const IMAGES: [(&str, &str); 2] = [
    ("firmware/qemu", "QEMU mps2-an386 image"),
    ("firmware/nucleo", "NUCLEO-F429ZI image"),
];

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("test") => test(&args[1..]),
        Some("setup") => setup(),
        Some("images") => setup().and_then(|_| build_images()),
        _ => {
            eprintln!(
                "usage: cargo xtask <command>\n\n\
                 commands:\n  \
                 test [ARGS]  set up, build the firmware images, run every test (ARGS go to cargo nextest run,\n               \
                              or to cargo test where nextest is missing or XTASK_RUNNER=cargo)\n  \
                 setup        install or check the thumbv7em target, qemu-system-arm, ffmpeg, Chromium\n               \
                              and the Python venv target/pyenv (rosbags, mcap, pillow)\n  \
                 images       setup, then build the bare-metal firmware images"
            );
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask sits one level below the workspace root")
        .to_path_buf()
}

fn step(what: &str) {
    println!("\n==> {what}");
}

/// Runs a command in `dir`, echoing it; an error names the command.
fn run(dir: &Path, program: &str, args: &[&str]) -> Result<(), String> {
    println!("$ {program} {}", args.join(" "));
    let status = Command::new(program)
        .args(args)
        .current_dir(dir)
        .status()
        .map_err(|e| format!("could not start `{program}`: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("`{program} {}` failed ({status})", args.join(" ")))
    }
}

fn output(program: &str, args: &[&str]) -> Option<String> {
    let out = Command::new(program).args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
}

fn setup() -> Result<(), String> {
    step(&format!("checking the Rust target {TARGET}"));
    let installed = output("rustup", &["target", "list", "--installed"]).unwrap_or_default();
    if installed.lines().any(|l| l.trim() == TARGET) {
        println!("{TARGET} is installed");
    } else {
        println!("{TARGET} is missing: installing it with rustup");
        run(&root(), "rustup", &["target", "add", TARGET])?;
    }

    tools(&[
        Tool {
            program: "qemu-system-arm",
            version_args: &["--version"],
            package: "qemu-system-arm",
            what: "qemu-system-arm (for the emulated Cortex-M4 tests)",
        },
        Tool {
            program: "ffmpeg",
            version_args: &["-version"],
            package: "ffmpeg",
            what: "ffmpeg (for the camera-stream tests)",
        },
        Tool {
            program: "chromium-headless-shell",
            version_args: &["--version"],
            package: "chromium-headless-shell",
            what: "headless Chromium (for the test that lays out the demo's report at 1280 px)",
        },
    ])?;
    pyenv()
}

/// The Python packages the ROS 2 tests check `msr` against (independent readers and writers of
/// rosbag2 and MCAP; Pillow encodes the JPEG and PNG test images), pinned.
const PY_PACKAGES: [&str; 3] = ["rosbags==0.11.9", "mcap==1.6.0", "pillow==13.0.0"];

/// Makes the virtual environment `target/pyenv` with [`PY_PACKAGES`] (the tests in
/// host/tests/rosbag_py.rs run its python and fail, naming this command, without it).
fn pyenv() -> Result<(), String> {
    tools(&[Tool {
        program: "python3",
        version_args: &["--version"],
        package: "python3-venv",
        what: "python3 (for the ROS 2 bag tests)",
    }])?;
    let env = root().join("target/pyenv");
    let py = env.join("bin/python");
    step(&format!("making the Python venv {} with {}", env.display(), PY_PACKAGES.join(", ")));
    let env_s = env.to_string_lossy().into_owned();
    let py_s = py.to_string_lossy().into_owned();
    if !py.exists() {
        run(&root(), "python3", &["-m", "venv", &env_s])?;
    }
    let check = "import importlib.metadata as m; print(m.version('rosbags'), m.version('mcap'), m.version('pillow'))";
    let want: Vec<&str> = PY_PACKAGES.iter().map(|p| p.split("==").nth(1).unwrap_or("")).collect();
    if output(&py_s, &["-c", check]).is_some_and(|v| v.split_whitespace().eq(want.iter().copied())) {
        println!("{} are installed", PY_PACKAGES.join(", "));
        return Ok(());
    }
    let mut args = vec!["-m", "pip", "install", "-q"];
    args.extend(PY_PACKAGES);
    run(&root(), &py_s, &args)
}

/// A program a test needs, and the Debian package that has it.
struct Tool {
    program: &'static str,
    version_args: &'static [&'static str],
    package: &'static str,
    what: &'static str,
}

/// Checks that each program runs, and installs the Debian packages of those that do not, in
/// one `apt-get` without the packages' recommendations (qemu-system-arm's alone are a desktop's
/// worth of GTK, GStreamer and firmware), when this user can.
fn tools(tools: &[Tool]) -> Result<(), String> {
    let mut missing = Vec::new();
    for t in tools {
        step(&format!("checking {}", t.what));
        match output(t.program, t.version_args) {
            Some(v) => println!("{}", v.lines().next().unwrap_or("found")),
            None => {
                println!("{} is missing", t.program);
                missing.push(t);
            }
        }
    }
    if missing.is_empty() {
        return Ok(());
    }
    let packages: Vec<&str> = missing.iter().map(|t| t.package).collect();
    let is_root = output("id", &["-u"]).is_some_and(|u| u.trim() == "0");
    if !(is_root && output("apt-get", &["--version"]).is_some()) {
        let programs: Vec<&str> = missing.iter().map(|t| t.program).collect();
        return Err(format!(
            "{} not installed and this user cannot install them; install the Debian/Ubuntu \
             packages `{}` (or your distribution's) and run again",
            programs.join(", "),
            packages.join(" ")
        ));
    }
    step(&format!("installing the Debian packages {}", packages.join(", ")));
    run(&root(), "apt-get", &["update", "-q"])?;
    let mut args = vec!["install", "-y", "-q", "--no-install-recommends"];
    args.extend(&packages);
    run(&root(), "apt-get", &args)?;
    for t in missing {
        if output(t.program, t.version_args).is_none() {
            return Err(format!("`{}` still does not run after installing {}", t.program, t.package));
        }
    }
    Ok(())
}

fn build_images() -> Result<(), String> {
    let root = root();
    step(&format!("building msr-shared and msr-firmware for {TARGET} (no std)"));
    run(
        &root,
        "cargo",
        &["build", "--release", "--target", TARGET, "-p", "msr-shared", "-p", "msr-firmware"],
    )?;
    for (dir, what) in IMAGES {
        if !root.join(dir).join("Cargo.toml").exists() {
            return Err(format!("{dir}/Cargo.toml is missing: cannot build the {what}"));
        }
    }
    // Each image ends in a fat-LTO link with one codegen unit, which keeps one core busy for
    // most of a minute: the images build side by side, each printing its output when done.
    let names: Vec<String> = IMAGES.iter().map(|(dir, what)| format!("the {what} ({dir})")).collect();
    step(&format!("building {}, side by side", names.join(" and ")));
    let outputs: Vec<_> = std::thread::scope(|s| {
        let builds: Vec<_> = IMAGES
            .iter()
            .map(|(dir, _)| {
                let path = root.join(dir);
                s.spawn(move || Command::new("cargo").args(["build", "--release"]).current_dir(path).output())
            })
            .collect();
        builds.into_iter().map(|b| b.join().expect("the build thread does not panic")).collect()
    });
    let mut failed = Vec::new();
    for ((dir, what), out) in IMAGES.iter().zip(outputs) {
        println!("\n$ cargo build --release  (in {dir})");
        let out = out.map_err(|e| format!("could not start `cargo` for the {what}: {e}"))?;
        print!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        if !out.status.success() {
            failed.push(format!("`cargo build --release` in {dir} failed ({})", out.status));
        }
    }
    if failed.is_empty() {
        Ok(())
    } else {
        Err(failed.join("; "))
    }
}

fn test(extra: &[String]) -> Result<(), String> {
    setup()?;
    build_images()?;
    let root = root();
    let nextest = std::env::var("XTASK_RUNNER").as_deref() != Ok("cargo")
        && output("cargo", &["nextest", "--version"]).is_some();
    if nextest {
        step("running every test of the workspace with cargo-nextest (both cores across the test binaries)");
        let mut args = vec!["nextest", "run", "--workspace", "--release"];
        args.extend(extra.iter().map(String::as_str));
        run(&root, "cargo", &args)?;
        step("running the crates' documentation examples (nextest does not run doctests)");
        run(&root, "cargo", &["test", "--workspace", "--release", "--doc"])?;
    } else {
        step("running every test of the workspace with cargo test (cargo-nextest is not installed, \
              or XTASK_RUNNER=cargo; `cargo install cargo-nextest --locked` spreads the tests over the cores)");
        let mut args = vec!["test", "--workspace", "--release"];
        args.extend(extra.iter().map(String::as_str));
        run(&root, "cargo", &args)?;
    }
    println!("\nxtask: all tests passed");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::root;
    use std::collections::{BTreeMap, BTreeSet};
    use std::process::Command;

    /// Each package `cargo tree ARGS` resolves, with the sets of features it is built with.
    fn features(args: &[&str]) -> BTreeMap<String, BTreeSet<String>> {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let out = Command::new(cargo)
            .args(["tree", "--offline", "--prefix", "none", "--no-dedupe", "-f", "{p} {f}"])
            .args(args)
            .current_dir(root())
            .output()
            .expect("run cargo tree");
        assert!(out.status.success(), "cargo tree {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        let mut map: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for line in String::from_utf8_lossy(&out.stdout).lines() {
            let mut words = line.split(' ');
            let (Some(name), Some(version)) = (words.next(), words.next()) else { continue };
            let feats: Vec<&str> = words.collect();
            map.entry(format!("{name} {version}")).or_default().insert(feats.join(" "));
        }
        map
    }

    /// The README's first command builds `msr-host` without dev-dependencies; the test command
    /// builds the workspace with them. A dependency whose features differ between the two is
    /// compiled twice, and with it everything above it (burn included).
    #[test]
    fn the_build_and_the_test_build_resolve_the_same_features() {
        let build = features(&["-p", "msr-host", "-e", "no-dev"]);
        let test = features(&["--workspace"]);
        assert!(build.len() > 100, "cargo tree listed {} packages", build.len());
        let differ: Vec<String> = build
            .iter()
            .filter_map(|(p, f)| test.get(p).filter(|g| *g != f).map(|g| format!("{p}: build {f:?}, test {g:?}")))
            .collect();
        assert!(
            differ.is_empty(),
            "name these features in host/Cargo.toml's list for the test build:\n{}",
            differ.join("\n")
        );
    }
}
