//! The image's command line, through semihosting: `msr-qemu [lockstep-pipe] [flash=PATH]`, as
//! `msr_sim::qemu` starts QEMU (`-semihosting-config ...,arg=msr-qemu,arg=lockstep-pipe,...`;
//! QEMU joins the arguments with spaces).

use cortex_m_semihosting::{nr, syscall1};

const PROGRAM: &[u8] = b"msr-qemu";
const PIPE: &[u8] = b" lockstep-pipe";
const FLASH: &[u8] = b" flash=";

/// The command line as read, NUL-terminated.
pub struct Line {
    buf: [u8; 512],
    len: usize,
}

/// What the command line says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Args<'a> {
    /// The host passed the lockstep pipe (see [`crate::pipe`]).
    pub lockstep_pipe: bool,
    /// The flash file's path, running to the end of the line (it may hold spaces), with the
    /// NUL after it.
    pub flash: Option<&'a [u8]>,
}

impl Line {
    /// Reads the command line; `Err` when it does not fit.
    pub fn read() -> Result<Line, &'static str> {
        let mut line = Line { buf: [0; 512], len: 0 };
        // The block is read and written by the host: buffer, then its length (in), the string's
        // length (out).
        let mut block = [line.buf.as_mut_ptr() as usize, line.buf.len()];
        let block_ptr = block.as_mut_ptr();
        // SAFETY: GET_CMDLINE writes at most `buf.len()` bytes into `buf` and the length into the
        // block, both alive across the call. Passed as a raw pointer and read back volatile:
        // through a shared reference the compiler may keep the length it stored.
        if unsafe { syscall1(nr::GET_CMDLINE, block_ptr as usize) } != 0 {
            return Ok(line);
        }
        // SAFETY: the block's second word, written by the host.
        let len = unsafe { core::ptr::read_volatile(block_ptr.add(1)) };
        if len >= line.buf.len() {
            return Err("the command line is too long");
        }
        line.len = len;
        Ok(line)
    }

    /// The arguments; none when the line is not this image's.
    pub fn args(&self) -> Args<'_> {
        parse(&self.buf[..=self.len])
    }
}

/// Parses a NUL-terminated line.
fn parse(line: &[u8]) -> Args<'_> {
    let none = Args { lockstep_pipe: false, flash: None };
    let Some(mut rest) = line.strip_prefix(PROGRAM) else { return none };
    let lockstep_pipe = rest.starts_with(PIPE) && matches!(rest.get(PIPE.len()), Some(b' ' | 0));
    if lockstep_pipe {
        rest = &rest[PIPE.len()..];
    }
    Args { lockstep_pipe, flash: rest.strip_prefix(FLASH) }
}
