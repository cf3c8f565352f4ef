//! The board image for QEMU's mps2-an386: the firmware library's [`Board`] on UART0 (host link)
//! and UART1 (servo bus).
//!
//! Two clocks, chosen by the host:
//! - **free running** (from reset): SysTick is the board's microsecond clock, as on a real board.
//!   Under `-icount shift=0` that is QEMU's virtual time; the image sleeps (`wfi`) when it has
//!   nothing to do, so virtual time follows real time while idle (see [`uart::idle`]).
//! - **lockstep** (after a reset asked for with `R tick` on UART2, see [`ctl`]): the simulation
//!   drives the clock. Its commands then come through the host's pipe ([`msr_qemu::pipe`]),
//!   not UART2. Each `T` command is one tick and carries the bytes that reached UART0 and UART1
//!   during it; the image runs one `Board::poll` at the tick's time and answers on UART2 with how
//!   many bytes the board wrote on each UART. The simulated world and the board then share one
//!   time base whatever the host's load, exactly as the in-process firmware does.
//!
//! The servo bus is the host's choice (`UseServoBus`; see `Board::await_servo_bus`): the image
//! says nothing on UART1 until then, and a host that starts without choosing gets the framed bus.
//!
//! The model is the built-in one (`MSR_MODEL_BLOB` at build time), whatever the host uploads
//! (`ModelBegin` / `ModelChunk` / `ModelCommit`) into the store's two flash slots, or the one
//! committed there before a reset (`R` on UART2). A model preloaded into PSRAM with QEMU's generic loader
//! ([`model_area::take_preload`]) goes into the slots at a start that finds them empty, checked
//! as an upload is. Given a host file (`msr-qemu flash=PATH` on the semihosting command line,
//! [`msr_qemu::flash_file`]), the flash is that file, read at start and written through.
//!
//! For tests, [`EXIT_SEQUENCE`] on UART0 (or `X` on UART2) ends the run: the image prints its
//! status, stack peak and sizes on the semihosting console and exits with code 0. The sequence
//! cannot occur inside a COBS frame (it holds zeros) and is not a valid frame, so no real
//! traffic triggers it.
#![no_std]
#![no_main]

use cortex_m_rt::{entry, exception};
use cortex_m_semihosting::hprintln;
use msr_firmware::board::Board;
use msr_firmware::model::{ModelStore, UploadError};
use msr_qemu::clock::{Clock, RELOAD_1MS};
use msr_qemu::exit::exit;
use msr_qemu::memory;
use msr_qemu::model_area::{self, FlashStore};
use msr_qemu::pipe::Pipe;
use msr_qemu::uart::{self, Uart, UART0, UART1, UART2};
use msr_shared::frame::{encode_message, LinkCounters, MAX_WIRE_FRAME};
use msr_shared::msg::{BoardToHost, Mode};

/// Three delimiters, an ASCII word, a delimiter.
pub const EXIT_SEQUENCE: &[u8; 12] = b"\0\0\0MSR-EXIT\0";

/// What the host asked the next start to be (`R`): [`BOOT_MAGIC`] and the lockstep tick. In
/// `.uninit`, which start-up code leaves alone and QEMU's reset does not clear.
#[link_section = ".uninit.msr_boot"]
static mut BOOT_REQUEST: core::mem::MaybeUninit<[u32; 2]> = core::mem::MaybeUninit::uninit();
const BOOT_MAGIC: u32 = 0x4D53_5242; // "MSRB"

/// Takes the boot request: the lockstep tick asked for, if any.
fn boot_request() -> Option<u64> {
    // SAFETY: read and cleared once at start-up, before anything else uses it.
    // Any bit pattern is a valid [u32; 2]; garbage after power-on fails the magic.
    let p = core::ptr::addr_of_mut!(BOOT_REQUEST) as *mut [u32; 2];
    let [magic, tick] = unsafe { core::ptr::read_volatile(p) };
    unsafe { core::ptr::write_volatile(p, [0; 2]) };
    (magic == BOOT_MAGIC && tick > 0).then_some(tick as u64)
}

// SAFETY (model_area::store): the one store of this image.
static mut BOARD: Board<FlashStore> = Board::new(unsafe { model_area::store() });

