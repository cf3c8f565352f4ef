//! Dynamixel Protocol 2.0 on the wire, as the ROBOTIS e-Manual defines it: the packet encoder
//! ([`Writer`] and the per-instruction builders), a checked parser ([`parse`], [`Receiver`]) and
//! views of what a packet says ([`Status`], [`Instruction`]).
//!
//! A packet is `FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAM.. | CRC_L CRC_H`, where LEN counts
//! the bytes after itself (instruction, parameters, CRC) and the CRC is CRC-16 with polynomial
//! 0x8005 (init 0, unreflected: CRC-16/UMTS) over everything before it. Between the instruction
//! and the CRC, every `FF FF FD` is followed by a stuffed `FD`, so that no header can appear
//! inside a packet; LEN and CRC cover the stuffed bytes. A status packet has instruction `0x55`
//! and an error byte before its parameters.
//!
//! No heap: encoding writes into a caller's slice, parsing unstuffs in place.

use crc::Crc;

pub mod map;
pub mod table;

/// The four header bytes (the fourth is the reserved `0x00`).
pub const HEADER: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];
/// Header, ID and the two length bytes.
pub const PREFIX_LEN: usize = 7;
/// Header, ID, length, instruction and CRC: the smallest packet (a Ping) is this long.
pub const MIN_PACKET: usize = 10;
/// The ID every device obeys; only Ping, Sync Read and Sync Write are answered or sent to it.
pub const BROADCAST: u8 = 0xFE;
/// Highest ID a device may have.
pub const MAX_ID: u8 = 0xFC;

/// CRC-16 of Protocol 2.0: polynomial 0x8005, initial value 0, no reflection, no final XOR.
pub const CRC16: Crc<u16> = Crc::<u16>::new(&crc::CRC_16_UMTS);

/// Instruction codes used here.
pub mod inst {
    /// Ping (0x01): the device answers its model number (2 bytes) and firmware version.
    pub const PING: u8 = 0x01;
    /// Read (0x02): address (2) and length (2); the status carries the bytes read.
    pub const READ: u8 = 0x02;
    /// Write (0x03): address (2) and data; answered by an empty status.
    pub const WRITE: u8 = 0x03;
    /// Status (0x55): a device's answer, error byte first.
    pub const STATUS: u8 = 0x55;
    /// Sync Read (0x82), to the broadcast ID: address, length and IDs; each device answers in the listed order.
    pub const SYNC_READ: u8 = 0x82;
    /// Sync Write (0x83), to the broadcast ID: address, length, then `(id, data)` per device; no answers.
    pub const SYNC_WRITE: u8 = 0x83;
}

/// The status packet's error byte: bit 7 is the Alert (look at Hardware Error Status), bits 0-6
/// the error number of the instruction's processing.
pub mod error {
    /// Bit 7: the device has an error in Hardware Error Status (see [`table::hw`](crate::dynamixel::table::hw)).
    pub const ALERT: u8 = 0x80;
    /// Result Fail (1): the device failed to process the instruction.
    pub const RESULT_FAIL: u8 = 0x01;
    /// Instruction Error (2): an undefined instruction, or Action without Reg Write.
    pub const INSTRUCTION: u8 = 0x02;
    /// CRC Error (3): the instruction packet's CRC did not match.
    pub const CRC: u8 = 0x03;
    /// Data Range Error (4): the value is outside the item's minimum/maximum.
    pub const DATA_RANGE: u8 = 0x04;
    /// Data Length Error (5): the data is shorter than the item.
    pub const DATA_LENGTH: u8 = 0x05;
    /// Data Limit Error (6): the value is outside the item's limits.
    pub const DATA_LIMIT: u8 = 0x06;
    /// Access Error (7): writing a read-only or undefined item, or EEPROM with torque on; reading a write-only one.
    pub const ACCESS: u8 = 0x07;
}

/// Why a packet could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EncodeError {
    /// The output slice is too small for the stuffed packet.
    TooLong,
    /// An ID above [`MAX_ID`] that is not [`BROADCAST`], or a Sync entry whose data is not the
    /// announced length.
    Invalid,
}

/// Builds one packet into a caller's buffer, stuffing as it goes.
pub struct Writer<'a> {
    buf: &'a mut [u8],
    len: usize,
    /// `FF` bytes just written in the stuffed region (0, 1 or 2+).
    ff_run: u8,
    overflow: bool,
}

