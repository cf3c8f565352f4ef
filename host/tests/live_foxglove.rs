//! `--live`: `msr mirror-test --live 127.0.0.1:0 --live-wait` watched by a Foxglove WebSocket
//! client that is not msr's: host/tests/live/foxglove_client.py, written from RFC 6455 and the
//! published Foxglove protocol specification, decoding every message with the Python `rosbags`
//! package from the schema text the server advertises. Also: a client that subscribes and never
//! reads (its drops counted and reported), and `/board/status` in the MCAP of a one-board run.
//!
//! Needs the venv `target/pyenv` that `cargo xtask setup` makes.
mod common;
#[path = "../../tests/tests/common/mod.rs"]
mod models;

use msr_sim::Robot;
use serde_json::Value;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;

const TOPICS: [&str; 11] = [
    "/board/head",
    "/board/status",
    "/camera/annotations",
    "/camera/image",
    "/face/image",
    "/face/predicted",
    "/face/saliency",
    "/joint_commands",
    "/joint_states",
    "/msr/trial",
    "/reach/target",
];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

fn python() -> PathBuf {
    let py = root().join("target/pyenv/bin/python");
    assert!(py.exists(), "{} is missing: run `cargo xtask setup`", py.display());
    py
}

fn model(dir: &Path) -> PathBuf {
    let m = dir.join("model.msrm");
    std::fs::write(&m, models::trained_model(Robot::Red)).unwrap();
    m
}

/// `msr` started with its stderr read line by line on a thread (each line also echoed).
struct Run {
    child: Child,
    lines: mpsc::Receiver<String>,
}

impl Run {
    fn start(args: &[&str]) -> Run {
        let mut child = Command::new(env!("CARGO_BIN_EXE_msr"))
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let err = child.stderr.take().unwrap();
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for l in BufReader::new(err).lines().map_while(Result::ok) {
                eprintln!("msr: {l}");
                let _ = tx.send(l);
            }
        });
        Run { child, lines }
    }

    /// Waits for a line of stderr containing `what`.
    fn line(&self, what: &str) -> String {
        loop {
            let l = self.lines.recv().unwrap_or_else(|_| panic!("msr ended before saying {what:?}"));
            if l.contains(what) {
                return l;
            }
        }
    }

    /// Where the server listens, from its first line.
    fn addr(&self) -> String {
        let l = self.line("Foxglove WebSocket server at ws://");
        l.split("ws://").nth(1).unwrap().split_whitespace().next().unwrap().to_string()
    }

    /// Waits for the end: the JSON summary on stdout.
    fn summary(self) -> Value {
        let out = self.child.wait_with_output().unwrap();
        assert!(out.status.success(), "msr failed");
        serde_json::from_slice(&out.stdout).unwrap()
    }
}

fn client(addr: &str, mode: &str) -> Child {
    Command::new(python())
        .arg(root().join("host/tests/live/foxglove_client.py"))
        .args([addr, mode])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap()
}

fn mirror_test(m: &Path, trials: &str) -> Vec<String> {
    ["mirror-test", "--model", m.to_str().unwrap(), "--trials", trials, "--seed", "2", "--parallel", "1", "--json"]
        .map(String::from)
        .to_vec()
}

fn without_live(mut v: Value) -> Value {
    v.as_object_mut().unwrap().remove("live");
    v
}