/// The clock channel. Host to board, on UART2 while the board runs free and through the pipe in
/// lockstep, one opcode byte then little-endian fields:
/// - `T host:u16 servo:u16`, then `host` bytes for UART0 and `servo` bytes for UART1: one tick
///   (lockstep only). Answered `T host:u16 servo:u16` with the bytes the board wrote.
/// - `S`: the board's status, out of band (the links are not touched, so a frame the sim cut off
///   at the end of a trial costs no error): answered `S len:u16` and one framed
///   `BoardToHost::Status` message of `len` bytes.
/// - `R tick_us:u32`: reset the board (the model in the flash slots stays); it comes back with
///   `H`, in lockstep at time 0 with this tick when `tick_us` > 0 (no free-running poll comes
///   first, so a lockstep run starts from the board's power-on state), free running otherwise.
/// - `X`: print the status and exit with code 0.
///
/// Board to host, always on UART2: the answers, and at every start `H crc:u32`, the CRC of the
/// model in use (0: none). A command it cannot take is answered `E code:u8` (1: unknown opcode,
/// 3: a tick while free running, 2: more bytes than fit the receive buffer). A board asked to
/// start in lockstep without a pipe says so and exits with code 4.
mod ctl {
    pub const TICK: u8 = b'T';
    pub const RESET: u8 = b'R';
    pub const EXIT: u8 = b'X';
    pub const STATUS: u8 = b'S';
    pub const HELLO: u8 = b'H';
    pub const ERROR: u8 = b'E';

    /// Bytes after the opcode.
    pub fn args(op: u8) -> Option<usize> {
        match op {
            TICK => Some(4),
            RESET => Some(4),
            EXIT | STATUS => Some(0),
            _ => None,
        }
    }
}

/// Bytes a link may hold between the UART and the board in lockstep: ten times what a 1 ms tick
/// brings at the sim's 921600 baud (92 bytes), small because static RAM is budgeted (64 KiB).
const FIFO: usize = 1024;

/// One UART as the board sees it: read straight from the UART (free running) or from what the
/// ticks brought (lockstep); bytes written are counted for the tick's answer.
struct Port {
    uart: Uart,
    buf: &'static mut [u8; FIFO],
    head: usize,
    len: usize,
    lockstep: bool,
    written: u32,
    /// The last bytes read, newest last (UART0 only: the exit sequence).
    recent: [u8; EXIT_SEQUENCE.len()],
    exit: bool,
}

impl Port {
    fn new(uart: Uart, buf: &'static mut [u8; FIFO]) -> Port {
        Port { uart, buf, head: 0, len: 0, lockstep: false, written: 0, recent: [0xFF; 12], exit: false }
    }

    /// Moves a tick's `n` bytes from the pipe into the buffer. Returns `Some(false)` when they
    /// do not fit (they are read and dropped, so the next command is read whole), `None` when
    /// the pipe ended.
    fn take(&mut self, pipe: &mut Pipe, mut n: usize) -> Option<bool> {
        if n > FIFO - self.len {
            let mut sink = [0u8; 64];
            while n > 0 {
                let k = n.min(sink.len());
                pipe.read_exact(&mut sink[..k]).then_some(())?;
                n -= k;
            }
            return Some(false);
        }
        while n > 0 {
            // The free part after the newest byte, up to the buffer's end.
            let at = (self.head + self.len) % FIFO;
            let k = n.min(FIFO - at);
            pipe.read_exact(&mut self.buf[at..at + k]).then_some(())?;
            self.len += k;
            n -= k;
        }
        Some(true)
    }
}

impl embedded_io::ErrorType for Port {
    type Error = core::convert::Infallible;
}

impl embedded_io::ReadReady for Port {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(if self.lockstep { self.len > 0 } else { self.uart.rx_ready() })
    }
}

impl embedded_io::Read for Port {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = if self.lockstep {
            let n = buf.len().min(self.len);
            for b in &mut buf[..n] {
                *b = self.buf[self.head];
                self.head = (self.head + 1) % FIFO;
            }
            self.len -= n;
            n
        } else {
            embedded_io::Read::read(&mut self.uart, buf)?
        };
        for &b in &buf[..n] {
            self.recent.copy_within(1.., 0);
            self.recent[EXIT_SEQUENCE.len() - 1] = b;
            self.exit |= self.recent == *EXIT_SEQUENCE;
        }
        Ok(n)
    }
}

