//! `QemuUnit`: the spacecraft firmware (`ssis-fw-test`) in QEMU, stepped in lockstep one
//! 5-ms step at a time by the runner's driver (`ssis_runner::qemu::run_feed`, what
//! `ssis-qemu` runs): each step's FOG and star-tracker frames go out on the emulated
//! UARTs, the firmware steps on the STEP control frame, its output frame comes back, and
//! the runner compares every output frame with the same core run in-process.
//!
//! The driver pulls its steps; here it runs on its own thread and pulls them from
//! [`PyQemuUnit::step`] through a channel, so a closed loop (Basilisk) can make step n + 1
//! from the output of step n.

use std::sync::{mpsc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use ssis::flight::{health, Profile};
use ssis::frames::event::EventFrame;
use ssis::frames::output::OutputFrame;
use ssis_common::ARCSEC_PER_RAD;
use ssis_runner::qemu::{build_firmware, run_feed, Feed, QemuOptions, QemuSummary};
use ssis_sim::harness::StepInput;

use crate::core::{event_dicts, Encoder, StepIn};
use crate::table::PyTable;
use crate::{err, SsisError};

/// How long a step may take to come back (QEMU's start included) before the run is given up.
const STEP_PATIENCE: Duration = Duration::from_secs(120);

/// The firmware in QEMU in lockstep.
#[pyclass(module = "ssis._ssis", name = "QemuUnit")]
pub struct PyQemuUnit {
    tx: Option<mpsc::SyncSender<StepInput>>,
    /// (In a mutex: Basilisk calls a module from its own threads.)
    rx: Mutex<mpsc::Receiver<(OutputFrame, Vec<EventFrame>)>>,
    run: Option<JoinHandle<anyhow::Result<QemuSummary>>>,
    enc: Encoder,
    report: Option<String>,
}

impl PyQemuUnit {
    /// Ends the run: the driver sees the end of its steps, sends END and waits for QEMU.
    fn finish(&mut self) -> PyResult<String> {
        self.tx = None;
        if let Some(h) = self.run.take() {
            let s = h.join().map_err(|_| SsisError::new_err("the QEMU driver thread panicked"))?.map_err(err)?;
            self.report = Some(s.report());
        }
        Ok(self.report.clone().unwrap_or_default())
    }
}

impl Drop for PyQemuUnit {
    fn drop(&mut self) {
        let _ = self.finish();
    }
}

#[pymethods]
impl PyQemuUnit {
    /// Starts QEMU on `elf` (default: the test build, built if out of date) with `table`
    /// in its flash; `steps` is what the summary calls the run's length.
    #[new]
    #[pyo3(signature = (table = None, elf = None, steps = 0))]
    fn new(table: Option<&PyTable>, elf: Option<std::path::PathBuf>, steps: u64) -> PyResult<Self> {
        let table = PyTable::table(table);
        let elf = match elf {
            Some(e) => e,
            None => build_firmware().map_err(err)?,
        };
        let (tx, rx_in) = mpsc::sync_channel::<StepInput>(1);
        let (tx_out, rx) = mpsc::channel::<(OutputFrame, Vec<EventFrame>)>();
        let run = std::thread::spawn(move || {
            let feed = Feed {
                name: "ssis.QemuUnit".into(),
                profile: Profile::SPACECRAFT,
                table,
                steps,
                settle_s: 0.0,
                next: Box::new(move || rx_in.recv().ok()),
                on_step: Some(Box::new(move |f, events| {
                    let _ = tx_out.send((*f, events.to_vec()));
                })),
            };
            run_feed(feed, &QemuOptions::lockstep(elf), |_, _| {})
        });
        Ok(PyQemuUnit { tx: Some(tx), rx: Mutex::new(rx), run: Some(run), enc: Encoder::new(&table), report: None })
    }

    /// One step, as `FlightCore.step`; returns the firmware's output frame, decoded, and the
    /// events of the event frame it sent after it (`events`, as `FlightCore.step`'s).
    fn step<'py>(&mut self, py: Python<'py>, args: StepIn) -> PyResult<Bound<'py, PyDict>> {
        let input = self.enc.encode(&args);
        let n = input.n;
        let sent = self.tx.as_ref().is_some_and(|tx| tx.send(input).is_ok());
        let rx = self.rx.lock().map_err(|_| SsisError::new_err("QEMU: the output channel is poisoned"))?;
        let frame = if sent { rx.recv_timeout(STEP_PATIENCE).ok() } else { None };
        drop(rx);
        let Some((f, events)) = frame else {
            let why = self.finish().err().map_or_else(|| "the run ended".to_string(), |e| e.to_string());
            return Err(SsisError::new_err(format!("QEMU: no output for step {n}: {why}")));
        };
        let d = PyDict::new(py);
        d.set_item("time_s", f.time_us as f64 * 1e-6)?;
        d.set_item("q", f.quaternion().to_vec().into_pyarray(py))?;
        d.set_item("rate_rad_s", f.rate_rad_s().to_vec().into_pyarray(py))?;
        d.set_item("drift_rad_s", f.drift_rad_s().to_vec().into_pyarray(py))?;
        d.set_item("att_sigma_arcsec", f.att_sigma_rad().map(|v| v * ARCSEC_PER_RAD).to_vec().into_pyarray(py))?;
        d.set_item("drift_sigma_rad_s", f.drift_sigma_rad_s().to_vec().into_pyarray(py))?;
        d.set_item("parity_rad", f.parity_rad())?;
        d.set_item("flags", f.flags)?;
        d.set_item("st_status", f.st_status)?;
        d.set_item("fog_health", f.fog_health.map(u32::from).to_vec())?;
        let used =
            f.fog_health.iter().enumerate().filter(|(_, h)| *h & health::USED != 0).fold(0u8, |a, (i, _)| a | 1 << i);
        d.set_item("fogs_used", used)?;
        d.set_item("fdi", f.fdi)?;
        d.set_item("events", event_dicts(py, &events)?)?;
        Ok(d)
    }

    /// Ends the run (END, QEMU's exit) and returns the runner's report: every output frame
    /// compared with the in-process core's, instructions per step, overruns.
    fn close(&mut self) -> PyResult<String> {
        self.finish()
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyQemuUnit>()
}