#[test]
fn a_foxglove_client_gets_every_channel_decoded_and_a_second_one_joins_mid_run() {
    let tmp = tempfile::tempdir().unwrap();
    let m = model(tmp.path());
    let base = mirror_test(&m, "3");
    let plain: Value = serde_json::from_str(&common::msr_ok(&base.iter().map(String::as_str).collect::<Vec<_>>())).unwrap();
    assert!(plain.get("live").is_none(), "no live figures without --live: {plain}");

    let mut args = base.clone();
    args.extend(["--live", "127.0.0.1:0", "--live-wait"].map(String::from));
    let run = Run::start(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let addr = run.addr();
    assert!(addr.starts_with("127.0.0.1:"), "{addr}");
    let mut c = client(&addr, "full");
    run.line("the session is over");
    // The session's end: the client stops once the server falls silent (it should have
    // everything by then, and have left already).
    let _ = writeln!(c.stdin.as_mut().unwrap(), "end");
    let out = c.wait_with_output().unwrap();
    assert!(out.status.success(), "the client failed");
    let r: Value = serde_json::from_slice(&out.stdout).unwrap();
    let live = run.summary();

    assert_eq!(without_live(live.clone()), plain, "the trials' figures differ with --live");
    assert!(live["live"]["clients"].as_u64().unwrap() >= 2, "{}", live["live"]);
    assert_eq!(r["protocol"], "foxglove.sdk.v1");
    let chans = r["channels"].as_array().unwrap();
    let topics: Vec<&str> = chans.iter().map(|c| c["topic"].as_str().unwrap()).collect();
    assert_eq!(topics, TOPICS, "{chans:?}");
    for c in chans {
        assert_eq!(c["encoding"], "cdr", "{c}");
        assert_eq!(c["schemaEncoding"], "ros2msg", "{c}");
    }
    let ty = |t: &str| chans.iter().find(|c| c["topic"] == t).unwrap()["schemaName"].clone();
    assert_eq!(ty("/camera/image"), "sensor_msgs/msg/Image");
    assert_eq!(ty("/camera/annotations"), "foxglove_msgs/msg/ImageAnnotations");
    assert_eq!(ty("/joint_states"), "sensor_msgs/msg/JointState");
    assert_eq!(ty("/board/status"), "diagnostic_msgs/msg/DiagnosticArray");
    for t in TOPICS {
        assert!(r["decoded"][t].as_u64().unwrap_or(0) >= 1, "nothing decoded on {t}: {}", r["counts"]);
    }
    let s = &r["samples"];
    assert_eq!(s["/camera/image"]["encoding"], "mono8");
    assert_eq!(
        s["/camera/image"]["bytes"].as_u64().unwrap(),
        s["/camera/image"]["width"].as_u64().unwrap() * s["/camera/image"]["height"].as_u64().unwrap()
    );
    assert_eq!(s["/board/head"]["name"], serde_json::json!(["HeadYaw", "HeadPitch"]));
    assert!(s["/joint_states"]["name"].as_array().unwrap().iter().any(|n| n == "HeadYaw"));
    assert!(s["/msr/trial"]["names"][0].as_str().unwrap().starts_with("trial "), "{}", s["/msr/trial"]);
    assert!(s["/board/status"]["keys"].as_array().unwrap().iter().any(|k| k == "frames"), "{}", s["/board/status"]);
    assert!(!s["/camera/annotations"]["texts"].as_array().unwrap().is_empty());

    // The second client: every channel advertised, the latched frame, then new ones.
    let second = &r["second"];
    let topics2: Vec<&str> = second["channels"].as_array().unwrap().iter().map(|c| c["topic"].as_str().unwrap()).collect();
    assert_eq!(topics2, TOPICS);
    let stamps: Vec<u64> = second["camera_stamps"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
    assert!(stamps.len() >= 3, "the second client got {stamps:?}");
    let before: Vec<u64> = r["camera_stamps_before_second"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
    assert!(stamps[1..].iter().all(|s| !before.contains(s)), "{stamps:?} {before:?}");
    assert!(stamps.windows(2).all(|w| w[0] != w[1]), "each frame once: {stamps:?}");
}

#[test]
fn a_client_that_never_reads_has_its_drops_counted_and_stops_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let m = model(tmp.path());
    // Six trials: some 20 MB of messages, several times what the client's queue and the
    // sockets' buffers hold.
    let mut args = mirror_test(&m, "6");
    args.extend(["--live", "127.0.0.1:0", "--live-wait"].map(String::from));
    let run = Run::start(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let addr = run.addr();
    let mut c = client(&addr, "slow");
    let mut first = String::new();
    BufReader::new(c.stdout.as_mut().unwrap()).read_line(&mut first).unwrap();
    assert!(first.contains("subscribed"), "{first}");
    run.line("the session is over; waiting for 1 client");
    drop(c.stdin.take());
    assert!(c.wait().unwrap().success());
    let live = run.summary();
    let l = &live["live"];
    assert_eq!(l["clients"], 1, "{l}");
    let (published, dropped) = (l["messages"].as_u64().unwrap(), l["dropped"].as_u64().unwrap());
    assert!(dropped > 0 && dropped < published, "{l}");
    assert_eq!(live["trials"], 6);
}

/// A one-board run's MCAP holds the board's status at each trial's end, as an in-process run's.
#[test]
fn one_board_mcap_has_the_board_status() {
    let tmp = tempfile::tempdir().unwrap();
    let m = model(tmp.path());
    let mcap = tmp.path().join("one.mcap");
    let m = m.to_str().unwrap();
    common::msr_ok(&["mirror-test", "--model", m, "--trials", "2", "--one-board", "--json", "--mcap", mcap.to_str().unwrap()]);
    let buf = std::fs::read(&mcap).unwrap();
    let status: Vec<_> = mcap::MessageStream::new(&buf)
        .unwrap()
        .map(|r| r.unwrap())
        .filter(|r| r.channel.topic == "/board/status")
        .collect();
    assert_eq!(status.len(), 2, "one status a trial");
    let d: msr_host::rosbag::msgs::DiagnosticArray = msr_host::rosbag::msgs::decode(&status[0].data).unwrap();
    assert!(d.status[0].values.iter().any(|kv| kv.key == "frames"));
}
