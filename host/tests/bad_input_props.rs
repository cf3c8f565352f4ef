//! Property tests of bad input: `msr`'s argument parser and argument checks, and its
//! file readers, fed random values and bytes, never panic and answer with one line naming the
//! problem; a few runs of the `msr` binary itself also exit with 1 or 2 and change no input.
//!
//! The parser is tested in-process (cheap, many cases); the binary as a subprocess (a few cases).
use proptest::prelude::*;
use std::path::Path;
use std::process::Command;

/// Every `--flag` of every subcommand, from the parser itself.
fn flags() -> Vec<(String, Vec<String>)> {
    msr_host::cmd::command()
        .get_subcommands()
        .map(|s| {
            let f = s
                .get_arguments()
                .filter_map(|a| a.get_long().map(|l| format!("--{l}")))
                .filter(|l| l != "--help" && l != "--version")
                .collect();
            (s.get_name().to_string(), f)
        })
        .collect()
}

/// A value a user might type: numbers at and past every edge, words, paths, empty.
fn value() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<i64>().prop_map(|v| v.to_string()),
        any::<u64>().prop_map(|v| v.to_string()),
        any::<f64>().prop_map(|v| v.to_string()),
        any::<f64>().prop_map(|v| format!("{v:e}")),
        Just("-0".to_string()),
        Just("NaN".to_string()),
        Just("-inf".to_string()),
        Just("1e-20".to_string()),
        Just("18446744073709551616".to_string()),
        Just("".to_string()),
        Just("red".to_string()),
        "[a-z0-9./-]{0,12}",
        "\\PC{0,8}",
    ]
}

fn one_line(msg: &str) -> bool {
    let t = msg.trim();
    !t.is_empty() && !t.contains('\n')
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    /// Random flags and values of a real subcommand: the parser and the range checks either
    /// accept or refuse with one line; nothing panics, nothing touches the disk.
    #[test]
    fn parser_and_checks_never_panic(cmd in 0usize..64, picks in prop::collection::vec((0usize..64, value()), 0..6)) {
        let all = flags();
        let (name, fl) = &all[cmd % all.len()];
        let mut argv = vec!["msr".to_string(), name.clone()];
        for (i, v) in &picks {
            if !fl.is_empty() {
                argv.push(fl[i % fl.len()].clone());
            }
            argv.push(v.clone());
        }
        match msr_host::cmd::parse_from(&argv) {
            Err(e) => {
                let m = msr_host::cmd::clap_line(&e);
                prop_assert!(one_line(&m), "{argv:?}: {m}");
            }
            Ok(cli) => {
                if let Err(e) = msr_host::cmd::check::check(&cli.command) {
                    let m = msr_host::cmd::one_line(&e);
                    prop_assert!(one_line(&m), "{argv:?}: {m}");
                }
            }
        }
    }

    /// The file readers on random bytes (and on cut-off real-looking headers): an error that
    /// names the file, never a panic or an allocation the bytes did not earn.
    #[test]
    fn file_readers_refuse_random_bytes(bytes in prop::collection::vec(any::<u8>(), 0..2048), npy_shape in (any::<u32>(), any::<u32>())) {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("f.bin");
        std::fs::write(&p, &bytes).unwrap();
        let name = p.display().to_string();
        let named = |r: anyhow::Result<()>| -> Result<(), TestCaseError> {
            if let Err(e) = r {
                let m = msr_host::cmd::one_line(&e);
                prop_assert!(one_line(&m) && m.contains(&name), "{m}");
            }
            Ok(())
        };
        named(msr_host::fsio::read_blob(&p).map(|_| ()))?;
        named(msr_host::data::crop::load_grey(&p).map(|_| ()))?;
        named(msr_host::data::npy::read(&p).map(|_| ()))?;
        named(msr_host::data::npy::read_shaped(&p, (58, 75)).map(|_| ()))?;
        named(msr_host::train::reach::read_rows::<2>(&p).map(|_| ()))?;
        // A valid npy header that claims a huge shape over a few bytes of data.
        let header = format!(
            "{{'descr': '<f8', 'fortran_order': False, 'shape': ({}, {}), }}",
            npy_shape.0, npy_shape.1
        );
        let mut npy = b"\x93NUMPY\x01\x00".to_vec();
        let pad = 64 - (10 + header.len() + 1) % 64;
        let h = format!("{header}{}\n", " ".repeat(pad));
        npy.extend((h.len() as u16).to_le_bytes());
        npy.extend(h.as_bytes());
        npy.extend(&bytes[..bytes.len().min(64)]);
        std::fs::write(&p, &npy).unwrap();
        named(msr_host::data::npy::read(&p).map(|_| ()))?;
        named(msr_host::data::npy::read_shaped(&p, (58, 75)).map(|_| ()))?;
    }
}

