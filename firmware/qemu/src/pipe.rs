//! The lockstep channel's commands, read from a pipe through semihosting.
//!
//! The host starts QEMU with the read end of a pipe as its file descriptor 3 (`msr_sim::qemu`)
//! and says so on the image's command line (`lockstep-pipe`, [`crate::cmdline`]); the image
//! opens it as `/dev/fd/3`. Without that word it opens nothing: descriptor 3 is then one of
//! QEMU's own files. A semihosting read takes a whole command with its bytes
//! in one call, where the emulated UART moves one byte per turn of QEMU's event loop (a tick's
//! 40 bytes took about 2 ms that way). What the board writes still goes out on its UARTs.
//!
//! A read blocks QEMU until the host writes: in lockstep the board has nothing to do between
//! ticks, and its clock is the host's.

use cortex_m_semihosting::{nr, syscall};

const PATH: &[u8] = b"/dev/fd/3\0";
/// `rb`.
const MODE_READ_BINARY: usize = 1;

/// The open pipe.
pub struct Pipe {
    handle: usize,
}

impl Pipe {
    /// Opens the pipe; `None` when QEMU was started without one. Out of line: the command
    /// line's buffer is on the stack only here.
    #[inline(never)]
    pub fn open() -> Option<Pipe> {
        if !crate::cmdline::Line::read().is_ok_and(|l| l.args().lockstep_pipe) {
            return None;
        }
        // SAFETY: OPEN reads the NUL-terminated path and the three-word block, both alive
        // across the call.
        let h = unsafe { syscall(nr::OPEN, &[PATH.as_ptr() as usize, MODE_READ_BINARY, PATH.len() - 1]) } as isize;
        (h >= 0).then_some(Pipe { handle: h as usize })
    }

    /// Fills `buf`, waiting for the host; false when the pipe ended (or failed) first.
    pub fn read_exact(&mut self, buf: &mut [u8]) -> bool {
        let mut got = 0;
        while got < buf.len() {
            let rest = &mut buf[got..];
            // SAFETY: READ writes at most `rest.len()` bytes into `rest`, which is ours.
            let unread = unsafe { syscall(nr::READ, &[self.handle, rest.as_mut_ptr() as usize, rest.len()]) };
            // The bytes not read: all of them at the end of the file, -1 (as usize) on an error.
            if unread >= rest.len() {
                return false;
            }
            got += rest.len() - unread;
        }
        true
    }

    /// Closes the pipe (QEMU's descriptor table outlives a reset of the board).
    pub fn close(self) {
        // SAFETY: CLOSE reads the one-word block.
        unsafe { syscall(nr::CLOSE, &[self.handle]) };
    }
}
