//! The README's and the book's examples cannot rot.
//!
//! Every fenced block of `README.md` and `docs/*.md` is one of:
//! - ```` ```console ````: run here. Lines starting with `$ ` are commands (bash; a command
//!   ending in ` \` goes on on the next line), other lines the expected output (stdout and
//!   stderr together), matched by snapbox (`...` alone on a line: any lines; `[..]`: any text
//!   within a line); no output lines: the output is not checked. Every command must exit 0. All
//!   the console blocks of one file run in order in one fresh folder, with `msr` (this build) on
//!   the PATH and `../shared` the real data beside the checkout, as a reader has them;
//!   `cargo run --release -p msr-host -- ` is `msr `.
//! - a shell block (`sh`, `bash`, `shell`) with `<!-- needs hardware -->` (or, for `cargo xtask
//!   test`, `<!-- is the test suite -->`) on the line before it: not run.
//! - any other language (`rust`, `text`, `toml`, ...): not a shell example.
//!
//! A fenced block without a language, or a shell block without its mark, fails the test: an
//! example is either run or says why it cannot be. `docs/cli-reference.md` (every `msr ... --help`)
//! is checked apart by trycmd (`cli_help.rs`), which can also write it anew.
use pulldown_cmark::{CodeBlockKind, Event, Parser, Tag, TagEnd};
use std::path::{Path, PathBuf};
use std::process::Command;

const MARKS: [&str; 2] = ["<!-- needs hardware -->", "<!-- is the test suite -->"];
const SHELLS: [&str; 4] = ["sh", "bash", "shell", "zsh"];
const CARGO_RUN: &str = "cargo run --release -p msr-host -- ";
/// Files checked by `cli_help.rs` instead.
const APART: [&str; 1] = ["cli-reference.md"];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

struct Block {
    line: usize,
    lang: String,
    marked: bool,
    text: String,
}

/// The fenced blocks of a Markdown text, with the line each starts on and whether the line just
/// before it is one of the marks.
fn blocks(md: &str) -> Vec<Block> {
    let line_of = |offset: usize| md[..offset].matches('\n').count() + 1;
    let mut out = Vec::new();
    let mut open: Option<Block> = None;
    for (ev, range) in Parser::new(md).into_offset_iter() {
        match ev {
            Event::Start(Tag::CodeBlock(CodeBlockKind::Fenced(info))) => {
                let line = line_of(range.start);
                let before = md[..range.start].trim_end().lines().last().unwrap_or("").trim();
                open = Some(Block {
                    line,
                    lang: info.split([',', ' ']).next().unwrap_or("").to_string(),
                    marked: MARKS.contains(&before),
                    text: String::new(),
                });
            }
            Event::Text(t) => {
                if let Some(b) = open.as_mut() {
                    b.text.push_str(&t);
                }
            }
            Event::End(TagEnd::CodeBlock) => out.extend(open.take()),
            _ => {}
        }
    }
    out
}

/// The Markdown files whose examples are checked here.
fn files() -> Vec<PathBuf> {
    let mut v = vec![root().join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .filter(|p| !APART.iter().any(|a| p.ends_with(a)))
        .collect();
    docs.sort();
    v.extend(docs);
    v
}

/// (command, expected output) pairs of a console block.
fn commands(text: &str) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = Vec::new();
    let mut lines = text.lines();
    while let Some(line) = lines.next() {
        if let Some(cmd) = line.strip_prefix("$ ") {
            let mut cmd = cmd.to_string();
            while cmd.ends_with('\\') {
                cmd.pop();
                cmd.truncate(cmd.trim_end().len());
                cmd.push(' ');
                cmd.push_str(lines.next().unwrap_or("").trim_start());
            }
            out.push((cmd.replace(CARGO_RUN, "msr "), String::new()));
        } else if let Some(last) = out.last_mut() {
            last.1.push_str(line);
            last.1.push('\n');
        } else {
            panic!("a console block must start with `$ `: {line:?}");
        }
    }
    out
}

