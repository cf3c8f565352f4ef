//! `msr demo` end to end on small settings: it must write the model, the report with its keys,
//! and the page with its pictures.
use msr_host::demo::{self, DemoConfig};
use msr_host::report::{DemoReport, RealCheck};

/// `../shared/data/nao-red-real` from the repository root.
fn real_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/nao-red-real")
}

#[test]
fn demo_writes_model_report_and_page() {
    let out = std::env::temp_dir().join(format!("msr-demo-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let returned = demo::run(
        &DemoConfig::new(out.clone())
            .with_frames(200)
            .with_epochs(4)
            .with_trials(3)
            .with_qemu_trials(1)
            .with_gate_trials(2)
            .with_real(Some(real_dir())),
    )
    .unwrap();
    let blob = std::fs::read(out.join("model.msrm")).unwrap();
    // The model the demo hands over carries a calibrated self gate, as `msr quantize`'s does.
    let gate = msr_shared::blob::Model::parse(&blob).unwrap().self_gate.expect("the demo's model has a self gate");
    // report.json is the typed report, whole: it reads back as what the demo returned.
    let r: DemoReport =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(serde_json::to_value(&r).unwrap(), serde_json::to_value(&returned).unwrap());
    assert!(!r.eval.rows.is_empty());
    assert!(r.eval.quantized_agreement.is_some());
    assert!(r.bench.get("stages").is_some() && r.timings.contains_key("total_s"));
    assert_eq!(r.mirror_test.inproc.trials, 3);
    assert_eq!(r.mirror_test.trials.len(), 3);
    assert_eq!(r.mirror_test.inproc.limit_violations, 0);
    assert_eq!(r.mirror_test.inproc.servo_bus, "dynamixel");
    // Under QEMU with the model preloaded when QEMU and its image are there; skipped, saying how
    // to build the image, when it is not (a fresh clone).
    let image = msr_sim::qemu::find_image(msr_sim::qemu::BOARD_IMAGE);
    match (&r.mirror_test.qemu, &r.mirror_test.qemu_error) {
        (Some(q), None) => assert_eq!((q.trials, r.mirror_test.qemu_matching_inproc), (1, Some(1))),
        (None, Some(e)) if image.is_err() => assert!(e.contains("run `cargo xtask images`"), "{e}"),
        (None, Some(e)) if !msr_sim::qemu::qemu_available() => assert!(e.starts_with("skipped:"), "{e}"),
        other => panic!("QEMU episodes: {other:?}"),
    }
    // The self gate: its own mirror image may reach; a delayed picture of it never.
    let g = r.self_gate.as_ref().expect("the self gate's scenes");
    // The gate trials ran with the model's own gate.
    assert_eq!((g.gain_tol, g.rest_tol_px, g.hold_tol_px), (gate.gain_tol, gate.rest_tol, gate.hold_tol));
    let scenes: Vec<&str> = g.scenes.iter().map(|s| s.summary.scene.as_str()).collect();
    assert_eq!(scenes, ["mirror", "other", "delayed"]);
    assert_eq!(g.scenes[2].summary.reaches, 0, "a delayed picture started a reach");
    let decisions = |s: &msr_host::report::SceneReport| s.summary.gate_passes + s.summary.gate_rejects + s.summary.gate_undecided;
    assert!(g.scenes.iter().all(|s| s.gain_ratios.len() <= decisions(s)));
    if real_dir().join("manifest.json").exists() {
        // The published model on the real frames, as the mission says it must do.
        let want = RealCheck { marked: 9, hits: 9, unmarked: 6, false_alarms: 0 };
        assert_eq!(r.real, Some(want));
    } else {
        assert!(r.real.is_none() && r.real_skipped.is_some());
        eprintln!("SKIPPED the real-frame part: no {}", real_dir().display());
    }
    // The page can be made again from report.json alone.
    std::fs::remove_file(out.join("index.html")).unwrap();
    msr_host::demo::rewrite_html(&out).unwrap();
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(html.contains("pictures/test0_saliency.png") && html.contains("Reach poses"));
    assert!(html.contains("The self gate") && html.contains("<svg"));
    assert!(out.join("pictures/test0_saliency.png").exists());
    page_fits_1280(&out);
    let _ = std::fs::remove_dir_all(&out);
}

/// The page as headless Chromium lays it out in a 1280 px window: nothing wider than the window,
/// each test frame's five pictures in one row, and the loss plots at least 500 px wide (their
/// labels are drawn for that). A script added to a copy of the page writes what it measured into
/// the title, which `--dump-dom` prints.
fn page_fits_1280(out: &std::path::Path) {
    let script = r#"<script>
const d = document.documentElement;
const rows = [...document.querySelectorAll('.strip')].map(s => {
  const tops = [...s.querySelectorAll('img')].map(i => Math.round(i.getBoundingClientRect().top));
  return [tops.length, Math.max(...tops) - Math.min(...tops)];
});
const over = [...document.querySelectorAll('body *')]
  .filter(e => e.getBoundingClientRect().right > d.clientWidth + 0.5)
  .map(e => e.tagName + '.' + e.className).slice(0, 5);
const plots = [...document.querySelectorAll('.plots img')].map(i => Math.round(i.getBoundingClientRect().width));
document.title = 'LAYOUT ' + JSON.stringify({scroll: d.scrollWidth, client: d.clientWidth, rows, over, plots});
</script></body>"#;
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    let page = out.join("layout-check.html");
    std::fs::write(&page, html.replace("</body>", script)).unwrap();
    let chromium = "chromium-headless-shell";
    let res = std::process::Command::new(chromium)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars"])
        .args(["--window-size=1280,900", "--virtual-time-budget=10000", "--dump-dom"])
        .arg(format!("file://{}", page.display()))
        .output()
        .unwrap_or_else(|e| panic!("{chromium} could not start ({e}): `cargo xtask setup` installs it"));
    let dom = String::from_utf8_lossy(&res.stdout);
    let json = dom
        .split("<title>LAYOUT ")
        .nth(1)
        .and_then(|t| t.split("</title>").next())
        .unwrap_or_else(|| panic!("no layout in Chromium's output: {}", String::from_utf8_lossy(&res.stderr)));
    let m: serde_json::Value = serde_json::from_str(&json.replace("&quot;", "\"")).unwrap();
    eprintln!("report layout at 1280 px: {m}");
    assert_eq!(m["client"], 1280, "{m}");
    assert!(m["scroll"].as_u64().unwrap() <= 1280, "the page is wider than 1280 px: {m}");
    assert!(m["over"].as_array().unwrap().is_empty(), "elements past the right edge: {m}");
    let rows = m["rows"].as_array().unwrap();
    assert!(!rows.is_empty(), "{m}");
    for r in rows {
        assert_eq!((r[0].as_u64(), r[1].as_u64()), (Some(5), Some(0)), "a test frame's pictures are not in one row: {m}");
    }
    let plots = m["plots"].as_array().unwrap();
    assert_eq!(plots.len(), 2, "{m}");
    assert!(plots.iter().all(|w| w.as_u64().unwrap() >= 500), "loss plots too small to read: {m}");
}
