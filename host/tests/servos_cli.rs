//! `msr servos` against an implementation of Protocol 2.0 that is not ours: the `dynamixel2`
//! crate, as bus master over the PTY that `msr servos` opens and prints.
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

#[test]
fn dynamixel2_pings_reads_writes_and_sync_reads_msr_servos() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(["servos", "--bus", "dynamixel", "--robot", "red", "--seconds", "30"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    let path = line.trim().to_string();
    let result = std::panic::catch_unwind(|| {
        assert!(path.starts_with("/dev/"), "{path:?}");
        let mut d = dynamixel2::Bus::open(&path, 1_000_000).unwrap();
        // The default map: HeadYaw 1, HeadPitch 2, LShoulderPitch 3, LShoulderRoll 4, LElbowRoll 6.
        let ids = [1u8, 2, 3, 4, 6];
        for id in ids {
            let p = d.ping(id).unwrap();
            assert_eq!((p.motor_id, p.data.model), (id, 1020));
        }
        assert!(d.ping(5).is_err(), "LElbowYaw has no servo on this bus");
        assert_eq!(d.read_u8(6, 7).unwrap().data, 6, "ID register");
        assert_eq!(d.read_u8(1, 9).unwrap().data, 250, "Return Delay Time");
        d.write_u32(2, 116, 2100).unwrap();
        std::thread::sleep(Duration::from_millis(400));
        let r = d.sync_read_u32(&ids, 132).unwrap();
        assert_eq!(r.iter().map(|r| r.motor_id).collect::<Vec<_>>(), ids);
        assert!(r[1].data.abs_diff(2100) <= 2, "{}", r[1].data);
        // The others have not moved from home (HeadYaw at 0 rad: the centre count).
        assert_eq!(r[0].data, 2048);
        // Writing EEPROM with the torque on is refused (Access Error).
        assert!(d.write_u32(1, 48, 3000).is_err());
    });
    let _ = child.kill();
    let _ = child.wait();
    if let Err(e) = result {
        std::panic::resume_unwind(e);
    }
}
