//! One readable line for each thing a board reports: its messages, its room calibration and its
//! model store.
use msr_shared::msg::{BoardToHost, ModelSource, RoomReport, RoomState, StoreReport};

/// One readable line for a board message.
pub fn describe(m: &BoardToHost) -> String {
    match m {
        BoardToHost::Detection(d) => {
            let none = match d.reason {
                Some(r) => format!("no detection: {r:?}"),
                None => "no mark".to_string(),
            };
            let blob = d.blob.map_or(none, |b| {
                format!("mark at ({:.1}, {:.1}), {} px, box {:?}", b.centroid[0], b.centroid[1], b.area, b.box_xyxy)
            });
            let reach = match (d.confirmed, d.reach) {
                (true, Some(r)) => format!("; REACH {:?}", r.map(|v| (v * 1000.0).round() / 1000.0)),
                _ => String::new(),
            };
            format!("frame {}: head ({:.3}, {:.3}) rad, {blob}{reach}", d.frame, d.head[0], d.head[1])
        }
        BoardToHost::Error { code, detail } => format!("error {code:?} (detail {detail})"),
        BoardToHost::Status(s) => format!(
            "status: {:?}, model crc {:08x}, {} frames, {} detections, {} reaches, host link {} CRC errors / {} resyncs, \
             servo bus {} CRC errors / {} resyncs, watchdog trips face {} servo {}, clamped targets {}, \
             frames refused NoFace {} SceneChanged {}; {}",
            s.mode,
            s.model_crc,
            s.frames,
            s.detections,
            s.reaches,
            s.host_link.crc_errors,
            s.host_link.resyncs(),
            s.servo_link.crc_errors,
            s.servo_link.resyncs(),
            s.face_watchdog_trips,
            s.servo_watchdog_trips,
            s.clamped_targets,
            s.no_face,
            s.scene_changed,
            describe_room(&s.room)
        ),
        BoardToHost::ModelAccepted { crc32 } => format!("model accepted, crc {crc32:08x}"),
        BoardToHost::Pong { nonce } => format!("pong {nonce}"),
        BoardToHost::ServoBus(r) => format!("servo bus: {r:?}"),
        BoardToHost::HeadAt { head } => format!(
            "head settled at yaw {:.3} deg, pitch {:.3} deg",
            head[0].to_degrees(),
            head[1].to_degrees()
        ),
        BoardToHost::FrameAck(a) => format!("frame {} round {}: {:?}", a.frame, a.round, a.state),
        BoardToHost::UploadAck { next } => format!("upload: the board wants byte {next} next"),
        BoardToHost::Store(r) => describe_store(r),
        BoardToHost::SelfGate(g) => format!(
            "self gate at frame {}: {:?}, gain ratio {:.3}, rest {:.2} px, hold {:.2} px, level {:.2} px, line {:.2} px, {} frames unlike the prediction, frames {:?}, {} ms",
            g.frame, g.decision, g.gain_ratio, g.rest_px, g.hold_px, g.level_px, g.line_px, g.unlike, g.frames, g.elapsed_ms
        ),
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
    }
}
