//! The noisy-line flags `msr serve` and `msr mirror-test` share: one definition, one range check
//! (in [`super::check`]), one way to the sim's [`FaultConfig`].
use msr_sim::link::FaultConfig;

/// The noisy-line flags: bit errors and bursts on the emulated links.
#[derive(clap::Args, Debug, Clone)]
pub struct LineNoise {
    /// Bit-error rate on both directions of the link (a noisy line), errors per bit
    #[arg(long, default_value_t = 0.0)]
    pub ber: f64,
    /// Bursts (the sim's burst model): probability per byte that a burst of `--burst-len`
    /// random bytes starts
    #[arg(long, default_value_t = 0.0)]
    pub burst_rate: f64,
    /// Bytes a burst replaces
    #[arg(long, default_value_t = 16)]
    pub burst_len: u32,
}

impl LineNoise {
    /// The faults these flags ask for; nothing else (no disconnects, no drops).
    pub fn faults(&self) -> FaultConfig {
        FaultConfig {
            bit_error_rate: self.ber,
            burst_rate: self.burst_rate,
            burst_len: self.burst_len,
            ..FaultConfig::default()
        }
    }
}
