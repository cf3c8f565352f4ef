//! `msr status`: what a board runs. Its model's CRC and where the model came from (built in,
//! uploaded into RAM, or into a flash slot with its commit's sequence number), the saved
//! statistics and their age, and the board's counters.
use crate::describe::{describe, describe_room, describe_store};
use crate::session::Session;
use anyhow::Result;
use msr_shared::msg::{BoardToHost, RoomCommand};
use std::time::Duration;

/// `msr status`'s flags: the board's line, the wait, the format, and a room action.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The board to ask.
    #[command(flatten)]
    pub line: super::BoardLine,
    /// How long to wait for each answer, milliseconds
    #[arg(long, default_value_t = 2000)]
    pub timeout_ms: u64,
    /// One JSON object: `{"store": ..., "status": ...}`
    #[arg(long)]
    pub json: bool,
    /// First tell the board's online self-calibration (what it learns of the room's light) to
    /// freeze, resume, reset or save
    #[arg(long, value_name = "ACTION")]
    pub room: Option<RoomAction>,
}

/// What `--room` asks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum RoomAction {
    /// Stop learning, keep what was learnt
    Freeze,
    /// Learn again
    Resume,
    /// Back to the model's calibrated statistics, the saved ones dropped
    Reset,
    /// Save what was learnt into the board's flash store now
    Save,
}

impl RoomAction {
    /// The message that asks the board for this action.
    pub fn command(self) -> RoomCommand {
        match self {
            RoomAction::Freeze => RoomCommand::Freeze,
            RoomAction::Resume => RoomCommand::Resume,
            RoomAction::Reset => RoomCommand::Reset,
            RoomAction::Save => RoomCommand::Save,
        }
    }
}

/// Asks the board (after the `--room` action, if any) for its store and status, and prints them.
pub fn run(a: Args) -> Result<()> {
    let timeout = Duration::from_millis(a.timeout_ms);
    let mut s = Session::open(&a.line.port, a.line.baud)?;
    if let Some(r) = a.room {
        s.room(r.command(), timeout)?;
    }
    let store = s.store(timeout)?;
    let status = s.status(timeout)?;
    if a.json {
        println!("{}", serde_json::json!({ "store": store, "status": status }));
    } else {
        println!("{}", describe_store(&store));
        println!("{}", describe(&BoardToHost::Status(status)));
        println!("{}", describe_room(&status.room));
    }
    Ok(())
}
