//! `docs/cli-reference.md` is every `msr ... --help` text as the binary prints it, checked by
//! trycmd: the book and the binary cannot drift apart. After changing a flag, write the file anew
//! with `TRYCMD=overwrite cargo test --release -p msr-host --test cli_help`, and read the diff.
use std::path::Path;
use std::process::Command;

fn reference() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/cli-reference.md")
}

#[test]
fn help_texts_are_the_reference() {
    trycmd::TestCases::new()
        .register_bin("msr", Path::new(env!("CARGO_BIN_EXE_msr")))
        .case(reference());
}

/// The subcommands `msr --help` lists, in its order.
fn subcommands() -> Vec<String> {
    let out = Command::new(env!("CARGO_BIN_EXE_msr")).arg("--help").output().unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    text.lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .map(str::to_string)
        .collect()
}

#[test]
fn every_subcommand_is_in_the_reference() {
    let md = std::fs::read_to_string(reference()).unwrap();
    let cmds = subcommands();
    assert!(cmds.len() >= 16, "msr --help lists {cmds:?}");
    assert!(md.contains("\n$ msr --help\n"), "docs/cli-reference.md lacks `msr --help`");
    let missing: Vec<&String> = cmds
        .iter()
        .filter(|c| !md.contains(&format!("\n$ msr {c} --help\n")))
        .collect();
    assert!(
        missing.is_empty(),
        "docs/cli-reference.md has no `$ msr X --help` block for {missing:?}: add one and write the \
         file anew (TRYCMD=overwrite cargo test --release -p msr-host --test cli_help)"
    );
}
