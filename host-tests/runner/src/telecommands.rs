//! The command link in a lockstep run: telecommand bytes scheduled by step, and the
//! in-process reference's command link (the unit's own code, `ssis::telecommand`, on a
//! copy of the table's flash region), so that the firmware's output frames and command
//! reports can be compared with the host's, step for step, through a table update.

use ssis::calib::store::RamFlash;
use ssis::flight::FlightCore;
use ssis::frames::telecommand::CommandReport;
use ssis::telecommand::CommandLink;

/// The telecommand bytes due before step `n`, in the order given.
pub fn due(commands: &[(u64, Vec<u8>)], n: u64) -> Vec<u8> {
    commands.iter().filter(|(k, _)| *k == n).flat_map(|(_, b)| b.iter().copied()).collect()
}

/// The reference core's command link and flash region.
pub struct ReferenceLink {
    link: CommandLink,
    flash: RamFlash,
}

impl ReferenceLink {
    /// A link with the key record `key_record` (none: no key) on a flash region holding
    /// `image`.
    pub fn new(key_record: Option<&[u8]>, image: &[u8]) -> ReferenceLink {
        ReferenceLink { link: CommandLink::new(key_record.unwrap_or(&[])), flash: RamFlash::new(image) }
    }

    /// The bytes that arrived on the command line before a step.
    pub fn receive(&mut self, bytes: &[u8], core: &mut FlightCore) {
        self.link.receive(bytes, core, &mut self.flash, |_| {});
    }

    /// A command report asked for, once.
    pub fn take_report(&mut self) -> Option<CommandReport> {
        self.link.take_report()
    }

    /// The flash region as the reference's link left it.
    pub fn flash(&self) -> &RamFlash {
        &self.flash
    }
}
