//! `msr status`: what a board runs. Its model's CRC and where the model came from (built in,
//! uploaded into RAM, or into a flash slot with its commit's sequence number), the saved
//! statistics and their age, and the board's counters.
use crate::session::Session;
use anyhow::{bail, Result};
use msr_shared::msg::{BoardToHost, ModelSource, RoomCommand, RoomReport, RoomState, StoreReport};
use std::path::Path;
use std::time::Duration;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Serial port of the board (e.g. /dev/ttyACM0, or a PTY `msr serve` printed)
    #[arg(long)]
    pub port: String,
    /// Line rate, baud
    #[arg(long, default_value_t = 921_600)]
    pub baud: u32,
    /// How long to wait for each answer, milliseconds
    #[arg(long, default_value_t = 2000)]
    pub timeout_ms: u64,
    /// One JSON object: `{"store": ..., "status": ...}`
    #[arg(long)]
    pub json: bool,
    /// First tell the board's online self-calibration (what it learns of the room's light):
    /// freeze (stop learning, keep what was learnt), resume, reset (back to the model's own
    /// statistics, the saved ones dropped), save (into its flash store now)
    #[arg(long, value_name = "ACTION")]
    pub room: Option<RoomAction>,
}

/// What `--room` asks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum RoomAction {
    Freeze,
    Resume,
    Reset,
    Save,
}

impl RoomAction {
    pub fn command(self) -> RoomCommand {
        match self {
            RoomAction::Freeze => RoomCommand::Freeze,
            RoomAction::Resume => RoomCommand::Resume,
            RoomAction::Reset => RoomCommand::Reset,
            RoomAction::Save => RoomCommand::Save,
        }
    }
}

/// One line for the room's state.
pub fn describe_room(r: &RoomReport) -> String {
    match r.state {
        RoomState::Off => "room: not learnt (no model, or its test is not the pooled one-sided one)".into(),
        st => format!(
            "room: {}, {} frames learnt from, {} updates, largest offset {:.2} grey levels, {} cells at the limit",
            if st == RoomState::Frozen { "frozen" } else { "learning" },
            r.frames,
            r.updates,
            r.largest_q88 as f64 / 256.0,
            r.at_limit
        ),
    }
}

/// One line for a store report.
pub fn describe_store(r: &StoreReport) -> String {
    let source = match r.source {
        ModelSource::None => "no model".to_string(),
        ModelSource::BuiltIn => "built in".to_string(),
        ModelSource::Ram => "uploaded into RAM (lost at reset)".to_string(),
        ModelSource::Flash { slot, seq } => format!("uploaded into flash slot {slot} (commit {seq})"),
    };
    let stats = match r.stats {
        None => "none saved (the model's own)".to_string(),
        Some(a) if a.this_boot => {
            format!("saved {:.1} s ago", r.now_ms.saturating_sub(a.saved_ms) as f64 / 1000.0)
        }
        Some(a) => format!("saved in an earlier start-up, {:.1} s after it began", a.saved_ms as f64 / 1000.0),
    };
    format!(
        "model crc {:08x}, {source}; statistics: {stats}; uploads take up to {} bytes{}",
        r.model_crc,
        r.capacity,
        if r.busy { "; flash busy" } else { "" }
    )
}

/// Refuses a board that runs another model than `want` (from `path`).
pub fn check_model(runs: u32, want: u32, path: &Path) -> Result<()> {
    if runs == want {
        return Ok(());
    }
    if runs == 0 {
        bail!("the board has no model; give --upload to upload {}", path.display());
    }
    bail!(
        "the board runs model {runs:08x}, not {want:08x} of {}: give --upload to upload it, or the model the board runs",
        path.display()
    )
}

pub fn run(a: Args) -> Result<()> {
    let timeout = Duration::from_millis(a.timeout_ms);
    let mut s = Session::open(&a.port, a.baud)?;
    if let Some(r) = a.room {
        s.room(r.command(), timeout)?;
    }
    let store = s.store(timeout)?;
    let status = s.status(timeout)?;
    if a.json {
        println!("{}", serde_json::json!({ "store": store, "status": status }));
    } else {
        println!("{}", describe_store(&store));
        println!("{}", super::run::describe(&BoardToHost::Status(status)));
        println!("{}", describe_room(&status.room));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use msr_shared::msg::StatsAge;

    #[test]
    fn lines() {
        let mut r = StoreReport {
            model_crc: 0xDEADBEEF,
            source: ModelSource::Flash { slot: 1, seq: 7 },
            stats: Some(StatsAge { saved_ms: 1500, this_boot: true, seq: 9 }),
            now_ms: 4000,
            busy: false,
            capacity: 1024,
        };
        assert_eq!(
            describe_store(&r),
            "model crc deadbeef, uploaded into flash slot 1 (commit 7); statistics: saved 2.5 s ago; uploads take up to 1024 bytes"
        );
        r.source = ModelSource::BuiltIn;
        r.stats = None;
        r.busy = true;
        assert!(describe_store(&r).contains("built in; statistics: none saved (the model's own)"));
        assert!(describe_store(&r).ends_with("; flash busy"));
        let p = Path::new("m.msrm");
        assert!(check_model(5, 5, p).is_ok());
        let e = check_model(4, 5, p).unwrap_err().to_string();
        assert!(e.contains("runs model 00000004, not 00000005 of m.msrm"), "{e}");
        assert!(check_model(0, 5, p).unwrap_err().to_string().contains("no model"));
    }
}
