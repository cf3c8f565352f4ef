//! `--live [ADDR]` and `--live-wait`, shared by `msr run`, `msr mirror-test` and `msr record`:
//! the flags, and the lines the commands print about the server ([`crate::live`]).
use crate::live::{Live, LiveStats};
use anyhow::Result;
use std::net::SocketAddr;
use std::sync::Arc;

/// The `--live` and `--live-wait` flags.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct LiveFlags {
    /// Serve the session live to Foxglove (the --mcap topics over the Foxglove WebSocket
    /// protocol) at ADDR, 127.0.0.1:8765 when none is given; 0.0.0.0:PORT serves the network
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = crate::live::DEFAULT_ADDR,
          value_parser = crate::live::parse_addr)]
    pub live: Option<SocketAddr>,
    /// With --live: start only once a client has subscribed to a channel, and at the end stay
    /// until every client has disconnected
    #[arg(long, requires = "live")]
    pub live_wait: bool,
}

impl LiveFlags {
    /// Starts the server (before any work: a taken address is refused in one line), says where
    /// it listens, and with --live-wait waits for a subscriber.
    pub fn start(&self, quiet: bool) -> Result<Option<Arc<Live>>> {
        let Some(addr) = self.live else { return Ok(None) };
        let live = Arc::new(Live::start(addr)?);
        // Always said, even with --json (on stderr): a server is listening.
        eprintln!("live: Foxglove WebSocket server at {} (Foxglove: Open connection, Foxglove WebSocket)", live.url());
        if self.live_wait {
            eprintln!("live: waiting for a client to subscribe");
            live.wait_for_subscriber();
            if !quiet {
                eprintln!("live: a client subscribed; starting");
            }
        }
        Ok(Some(live))
    }

    /// Ends the server (after the clients have left, with --live-wait); its figures.
    pub fn finish(&self, live: Option<Arc<Live>>) -> Option<LiveStats> {
        let live = live?;
        if self.live_wait {
            let n = live.clients_now();
            eprintln!("live: the session is over{}", if n > 0 { format!("; waiting for {n} client(s) to disconnect") } else { String::new() });
            live.wait_for_no_clients();
        }
        Some(live.stop())
    }
}
