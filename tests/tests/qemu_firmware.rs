//! The firmware under QEMU (mps2-an386, Cortex-M4): the UART plumbing, the board image driven
//! over its two links, and exactness against the host build of the same pipeline.
//!
//! The images are built by `cargo xtask test` (or `cargo xtask images`) before the tests run;
//! a missing image fails with the command to build it. Only a missing `qemu-system-arm` skips.

use std::io::{Read, Write};
use std::time::Duration;

use msr_sim::qemu::{self, Qemu};

/// `None` (with a message) when QEMU is not installed.
fn image(name: &str) -> Option<std::path::PathBuf> {
    if !qemu::qemu_available() {
        eprintln!("SKIPPED: {} not found; install qemu-system-arm to run the QEMU tests", qemu::qemu_binary());
        return None;
    }
    Some(qemu::find_image(name).unwrap_or_else(|e| panic!("{e:#}")))
}

#[test]
fn selftest_clock_and_uarts() {
    let Some(img) = image("msr-qemu-selftest") else { return };
    let mut q = Qemu::start(&img).unwrap();
    let msg: Vec<u8> = (1..=255u8).collect();
    q.host.write_all(&msg).unwrap();
    let mut got = vec![0u8; msg.len()];
    q.servo.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    q.servo.read_exact(&mut got).unwrap();
    assert_eq!(got, msg.iter().map(|b| b ^ 0x55).collect::<Vec<_>>());
    q.servo.write_all(b"servo->host").unwrap();
    let mut back = [0u8; 11];
    q.host.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    q.host.read_exact(&mut back).unwrap();
    assert_eq!(&back, b"servo->host");
    q.host.write_all(&[0]).unwrap();
    let exit = q.wait(Duration::from_secs(20)).unwrap();
    exit.success().unwrap();
    assert!(exit.output.contains("calibration: 4000000 loop instructions"), "{}", exit.output);
}
