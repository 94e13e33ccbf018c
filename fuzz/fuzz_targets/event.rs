//! Fuzz target: the event frame decoder (single frame and stream).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    ssis_fuzz::check_frame::<ssis::frames::event::EventFrame>(data);
});
