//! The defmt log's output: a SEGGER RTT control block with one up channel, written
//! without waiting and without a panic path (`defmt-rtt` has one).

use core::sync::atomic::{AtomicU32, Ordering};

/// Bytes of the RTT up channel's buffer.
const RTT_BUF_LEN: usize = 1024;

/// The RTT control block the probe finds (by its `_SEGGER_RTT` symbol or by the id
/// at its start) and reads the up channel of: SEGGER's layout, one up channel named
/// `defmt`, no down channel.
#[repr(C)]
pub struct RttControlBlock {
    id: [u8; 16],
    max_up: u32,
    max_down: u32,
    up: RttChannel,
}

#[repr(C)]
struct RttChannel {
    name: *const u8,
    buffer: *mut u8,
    size: u32,
    /// Written by the target.
    write: AtomicU32,
    /// Written by the probe.
    read: AtomicU32,
    flags: u32,
}

// SAFETY: the pointers are to statics; the buffer is written only by `rtt_write`,
// which runs inside the logger's critical section, and read by the probe.
unsafe impl Sync for RttControlBlock {}

struct RttBuffer(core::cell::UnsafeCell<[u8; RTT_BUF_LEN]>);

// SAFETY: see `RttControlBlock`.
unsafe impl Sync for RttBuffer {}

static RTT_BUFFER: RttBuffer = RttBuffer(core::cell::UnsafeCell::new([0; RTT_BUF_LEN]));
static RTT_NAME: [u8; 6] = *b"defmt\0";

/// The control block.
#[no_mangle]
pub static _SEGGER_RTT: RttControlBlock = RttControlBlock {
    id: *b"SEGGER RTT\0\0\0\0\0\0",
    max_up: 1,
    max_down: 0,
    up: RttChannel {
        name: RTT_NAME.as_ptr(),
        buffer: RTT_BUFFER.0.get().cast(),
        size: RTT_BUF_LEN as u32,
        write: AtomicU32::new(0),
        read: AtomicU32::new(0),
        // Non-blocking, trim: what does not fit is dropped, the unit never waits
        // for the probe (the defmt decoder resynchronises at the next frame).
        flags: 1,
    },
};

/// The log's output (the logger of `ssis_firmware::cortex_m7_runtime!`): `bytes` into the RTT
/// up channel, as much as fits; never waits and never panics.
pub fn rtt_write(bytes: &[u8]) {
    let ch = &_SEGGER_RTT.up;
    let read = ch.read.load(Ordering::Acquire) as usize;
    let mut write = ch.write.load(Ordering::Relaxed) as usize;
    if write >= RTT_BUF_LEN {
        write = 0;
    }
    let buf: *mut u8 = RTT_BUFFER.0.get().cast();
    for &b in bytes {
        let next = (write + 1) % RTT_BUF_LEN;
        if next == read {
            break;
        }
        // SAFETY: `write` < RTT_BUF_LEN (checked above, kept by the modulo).
        unsafe { buf.add(write).write_volatile(b) };
        write = next;
    }
    ch.write.store(write as u32, Ordering::Release);
}
