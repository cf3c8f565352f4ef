//! Running the bare-metal firmware image under `qemu-system-arm` (mps2-an386) with its UARTs
//! connected to byte streams on the host side. Owned by the firmware-board work.