impl<'a> Writer<'a> {
    /// Starts a packet for `id` with `instruction`.
    pub fn new(buf: &'a mut [u8], id: u8, instruction: u8) -> Result<Self, EncodeError> {
        if id > MAX_ID && id != BROADCAST {
            return Err(EncodeError::Invalid);
        }
        if buf.len() < MIN_PACKET {
            return Err(EncodeError::TooLong);
        }
        buf[..4].copy_from_slice(&HEADER);
        buf[4] = id;
        let mut w = Writer { buf, len: PREFIX_LEN, ff_run: 0, overflow: false };
        w.byte(instruction);
        Ok(w)
    }

    /// Appends one byte of the instruction's parameters (or a status's error byte).
    pub fn byte(&mut self, b: u8) {
        self.raw(b);
        if b == 0xFD && self.ff_run >= 2 {
            self.raw(0xFD);
            self.ff_run = 0;
        } else if b == 0xFF {
            self.ff_run = self.ff_run.saturating_add(1);
        } else {
            self.ff_run = 0;
        }
    }

    /// Appends bytes, stuffing as needed.
    pub fn bytes(&mut self, bs: &[u8]) {
        for &b in bs {
            self.byte(b);
        }
    }

    /// Appends a little-endian `u16`.
    pub fn u16(&mut self, v: u16) {
        self.bytes(&v.to_le_bytes());
    }

    /// Appends a little-endian `u32`.
    pub fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }

    fn raw(&mut self, b: u8) {
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = b;
                self.len += 1;
            }
            None => self.overflow = true,
        }
    }

    /// Writes the length and the CRC; returns the packet's length in the buffer.
    pub fn finish(self) -> Result<usize, EncodeError> {
        let n = self.len + 2;
        if self.overflow || n > self.buf.len() || n - PREFIX_LEN > u16::MAX as usize {
            return Err(EncodeError::TooLong);
        }
        let len = (n - PREFIX_LEN) as u16;
        self.buf[5..7].copy_from_slice(&len.to_le_bytes());
        let crc = CRC16.checksum(&self.buf[..self.len]);
        self.buf[self.len..n].copy_from_slice(&crc.to_le_bytes());
        Ok(n)
    }
}

/// Ping `id` (or everyone, with [`BROADCAST`]).
pub fn ping(id: u8, buf: &mut [u8]) -> Result<usize, EncodeError> {
    Writer::new(buf, id, inst::PING)?.finish()
}

/// Read `len` bytes at `addr` of `id`'s control table.
pub fn read(id: u8, addr: u16, len: u16, buf: &mut [u8]) -> Result<usize, EncodeError> {
    let mut w = Writer::new(buf, id, inst::READ)?;
    w.u16(addr);
    w.u16(len);
    w.finish()
}

/// Write `data` at `addr` of `id`'s control table.
pub fn write(id: u8, addr: u16, data: &[u8], buf: &mut [u8]) -> Result<usize, EncodeError> {
    let mut w = Writer::new(buf, id, inst::WRITE)?;
    w.u16(addr);
    w.bytes(data);
    w.finish()
}

/// Read `len` bytes at `addr` from each of `ids`, which answer in that order.
pub fn sync_read(addr: u16, len: u16, ids: &[u8], buf: &mut [u8]) -> Result<usize, EncodeError> {
    if ids.iter().any(|&id| id > MAX_ID) {
        return Err(EncodeError::Invalid);
    }
    let mut w = Writer::new(buf, BROADCAST, inst::SYNC_READ)?;
    w.u16(addr);
    w.u16(len);
    w.bytes(ids);
    w.finish()
}

/// Write, to each `(id, data)`, `data` (exactly `len` bytes) at `addr`. No device answers.
pub fn sync_write<'d, I>(addr: u16, len: u16, entries: I, buf: &mut [u8]) -> Result<usize, EncodeError>
where
    I: IntoIterator<Item = (u8, &'d [u8])>,
{
    let mut w = Writer::new(buf, BROADCAST, inst::SYNC_WRITE)?;
    w.u16(addr);
    w.u16(len);
    for (id, data) in entries {
        if id > MAX_ID || data.len() != len as usize {
            return Err(EncodeError::Invalid);
        }
        w.byte(id);
        w.bytes(data);
    }
    w.finish()
}

/// A status packet from `id` with `error` and `params` (what a device sends).
pub fn status(id: u8, error: u8, params: &[u8], buf: &mut [u8]) -> Result<usize, EncodeError> {
    if id > MAX_ID {
        return Err(EncodeError::Invalid);
    }
    let mut w = Writer::new(buf, id, inst::STATUS)?;
    w.byte(error);
    w.bytes(params);
    w.finish()
}

/// Why bytes that start like a packet are not one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PacketError {
    /// ID 0xFD or 0xFF.
    BadId,
    /// LEN below 3 (instruction and CRC), or a status without its error byte.
    BadLength,
    /// Longer than the receiver can hold.
    Oversized,
    /// The CRC does not match.
    Crc,
    /// `FF FF FD` inside the packet without its stuffed `FD`: a sender that does not stuff.
    BadStuffing,
}