#[test]
fn every_shell_example_is_run_or_marked() {
    let mut bad = Vec::new();
    for f in files() {
        let md = std::fs::read_to_string(&f).unwrap();
        for b in blocks(&md) {
            let at = format!("{}:{}", f.strip_prefix(root()).unwrap().display(), b.line);
            if b.lang.is_empty() {
                bad.push(format!("{at}: a fenced block without a language (console, sh + a mark, text, ...)"));
            } else if SHELLS.contains(&b.lang.as_str()) && !b.marked {
                bad.push(format!("{at}: a `{}` block that is neither run (```console) nor marked {MARKS:?}", b.lang));
            } else if b.lang == "console" && b.marked {
                bad.push(format!("{at}: a console block is run; it cannot also be marked"));
            } else if b.lang == "console" && commands(&b.text).is_empty() {
                bad.push(format!("{at}: a console block without a `$ ` command"));
            }
        }
    }
    assert!(bad.is_empty(), "examples that are neither run nor marked:\n{}", bad.join("\n"));
}

#[test]
fn the_marks_are_seen() {
    // The check above must be able to fail: an unmarked sh block and an untagged one are found,
    // a marked one is not.
    let md = "text\n\n```sh\nmsr serve\n```\n\n<!-- needs hardware -->\n```sh\nmsr record --camera /dev/video0\n```\n\n```\nx\n```\n";
    let b = blocks(md);
    assert_eq!(b.len(), 3);
    assert_eq!((b[0].lang.as_str(), b[0].marked, b[0].line), ("sh", false, 3));
    assert_eq!((b[1].lang.as_str(), b[1].marked), ("sh", true));
    assert_eq!(b[2].lang, "");
    let c = commands("$ cargo run --release -p msr-host -- dataset \\\n  --count 4\nwrote [..]\n$ ls\n");
    assert_eq!(c[0], ("msr dataset --count 4".to_string(), "wrote [..]\n".to_string()));
    assert_eq!(c[1].0, "ls");
}

#[test]
fn readme_reads_in_three_minutes() {
    let n = std::fs::read_to_string(root().join("README.md")).unwrap().lines().count();
    assert!(n <= 150, "README.md has {n} lines; the book (docs/) is the place for more");
}

#[test]
fn relative_links_resolve() {
    let mut bad = Vec::new();
    for f in files().into_iter().chain([root().join("docs/cli-reference.md")]) {
        let Ok(md) = std::fs::read_to_string(&f) else { continue };
        for (ev, _) in Parser::new(&md).into_offset_iter() {
            let dest = match ev {
                Event::Start(Tag::Link { dest_url, .. }) | Event::Start(Tag::Image { dest_url, .. }) => dest_url,
                _ => continue,
            };
            let path = dest.split('#').next().unwrap_or("");
            if path.is_empty() || path.contains("://") || path.starts_with("mailto:") {
                continue;
            }
            if !f.parent().unwrap().join(path).exists() {
                bad.push(format!("{}: {dest}", f.strip_prefix(root()).unwrap().display()));
            }
        }
    }
    assert!(bad.is_empty(), "links to nothing:\n{}", bad.join("\n"));
}

#[test]
fn console_examples_run() {
    let msr = PathBuf::from(env!("CARGO_BIN_EXE_msr"));
    let path = format!(
        "{}:{}",
        msr.parent().unwrap().display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let shared = root().join("../shared");
    let mut ran = 0;
    for f in files() {
        let md = std::fs::read_to_string(&f).unwrap();
        let console: Vec<Block> = blocks(&md).into_iter().filter(|b| b.lang == "console").collect();
        if console.is_empty() {
            continue;
        }
        let name = f.strip_prefix(root()).unwrap().display().to_string();
        let sandbox = tempfile::tempdir().unwrap();
        let work = sandbox.path().join("work");
        std::fs::create_dir(&work).unwrap();
        std::os::unix::fs::symlink(&shared, sandbox.path().join("shared")).unwrap();
        for b in console {
            for (cmd, want) in commands(&b.text) {
                let t = std::time::Instant::now();
                let out = Command::new("bash")
                    .args(["-o", "pipefail", "-c", &format!("{cmd} 2>&1")])
                    .current_dir(&work)
                    .env("PATH", &path)
                    .output()
                    .unwrap();
                let got = String::from_utf8_lossy(&out.stdout).into_owned();
                eprintln!("{name}:{}: `{cmd}` ({:.1} s)", b.line, t.elapsed().as_secs_f64());
                assert!(out.status.success(), "{name}:{}: `{cmd}` failed ({}):\n{got}", b.line, out.status);
                if !want.is_empty() {
                    snapbox::assert_data_eq!(got, snapbox::Data::text(want));
                }
                ran += 1;
            }
        }
    }
    assert!(ran > 0, "no console example found");
    eprintln!("{ran} example commands ran");
}
