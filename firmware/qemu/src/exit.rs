//! Ending the run under QEMU with an exit status, through semihosting.

/// `SYS_EXIT_EXTENDED`: unlike `SYS_EXIT` on 32-bit Arm, it carries a status code, which QEMU
/// makes its own exit status.
const SYS_EXIT_EXTENDED: usize = 0x20;
const ADP_STOPPED_APPLICATION_EXIT: usize = 0x20026;

/// Stops QEMU with `code` as its exit status (0 = success). Never returns; on real hardware
/// without a debugger this would fault, so only the QEMU image calls it.
pub fn exit(code: u8) -> ! {
    let block = [ADP_STOPPED_APPLICATION_EXIT, code as usize];
    // SAFETY: the semihosting call reads the two-word block, which lives across the call.
    unsafe {
        cortex_m_semihosting::syscall(SYS_EXIT_EXTENDED, &block);
    }
    loop {
        cortex_m::asm::bkpt();
    }
}