impl embedded_io::Write for Port {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.written = self.written.wrapping_add(buf.len() as u32);
        embedded_io::Write::write(&mut self.uart, buf)
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// Assembles clock-channel commands from UART2.
struct Ctl {
    uart: Uart,
    cmd: [u8; 5],
    have: usize,
}

impl Ctl {
    /// A complete command, if one has arrived; never waits.
    fn poll(&mut self) -> Option<[u8; 5]> {
        while let Some(b) = self.uart.try_read() {
            self.cmd[self.have] = b;
            self.have += 1;
            match ctl::args(self.cmd[0]) {
                Some(n) if self.have == n + 1 => {
                    self.have = 0;
                    return Some(self.cmd);
                }
                Some(_) => {}
                None => {
                    self.have = 0;
                    self.send(&[ctl::ERROR, 1]);
                }
            }
        }
        None
    }

    /// The next complete command from the pipe, waiting for it; `None` when the pipe ended.
    fn read(&mut self, pipe: &mut Pipe) -> Option<[u8; 5]> {
        let mut cmd = [0u8; 5];
        loop {
            pipe.read_exact(&mut cmd[..1]).then_some(())?;
            match ctl::args(cmd[0]) {
                Some(n) => {
                    pipe.read_exact(&mut cmd[1..1 + n]).then_some(())?;
                    return Some(cmd);
                }
                None => self.send(&[ctl::ERROR, 1]),
            }
        }
    }

