//! The demo's `index.html`.
use anyhow::Result;
use serde_json::Value;
use std::path::Path;

pub fn write_html(out: &Path, report: &Value, _blob: &[u8], _data: &Path) -> Result<()> {
    std::fs::write(out.join("index.html"), format!("<pre>{}</pre>", serde_json::to_string_pretty(report)?))?;
    Ok(())
}
