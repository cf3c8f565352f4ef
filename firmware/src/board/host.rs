//! What the board does with each message from the host: settings, uploads, the store, the room.

use super::Core;
use crate::confirm::Confirm;
use crate::dynamixel::Master;
use crate::link::{Assembly, Progress};
use crate::model::{ModelStore, UploadError};
use crate::pipeline::Workspace;
use crate::saliency::Settings;
use embedded_io::Write;
use msr_shared::blob::Merge;
use msr_shared::msg::{
    BoardToHost, Config, ErrorCode, FrameAck, FrameState, HostToBoard, ModelSource, RoomCommand,
    ServoBusKind, StoreReport,
};

impl<S: ModelStore> Core<S> {
    pub(super) fn on_host<H: Write>(
        &mut self,
        now_us: u64,
        msg: HostToBoard,
        ws: &mut Workspace,
        frame: &mut Assembly,
        host: &mut H,
    ) {
        let chooses_nothing = matches!(
            msg,
            HostToBoard::Ping { .. }
                | HostToBoard::GetStatus
                | HostToBoard::GetServoBus
                | HostToBoard::GetStore
                | HostToBoard::UseServoBus(_)
                | HostToBoard::SetServoMap(_)
        );
        if !self.bus_known && !chooses_nothing {
            // A host that does not choose: the framed bus, as before the choice existed.
            self.bus_known = true;
        }
        match msg {
            HostToBoard::Ping { nonce } => {
                self.host_tx.send(host, &BoardToHost::Pong { nonce });
            }
            // Answered by `poll` once the message no longer borrows the receiver's counters.
            HostToBoard::GetStatus => self.status_pending = true,
            HostToBoard::FrameStart(h) => match self.loaded {
                None => self.error(host, ErrorCode::NoModel, 0),
                Some(l) => {
                    if frame.start(h, l.face_w, l.face_h).is_err() {
                        self.error(host, ErrorCode::BadFrame, h.frame as u32);
                    }
                }
            },
            HostToBoard::FrameChunk {
                frame: id,
                offset,
                data,
            } => match frame.chunk(id, offset, data) {
                Ok(Progress::Quiet) => {}
                Ok(Progress::Ack(a)) => self.ack(host, a),
                Ok(Progress::Complete(h)) => {
                    self.ack(host, FrameAck { frame: h.frame, round: 0, state: FrameState::Complete });
                    self.on_frame(now_us, h, frame.pixels(&h), ws, host)
                }
                Err(_) => self.error(host, ErrorCode::BadFrame, id as u32),
            },
            HostToBoard::FramePoll { header, round } => match self.loaded {
                None => self.error(host, ErrorCode::NoModel, 0),
                Some(l) => match frame.poll(header, round, l.face_w, l.face_h) {
                    Ok(a) => self.ack(host, a),
                    Err(_) => self.error(host, ErrorCode::BadFrame, header.frame as u32),
                },
            },
            HostToBoard::ModelBegin { len, crc32 } => match self.upload.begin(&mut self.store, len, crc32) {
                // The slot is being erased: the ack (and so the chunks) wait for it.
                Ok(_) if self.store.busy() => self.upload_ack_due = true,
                Ok(next) => self.upload_ack(host, next),
                Err(e) => self.error(host, ErrorCode::BadUpload, e.detail()),
            },
            // Chunks before the ack, or while the flash is busy: dropped (the host sends them
            // again from where the board says it stands).
            HostToBoard::ModelChunk { .. } if self.upload_ack_due || self.store.busy() => {}
            HostToBoard::ModelChunk { offset, data } => {
                match self.upload.chunk(&mut self.store, offset, data) {
                    Ok(None) => {}
                    Ok(Some(next)) => self.upload_ack(host, next),
                    Err(e) => self.error(host, ErrorCode::BadUpload, e.detail()),
                }
            }
            // The commit record waits for flash work in progress (a log compaction).
            HostToBoard::ModelCommit if self.store.busy() => self.commit_due = true,
            HostToBoard::ModelCommit => self.commit_upload(ws, frame, host),
            HostToBoard::Configure(c) => {
                if !self.configure(&c) {
                    self.error(host, ErrorCode::BadConfig, 0);
                }
            }
            HostToBoard::UseServoBus(kind) => {
                self.dxl = match kind {
                    ServoBusKind::Framed => None,
                    ServoBusKind::Dynamixel => Some(Master::new()),
                };
                self.bus_known = true;
                self.dxl_stopped = false;
            }
            HostToBoard::SetServoMap(map) => {
                self.bus_known = true;
                let m = self.dxl.get_or_insert_with(Master::new);
                if let Err(e) = m.set_map(map) {
                    let at = map.iter().position(|j| Some(j.joint) == map_error_joint(e));
                    self.error(host, ErrorCode::BadServoMap, at.map_or(u32::MAX, |i| i as u32));
                }
            }
            HostToBoard::GetServoBus => {
                let r = self.servo_bus_report();
                self.host_tx.send(host, &BoardToHost::ServoBus(r));
            }
            HostToBoard::MoveHead { yaw, pitch } => self.move_head(now_us, [yaw, pitch], host),
            HostToBoard::GetStore => self.store_report(now_us, host),
            HostToBoard::ResetStats => {
                ws.room.reset();
                self.room = ws.room.report(self.room_applies());
                let crc = self.loaded.map_or(0, |l| l.crc);
                if !self.store.reset_stats(crc) {
                    self.error(host, ErrorCode::StoreBusy, 0);
                }
                self.store_report(now_us, host);
            }
            HostToBoard::Room(cmd) => {
                match cmd {
                    RoomCommand::Freeze => ws.room.freeze(true),
                    RoomCommand::Resume => ws.room.freeze(false),
                    RoomCommand::Reset => {
                        ws.room.reset();
                        let crc = self.loaded.map_or(0, |l| l.crc);
                        if self.store.saved_stats(crc).is_some() && !self.store.reset_stats(crc) {
                            self.error(host, ErrorCode::StoreBusy, 0);
                        }
                    }
                    RoomCommand::Save => {
                        if !self.save_room(ws, now_us / 1000) {
                            self.error(host, ErrorCode::StoreBusy, 0);
                        }
                        self.store_report(now_us, host);
                        return;
                    }
                }
                self.room = ws.room.report(self.room_applies());
                self.status_pending = true;
            }
        }
    }