    fn send(&mut self, bytes: &[u8]) {
        embedded_io::Write::write_all(&mut self.uart, bytes).ok();
    }
}

fn u16_at(b: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([b[i], b[i + 1]])
}

#[exception]
unsafe fn DefaultHandler(_irqn: i16) {
    // Only the UART RX lines are enabled: acknowledge; the main loop reads the data.
    uart::clear_rx_interrupts();
}

#[entry]
fn main() -> ! {
    memory::paint_stack();
    let cp = cortex_m::Peripherals::take().unwrap_or_else(|| exit(3));
    // A 1 ms SysTick: the sleeping loop wakes for the board's 10 ms motion period.
    let clock = Clock::start_with_reload(cp.SYST, RELOAD_1MS);
    // Static buffers: the stack stays small (its peak is one of the image's figures).
    let host_buf = cortex_m::singleton!(: [u8; FIFO] = [0; FIFO]).unwrap_or_else(|| exit(3));
    let servo_buf = cortex_m::singleton!(: [u8; FIFO] = [0; FIFO]).unwrap_or_else(|| exit(3));
    // SAFETY: this image owns the three UARTs.
    let (mut host, mut servo, mut ctl) = unsafe {
        (
            Port::new(Uart::new(UART0), host_buf),
            Port::new(Uart::new(UART1), servo_buf),
            Ctl { uart: Uart::new(UART2), cmd: [0; 5], have: 0 },
        )
    };
    host.uart.enable_rx_interrupt();
    servo.uart.enable_rx_interrupt();
    ctl.uart.enable_rx_interrupt();
    uart::enable_rx_irqs();
    // SAFETY: the only reference to BOARD, taken once in this single-threaded image.
    let board = unsafe { &mut *core::ptr::addr_of_mut!(BOARD) };
    // Wired to either bus: the host chooses (see `Board::await_servo_bus`), so a Dynamixel
    // bus never carries a framed byte.
    board.await_servo_bus();
    // The host's flash file, when it gave one, is the flash from here on.
    report_flash_file(model_area::attach_flash_file());
    // The store finds its committed model (if any) before anything asks for it.
    board.store_mut().start();
    report_preload(model_area::take_preload(board.store_mut()));
    // Lockstep state: the next tick's time and the tick length, and the pipe its commands come
    // through (a start that cannot have one ends before it says hello).
    let mut lockstep: Option<(u64, u64)> = boot_request().map(|tick| (0, tick));
    let mut pipe = lockstep.map(|_| Pipe::open().unwrap_or_else(|| no_pipe()));
    let crc = announce(board);
    let mut hello = [ctl::HELLO, 0, 0, 0, 0];
    hello[1..].copy_from_slice(&crc.to_le_bytes());
    ctl.send(&hello);

    host.lockstep = lockstep.is_some();
    servo.lockstep = lockstep.is_some();
    loop {
        if lockstep.is_none() {
            // 25 SysTick ticks of 40 ns per microsecond.
            let now_us = clock.ticks() / 25;
            poll(board, now_us, &mut host, &mut servo);
        }
        if host.exit {
            finish(board, "exit sequence on UART0");
        }
        let cmd = match pipe.as_mut() {
            Some(p) => ctl.read(p).unwrap_or_else(|| finish(board, "the lockstep pipe ended")),
            None => match ctl.poll() {
                Some(cmd) => cmd,
                None => {
                    let (h, s, c) = (&host.uart, &servo.uart, &ctl.uart);
                    uart::idle(|| h.rx_ready() || s.rx_ready() || c.rx_ready());
                    continue;
                }
            },
        };
        match cmd[0] {
            ctl::TICK => {
                let (Some((now_us, tick)), Some(p)) = (lockstep, pipe.as_mut()) else {
                    ctl.send(&[ctl::ERROR, 3]);
                    continue;
                };
                let (fit_host, fit_servo) = (host.take(p, u16_at(&cmd, 1) as usize), servo.take(p, u16_at(&cmd, 3) as usize));
                let (Some(fit_host), Some(fit_servo)) = (fit_host, fit_servo) else {
                    finish(board, "the lockstep pipe ended");
                };
                if !(fit_host && fit_servo) {
                    ctl.send(&[ctl::ERROR, 2]);
                    continue;
                }
                host.written = 0;
                servo.written = 0;
                poll(board, now_us, &mut host, &mut servo);
                lockstep = Some((now_us + tick, tick));
                let (h, s) = (host.written.min(u16::MAX as u32) as u16, servo.written.min(u16::MAX as u32) as u16);
                let mut a = [ctl::TICK, 0, 0, 0, 0];
                a[1..3].copy_from_slice(&h.to_le_bytes());
                a[3..5].copy_from_slice(&s.to_le_bytes());
                ctl.send(&a);
            }
            ctl::STATUS => send_status(board, &mut ctl),
            ctl::RESET => {
                let tick = u32::from_le_bytes([cmd[1], cmd[2], cmd[3], cmd[4]]);
                // SAFETY: a plain store; read once after the reset.
                unsafe { core::ptr::write_volatile(core::ptr::addr_of_mut!(BOOT_REQUEST) as *mut [u32; 2], [BOOT_MAGIC, tick]) };
                if let Some(p) = pipe.take() {
                    p.close();
                }
                cortex_m::peripheral::SCB::sys_reset()
            }
            ctl::EXIT => finish(board, "exit command on UART2"),
            _ => {}
        }
    }
}

/// A lockstep start without the host's pipe: nothing could drive the clock.
#[inline(never)]
fn no_pipe() -> ! {
    hprintln!("msr-qemu: lockstep asked for, but QEMU was started without the lockstep pipe (descriptor 3)");
    exit(4)
}

/// One board step, kept out of line: inlined at both call sites, its frame would add to
/// `main`'s twice and raise the stack peak.
#[inline(never)]
fn poll(board: &mut Board<FlashStore>, now_us: u64, host: &mut Port, servo: &mut Port) {
    board.poll(now_us, host, servo);
}

#[inline(never)]
fn send_status(board: &Board<FlashStore>, ctl: &mut Ctl) {
    let mut wire = [0u8; MAX_WIRE_FRAME];
    let n = encode_message(0, &BoardToHost::Status(board.status()), &mut wire).unwrap_or(0);
    let len = (n as u16).to_le_bytes();
    ctl.send(&[ctl::STATUS, len[0], len[1]]);
    ctl.send(&wire[..n]);
}

/// Prints the start-up line and returns the CRC of the model in use (0: none). Out of line:
/// its formatting would otherwise sit in `main`'s frame under every poll.
#[inline(never)]
fn announce(board: &Board<FlashStore>) -> u32 {
    let sizes = memory::sizes();
    let crc = board
        .store()
        .active()
        .and_then(|b| msr_firmware::model::validate(b).ok())
        .map_or(0, |m| m.crc32);
    hprintln!(
        "msr-qemu: ready; built-in model {} bytes; model in use crc {:#010x}; static RAM {} bytes, code {} bytes, .data initial values {} bytes",
        model_area::BUILT_IN.len(),
        crc,
        sizes.static_ram,
        sizes.code - model_area::BUILT_IN.len(),
        sizes.data_init
    );
    crc
}

/// Says whether the flash is a host file; a file that cannot be the flash ends the run (code 4):
/// a board that would forget what the host asked it to keep must not start.
#[inline(never)]
fn report_flash_file(a: msr_qemu::flash_file::Attach) {
    match a {
        msr_qemu::flash_file::Attach::None => {}
        msr_qemu::flash_file::Attach::Attached => hprintln!("msr-qemu: flash kept in the host's file"),
        msr_qemu::flash_file::Attach::Failed(why) => {
            hprintln!("msr-qemu: flash file: {}", why);
            exit(4)
        }
    }
}

/// Says what became of a preloaded model (nothing when there was none). Out of line, as
/// [`announce`].
#[inline(never)]
fn report_preload(p: model_area::Preload) {
    match p {
        model_area::Preload::None => {}
        model_area::Preload::Kept => hprintln!("msr-qemu: preloaded model left alone: the slots hold an active model"),
        model_area::Preload::Taken(crc) => hprintln!("msr-qemu: preloaded model accepted, crc {:#010x}", crc),
        model_area::Preload::Refused(e) => match e {
            UploadError::Invalid(b) => hprintln!("msr-qemu: preloaded model refused: Invalid(blob error code {})", b.code()),
            UploadError::Incomplete { next } => hprintln!("msr-qemu: preloaded model refused: Incomplete {{ next: {} }}", next),
            UploadError::TooLarge => hprintln!("msr-qemu: preloaded model refused: TooLarge"),
            UploadError::Sequence => hprintln!("msr-qemu: preloaded model refused: Sequence"),
            UploadError::Store => hprintln!("msr-qemu: preloaded model refused: Store"),
            UploadError::Crc => hprintln!("msr-qemu: preloaded model refused: Crc"),
        },
    }
}

/// The mode's name, as `Debug` spells it.
fn mode_name(m: Mode) -> &'static str {
    match m {
        Mode::NoModel => "NoModel",
        Mode::Observe => "Observe",
        Mode::Reach => "Reach",
        Mode::Hold => "Hold",
        Mode::Return => "Return",
        Mode::Halted => "Halted",
        Mode::SelfTest => "SelfTest",
    }
}

