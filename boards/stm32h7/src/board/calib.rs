//! The calibration sector: the table's two stored copies in the last flash sector.

extern "C" {
    /// Start of the `CALIB` region (memory.x): the calibration sector.
    static _calib_start: u8;
    /// Its end.
    static _calib_end: u8;
}

/// The calibration sector (the `CALIB` region of memory.x, one 128 KiB flash sector):
/// the two stored copies of the table at its start (`ssis::calib::store`), checked by
/// the boot policy. Erased flash reads as 0xFF, which the store refuses.
pub(super) fn calib_sector() -> &'static [u8] {
    let start = core::ptr::addr_of!(_calib_start);
    let len = (core::ptr::addr_of!(_calib_end) as usize).saturating_sub(start as usize);
    // SAFETY: memory.x reserves [_calib_start, _calib_end) (always mapped flash) for
    // the table; the firmware never writes it, so it does not change while borrowed.
    unsafe { core::slice::from_raw_parts(start, len) }
}