/// One checked packet, unstuffed: `params` holds a status's error byte first.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Packet<'a> {
    /// The device ID: the sender's for a status, the addressee's for an instruction.
    pub id: u8,
    /// Instruction code (see [`inst`]); 0x55 for a status.
    pub instruction: u8,
    /// Parameters, unstuffed (a status: error byte first).
    pub params: &'a [u8],
}

/// What [`parse`] found at the start of a buffer.
#[derive(Debug, PartialEq, Eq)]
pub enum Parsed<'a> {
    /// A packet; it took `used` bytes of the buffer (which now hold its unstuffed form).
    /// `packet` borrows the buffer; `used` is its length on the wire, stuffing included.
    #[allow(missing_docs)]
    Packet { packet: Packet<'a>, used: usize },
    /// The buffer starts with a packet that has not fully arrived yet.
    Incomplete,
    /// Drop `skip` bytes: noise before a header (`error: None`) or a broken packet's first byte
    /// (a header may start inside it).
    /// `skip`: bytes to drop; `error`: why, `None` for noise.
    #[allow(missing_docs)]
    Skip { skip: usize, error: Option<PacketError> },
}

/// Parses the packet at the start of `buf` (at most `max` bytes long), unstuffing it in place.
/// Never panics, whatever the bytes.
pub fn parse(buf: &mut [u8], max: usize) -> Parsed<'_> {
    if buf.is_empty() {
        return Parsed::Incomplete;
    }
    // Noise: skip to the next byte that could start a header.
    if buf[0] != HEADER[0] {
        let skip = buf.iter().position(|&b| b == HEADER[0]).unwrap_or(buf.len());
        return Parsed::Skip { skip, error: None };
    }
    for (i, &b) in buf.iter().enumerate().take(HEADER.len()) {
        if b != HEADER[i] {
            return Parsed::Skip { skip: 1, error: None };
        }
    }
    if buf.len() < PREFIX_LEN {
        return Parsed::Incomplete;
    }
    let id = buf[4];
    if id == 0xFD || id == 0xFF {
        return Parsed::Skip { skip: 1, error: Some(PacketError::BadId) };
    }
    let len = u16::from_le_bytes([buf[5], buf[6]]) as usize;
    if len < 3 {
        return Parsed::Skip { skip: 1, error: Some(PacketError::BadLength) };
    }
    let total = PREFIX_LEN + len;
    if total > max {
        return Parsed::Skip { skip: 1, error: Some(PacketError::Oversized) };
    }
    if buf.len() < total {
        return Parsed::Incomplete;
    }
    let body_end = total - 2;
    let crc = u16::from_le_bytes([buf[body_end], buf[body_end + 1]]);
    if CRC16.checksum(&buf[..body_end]) != crc {
        return Parsed::Skip { skip: 1, error: Some(PacketError::Crc) };
    }
    // Unstuff instruction and parameters in place (the output never overtakes the input).
    let (mut out, mut i, mut ff_run) = (PREFIX_LEN, PREFIX_LEN, 0u8);
    while i < body_end {
        let b = buf[i];
        buf[out] = b;
        out += 1;
        i += 1;
        if b == 0xFD && ff_run >= 2 {
            if i >= body_end || buf[i] != 0xFD {
                return Parsed::Skip { skip: 1, error: Some(PacketError::BadStuffing) };
            }
            i += 1;
            ff_run = 0;
        } else if b == 0xFF {
            ff_run = ff_run.saturating_add(1);
        } else {
            ff_run = 0;
        }
    }
    let instruction = buf[PREFIX_LEN];
    if instruction == inst::STATUS && out < PREFIX_LEN + 2 {
        return Parsed::Skip { skip: 1, error: Some(PacketError::BadLength) };
    }
    Parsed::Packet {
        packet: Packet { id, instruction, params: &buf[PREFIX_LEN + 1..out] },
        used: total,
    }
}