/// A link's counters as `name: value` pairs.
fn print_link(name: &str, c: &LinkCounters) {
    hprintln!(
        "msr-qemu: {} frames: {}, crc_errors: {}, cobs_errors: {}, oversized: {}, malformed: {}, seq_gaps: {}",
        name,
        c.frames,
        c.crc_errors,
        c.cobs_errors,
        c.oversized,
        c.malformed,
        c.seq_gaps
    );
}

#[inline(never)]
fn finish(board: &Board<FlashStore>, why: &str) -> ! {
    let s = board.status();
    hprintln!("msr-qemu: {}", why);
    // Integers and fixed words only, field by field: a derived `Debug` would link the struct
    // builders and padding of `core::fmt` into this size-budgeted image.
    hprintln!(
        "msr-qemu: status mode: {}, model_crc: {:#010x}, frames: {}, detections: {}, reaches: {}",
        mode_name(s.mode),
        s.model_crc,
        s.frames,
        s.detections,
        s.reaches
    );
    print_link("host_link", &s.host_link);
    print_link("servo_link", &s.servo_link);
    hprintln!(
        "msr-qemu: face_watchdog_trips: {}, servo_watchdog_trips: {}, clamped_targets: {}, frames_superseded: {}, chunks_ignored: {}, frame_crc_errors: {}",
        s.face_watchdog_trips,
        s.servo_watchdog_trips,
        s.clamped_targets,
        s.frames_superseded,
        s.chunks_ignored,
        s.frame_crc_errors
    );
    hprintln!("msr-qemu: stack peak {} bytes", memory::stack_peak());
    let errors = msr_qemu::flash_file::write_errors();
    if errors > 0 {
        hprintln!("msr-qemu: flash file: {} writes failed", errors);
    }
    exit(0)
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    // The location only: printing the message would link every formatter a panic site can name
    // (float printing alone is ~15 KB, from `f32::clamp`'s message) into a size-budgeted image.
    match info.location() {
        Some(l) => hprintln!("msr-qemu: PANIC at {}:{}", l.file(), l.line()),
        None => hprintln!("msr-qemu: PANIC"),
    }
    exit(101)
}