    pub(super) fn commit_upload<H: Write>(&mut self, ws: &mut Workspace, frame: &mut Assembly, host: &mut H) {
        self.commit_due = false;
        match self.upload.commit(&mut self.store) {
            Ok(crc) => {
                frame.clear();
                // Just validated whole: its CRC need not be read again (a pass over the blob
                // would stretch this poll, and so the control period).
                self.load_active(ws, true);
                self.host_tx.send(host, &BoardToHost::ModelAccepted { crc32: crc });
            }
            Err(UploadError::Incomplete { next }) => self.upload_ack(host, next),
            Err(e @ UploadError::Invalid(_)) => self.error(host, ErrorCode::BadModel, e.detail()),
            Err(e) => self.error(host, ErrorCode::BadUpload, e.detail()),
        }
    }

    pub(super) fn store_report<H: Write>(&mut self, now_us: u64, host: &mut H) {
        let crc = self.loaded.map_or(0, |l| l.crc);
        let r = StoreReport {
            model_crc: crc,
            source: if self.loaded.is_some() { self.store.source() } else { ModelSource::None },
            stats: self.loaded.and_then(|l| self.store.stats_age(l.crc)),
            now_ms: now_us / 1000,
            busy: self.store.busy(),
            capacity: self.store.capacity().min(u32::MAX as usize) as u32,
        };
        self.host_tx.send(host, &BoardToHost::Store(r));
    }

    pub(super) fn ack<H: Write>(&mut self, host: &mut H, a: FrameAck) {
        self.host_tx.send(host, &BoardToHost::FrameAck(a));
    }

    pub(super) fn upload_ack<H: Write>(&mut self, host: &mut H, next: u32) {
        self.host_tx.send(host, &BoardToHost::UploadAck { next });
    }

    /// Applies a configuration, all or nothing.
    pub(super) fn configure(&mut self, c: &Config) -> bool {
        let s = Settings {
            threshold: c.threshold,
            normalisation: c.normalisation,
            sided: c.sided,
            min_area: c.min_area,
            // The merge is the model's: the host link does not carry one.
            merge: self.settings.map_or(Merge::OFF, |s| s.merge),
        };
        let Some(confirm) = Confirm::new(c.confirm_k, c.confirm_n) else {
            return false;
        };
        let mut motion = self.motion;
        if !s.is_valid()
            || !motion.set_speed_fraction(c.speed_fraction)
            || !motion.set_hold_ms(c.hold_ms)
        {
            return false;
        }
        self.motion = motion;
        self.confirm = confirm;
        if self.loaded.is_some() {
            self.settings = Some(s);
        }
        true
    }
}

/// The joint a map error names.
fn map_error_joint(e: msr_shared::dynamixel::map::MapError) -> Option<msr_shared::joints::Joint> {
    use msr_shared::dynamixel::map::MapError::*;
    match e {
        BadId { joint } | BadJoint { joint } | BadScale { joint } | BadRawLimits { joint }
        | LeavesLimits { joint } | TargetOutOfRange { joint } | RawOutOfRange { joint, .. } => {
            Some(joint)
        }
    }
}