/// What a [`Receiver`] has thrown away, by cause.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RxCounters {
    /// Packets that passed every check.
    pub packets: u32,
    /// Bytes dropped before a header (line noise, or a broken packet's rest).
    pub noise_bytes: u32,
    /// Packets with ID 0xFD or 0xFF.
    pub bad_id: u32,
    /// Packets whose LEN is too short.
    pub bad_length: u32,
    /// Packets longer than the receiver's `N` bytes.
    pub oversized: u32,
    /// Packets whose CRC did not match.
    pub crc_errors: u32,
    /// Packets with `FF FF FD` not followed by a stuffed `FD`.
    pub bad_stuffing: u32,
    /// Bytes that arrived while the buffer was full (lost).
    pub overruns: u32,
}

impl RxCounters {
    /// Packets refused for any reason (noise not counted).
    pub fn errors(&self) -> u32 {
        self.bad_id + self.bad_length + self.oversized + self.crc_errors + self.bad_stuffing
    }

    fn count(&mut self, e: PacketError) {
        let c = match e {
            PacketError::BadId => &mut self.bad_id,
            PacketError::BadLength => &mut self.bad_length,
            PacketError::Oversized => &mut self.oversized,
            PacketError::Crc => &mut self.crc_errors,
            PacketError::BadStuffing => &mut self.bad_stuffing,
        };
        *c = c.saturating_add(1);
    }
}

/// A resynchronising receiver with room for one packet of up to `N` bytes: push bytes, then
/// take packets with [`Receiver::next_packet`] until it returns `None`.
pub struct Receiver<const N: usize> {
    buf: [u8; N],
    len: usize,
    /// Bytes of the packet last returned, dropped on the next call.
    consumed: usize,
    counters: RxCounters,
}

impl<const N: usize> Default for Receiver<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Receiver<N> {
    /// An empty receiver with zeroed counters; `const`, so it can live in a `static`.
    pub const fn new() -> Self {
        Receiver { buf: [0; N], len: 0, consumed: 0, counters: RxCounters {
            packets: 0, noise_bytes: 0, bad_id: 0, bad_length: 0, oversized: 0, crc_errors: 0,
            bad_stuffing: 0, overruns: 0,
        } }
    }

    /// What has been received and dropped so far.
    pub fn counters(&self) -> &RxCounters {
        &self.counters
    }

    /// Forgets everything buffered (a new transaction starts on a quiet line).
    pub fn clear(&mut self) {
        self.len = 0;
        self.consumed = 0;
    }

    /// Bytes waiting (part of a packet, or not yet looked at).
    pub fn buffered(&self) -> usize {
        self.len - self.consumed
    }

    /// Adds one received byte. Call [`Receiver::next_packet`] until `None` after each push, so that
    /// the buffer never holds more than one partial packet.
    pub fn push(&mut self, b: u8) {
        self.drop_consumed();
        if self.len < N {
            self.buf[self.len] = b;
            self.len += 1;
        } else {
            self.counters.overruns = self.counters.overruns.saturating_add(1);
        }
    }

    fn drop_consumed(&mut self) {
        if self.consumed > 0 {
            self.buf.copy_within(self.consumed..self.len, 0);
            self.len -= self.consumed;
            self.consumed = 0;
        }
    }

    /// The next complete packet, or `None` when more bytes are needed.
    pub fn next_packet(&mut self) -> Option<Packet<'_>> {
        self.drop_consumed();
        loop {
            // `parse` borrows the buffer mutably; decide with its result's lengths first.
            let step = match parse(&mut self.buf[..self.len], N) {
                Parsed::Incomplete => return None,
                Parsed::Packet { packet, used } => Ok((used, PREFIX_LEN + 1 + packet.params.len())),
                Parsed::Skip { skip, error } => Err((skip, error)),
            };
            match step {
                Ok((used, end)) => {
                    self.consumed = used;
                    self.counters.packets = self.counters.packets.saturating_add(1);
                    // Unstuffed in place by `parse`: the parameters end at `end`.
                    let b = &self.buf;
                    return Some(Packet { id: b[4], instruction: b[PREFIX_LEN], params: &b[PREFIX_LEN + 1..end] });
                }
                Err((skip, error)) => {
                    match error {
                        Some(e) => self.counters.count(e),
                        None => {
                            self.counters.noise_bytes =
                                self.counters.noise_bytes.saturating_add(skip as u32)
                        }
                    }
                    self.buf.copy_within(skip..self.len, 0);
                    self.len -= skip;
                }
            }
        }
    }
}