/// Runs `msr` to its end, with nothing on its standard input: exit code and standard error. A
/// run that never ends is a hang, which the test runner stops (nextest's `terminate-after`).
fn run_msr(args: &[String], dir: &Path) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(args)
        .current_dir(dir)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .output()
        .unwrap();
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stderr).into_owned())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// The binary on input files of random bytes, with random extra flags, and outputs that
    /// sometimes name an input: exit 1 or 2, one line on stderr, no panic, no input changed.
    #[test]
    fn msr_refuses_random_inputs_with_one_line(
        which in 0usize..9,
        bytes in prop::collection::vec(any::<u8>(), 0..512),
        out_is_input in any::<bool>(),
        extra in prop::option::of((0usize..64, value())),
    ) {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path();
        for n in ["in.bin", "in.png", "in.msrm", "in.json", "in.csv", "in.safetensors"] {
            std::fs::write(d.join(n), &bytes).unwrap();
        }
        std::fs::create_dir(d.join("data")).unwrap();
        std::fs::write(d.join("data/index.json"), &bytes).unwrap();
        let out = if out_is_input { "in.msrm" } else { "out.msrm" };
        let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<String>>();
        let mut args = match which {
            0 => s(&["detect", "--model", "in.msrm", "--image", "in.png", "--head-yaw", "0", "--head-pitch", "0", "--png", if out_is_input { "in.png" } else { "out.png" }]),
            1 => s(&["blobs", "--mask", "in.png"]),
            2 => s(&["eval", "--model", "in.msrm", "--data", "data"]),
            3 => s(&["import", "in.json", "--out", out]),
            4 => s(&["mirror-test", "--model", "in.msrm", "--trials", "1", "--trials-out", if out_is_input { "in.msrm" } else { "t.json" }]),
            5 => s(&["run", "--port", "/nonexistent/tty", "--model", "in.msrm", "--sim", "red"]),
            6 => s(&["train-reach", "--inputs", "in.csv", "--targets", "in.bin", "--out", if out_is_input { "in.csv" } else { "r.safetensors" }, "--iterations", "10", "--no-loo"]),
            7 => s(&["quantize", "--train", "data", "--reach", "in.safetensors", "--out", out]),
            _ => s(&["train", "--data", "data", "--out", "trained", "--epochs", "1"]),
        };
        if let Some((i, v)) = extra {
            let all = flags();
            if let Some((_, fl)) = all.iter().find(|(n, _)| *n == args[0]) {
                args.push(fl[i % fl.len()].clone());
                args.push(v);
            }
        }
        let (code, err) = run_msr(&args, d);
        prop_assert!(!err.contains("panicked"), "{args:?}: {err}");
        if code == 0 {
            // Random bytes that happen to be a valid input (an empty CSV line set, say) are
            // not bad input; nothing more to check.
            return Ok(());
        }
        prop_assert!(code == 1 || code == 2, "{args:?}: exit {code}: {err}");
        prop_assert_eq!(err.trim().lines().count(), 1, "{:?}: {}", args, err);
        prop_assert!(err.starts_with("msr: error: "), "{args:?}: {err}");
        for n in ["in.bin", "in.png", "in.msrm", "in.json", "in.csv", "in.safetensors", "data/index.json"] {
            prop_assert_eq!(&std::fs::read(d.join(n)).unwrap(), &bytes, "{:?} changed {}", args, n);
        }
    }
}