/// A status packet's content.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Status<'a> {
    /// The answering device's ID.
    pub id: u8,
    /// The error byte: [`error::ALERT`] and an error number.
    pub error: u8,
    /// The parameters after the error byte (e.g. the bytes a Read asked for).
    pub params: &'a [u8],
}

impl<'a> Status<'a> {
    /// The packet as a status, if it is one.
    pub fn of(p: &Packet<'a>) -> Option<Status<'a>> {
        if p.instruction != inst::STATUS {
            return None;
        }
        let (&error, params) = p.params.split_first()?;
        Some(Status { id: p.id, error, params })
    }

    /// The device's Hardware Error Status has something set.
    pub fn alert(&self) -> bool {
        self.error & error::ALERT != 0
    }

    /// The instruction's processing error (0: none).
    pub fn error_number(&self) -> u8 {
        self.error & !error::ALERT
    }

    /// The parameters as one little-endian value of exactly `n` bytes (1, 2 or 4).
    pub fn value(&self, n: usize) -> Option<u32> {
        if self.params.len() != n || !matches!(n, 1 | 2 | 4) {
            return None;
        }
        let mut v = [0u8; 4];
        v[..n].copy_from_slice(self.params);
        Some(u32::from_le_bytes(v))
    }
}

/// An instruction packet's content (what a device receives).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Instruction<'a> {
    /// Ping: is anyone there with this ID (or, broadcast, anyone at all)?
    Ping,
    /// Read `len` bytes of the control table from `addr`.
    #[allow(missing_docs)]
    Read { addr: u16, len: u16 },
    /// Write `data` to the control table from `addr`.
    #[allow(missing_docs)]
    Write { addr: u16, data: &'a [u8] },
    /// Read `len` bytes from `addr` of each device in `ids`; they answer in that order.
    #[allow(missing_docs)]
    SyncRead { addr: u16, len: u16, ids: &'a [u8] },
    /// `data` holds `(id, len bytes)` entries back to back; see [`Instruction::sync_entries`].
    /// Each listed device gets its `len` bytes written at `addr`; none answers.
    #[allow(missing_docs)]
    SyncWrite { addr: u16, len: u16, data: &'a [u8] },
    /// A status (0x55): not an instruction; e.g. another device's reply, or the echo of a
    /// half-duplex line.
    Status,
    /// Any other code, or parameters that do not fit the instruction.
    Other(u8),
}

impl<'a> Instruction<'a> {
    /// Decodes an instruction packet; malformed parameters give [`Instruction::Other`].
    pub fn of(p: &Packet<'a>) -> Instruction<'a> {
        let q = p.params;
        let u16_at = |i: usize| u16::from_le_bytes([q[i], q[i + 1]]);
        match p.instruction {
            inst::PING if q.is_empty() => Instruction::Ping,
            inst::READ if q.len() == 4 => Instruction::Read { addr: u16_at(0), len: u16_at(2) },
            inst::WRITE if q.len() >= 3 => Instruction::Write { addr: u16_at(0), data: &q[2..] },
            inst::SYNC_READ if q.len() >= 5 => {
                Instruction::SyncRead { addr: u16_at(0), len: u16_at(2), ids: &q[4..] }
            }
            inst::SYNC_WRITE if q.len() >= 4 => {
                let len = u16_at(2);
                let data = &q[4..];
                let entry = len as usize + 1;
                if len == 0 || data.is_empty() || !data.len().is_multiple_of(entry) {
                    Instruction::Other(p.instruction)
                } else {
                    Instruction::SyncWrite { addr: u16_at(0), len, data }
                }
            }
            inst::STATUS => Instruction::Status,
            code => Instruction::Other(code),
        }
    }

    /// A Sync Write's `(id, data)` entries (empty for anything else).
    pub fn sync_entries(&self) -> impl Iterator<Item = (u8, &'a [u8])> {
        let (len, data): (usize, &'a [u8]) = match *self {
            Instruction::SyncWrite { len, data, .. } => (len as usize, data),
            _ => (0, &[]),
        };
        data.chunks_exact(len + 1).map(|c| (c[0], &c[1..]))
    }
}

/// Bytes on the wire for a packet with `params` parameter bytes before stuffing (a status
/// counts its error byte as one): header, ID, length, instruction, parameters, CRC.
pub const fn packet_len(params: usize) -> usize {
    MIN_PACKET + params
}

#[cfg(test)]
mod tests;
