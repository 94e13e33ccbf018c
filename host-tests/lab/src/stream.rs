//! Passes over a session: every row turned into a small basis vector per FOG and summed
//! into per-block Gram matrices, so a fit never holds the rows.
//!
//! Every model term is linear in its coefficients and every regressor is a linear function
//! of a few per-row quantities, the **basis** z of FOG i ([`Basis`], [`Q`]): 1; ω_ref (x, y,
//! z), rad/s; |r_i| and r_i² with r_i = s_i⁰·ω_ref; (t − t₀)/3600; ΔT, ΔT², ΔT³, G, ΔT·G
//! (ΔT = T_i − T_ref, G = dT_i/dt); B_x, B_y, B_z, nT; sin and cos 2πft per sinusoid; the
//! value of each expression or user column; and last y_i = ω_i,raw − r_i. A pass carries only
//! the quantities its terms use. The scale factor is then s_i⁰ on the ω slots, a
//! misalignment angle ∂s_i/∂δ there, the magnetic term u_i or v_i on the field slots
//! ([`Basis::functionals`]). The pass sums z zᵀ per FOG and
//! per time block ([`Digest`]): m × m numbers per block, whatever the number of rows. Any
//! fit, residual sum of squares or correlation over any union of blocks follows from those
//! sums (`super::fit`). For conditioning, z is summed shifted by its value on the first row
//! (slot 0 stays 1): the shift is a change of basis the functionals undo exactly
//! ([`Digest::shifted`]).
//!
//! G = dT/dt needs the samples up to half a window ahead ([`temperature_rate`]):
//! the pass holds that many rows back, never more. A systematic sample of at most `keep`
//! rows (every row when the session is that short) is kept with its basis vectors for what
//! needs rows: plots, the spectral search, the T × G analysis of variance.

use std::path::Path;

use exmex::Express;
use indicatif::ProgressBar;

use super::lsq::{design_gram, lstsq_gram, residual_functional, Gram};
use super::model::{loop_plane, misalignment_partials, Catalog, Kind};
use super::noise::Bins;
use super::session::{
    median_interval_s, nominal_axes, write_record, Converter, Header, RowReader, SampleRef, Session, Shape,
};
use super::{LabError, LabResult};

/// Rows kept by default for plots, the spectral search and the ANOVA.
pub const DEFAULT_KEEP: usize = 40_000;

/// Where a pass reads its samples.
#[derive(Debug, Clone, Copy)]
pub enum Source<'a> {
    /// A session file, streamed.
    File(&'a Path),
    /// A session in memory.
    Memory(&'a Session),
}

impl Source<'_> {
    /// The session's header alone (a file's first lines: no pre-pass over its rows).
    pub fn header(&self) -> LabResult<Header> {
        match self {
            Source::File(p) => Ok(RowReader::open(p)?.header().clone()),
            Source::Memory(s) => Ok(Header::parse(&s.file, s.names.clone(), 1)?),
        }
    }

    /// The session's header, size and sample interval (a quick look at a file).
    pub fn shape(&self) -> LabResult<Shape> {
        match self {
            Source::File(p) => Ok(super::session::shape(p)?),
            Source::Memory(s) => {
                let header = Header::parse(&s.file, s.names.clone(), 1)?;
                let t = s.t_s();
                Ok(Shape {
                    header,
                    samples: t.len(),
                    t_span_s: [t[0], t[t.len() - 1]],
                    dt_s: median_interval_s(t),
                    bytes: 0,
                })
            }
        }
    }

    /// Calls `f` with the record of every sample in order ([`SampleRef`]), until it
    /// returns `false`.
    fn for_each(&self, progress: Option<&ProgressBar>, mut f: impl FnMut(&[f64]) -> LabResult<bool>) -> LabResult<()> {
        let mut rec = Vec::new();
        match self {
            Source::File(p) => {
                let mut rr = RowReader::open(p)?;
                let mut conv = Converter::new(&rr.header().layout);
                let mut rows = 0u64;
                while let Some(row) = rr.next_row()? {
                    if conv.convert(row, &mut rec) && !f(&rec)? {
                        break;
                    }
                    rows += 1;
                    if let Some(pb) = progress.filter(|_| rows.is_multiple_of(65_536)) {
                        pb.set_position(rr.bytes());
                    }
                }
            }
            Source::Memory(s) => {
                let t = s.t_s();
                for j in 0..s.len() {
                    write_record(
                        &mut rec,
                        t[j],
                        s.fogs.iter().map(|fog| fog.rate_rad_s[j]),
                        s.fogs.iter().map(|fog| fog.t_degc.as_ref().map_or(f64::NAN, |c| c[j])),
                        s.ref_rad_s[j],
                        s.field_nt.as_ref().map_or([0.0; 3], |b| b[j]),
                        s.cols.iter().map(|c| c[j]),
                    );
                    if !f(&rec)? {
                        break;
                    }
                }
            }
        }
        Ok(())
    }
}

/// Where an expression variable comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Var {
    /// A session column (file order).
    Column(usize),
    /// r_i = s_i⁰·ω_ref.
    Rate,
    /// T_i.
    TAbs,
    /// T_i − T_ref.
    DTemp,
    /// G_i.
    TRate,
    /// The FOG number.
    Fog,
}

/// An expression (or user column) of the basis.
#[derive(Debug, Clone)]
struct ExprSlot {
    text: String,
    /// The compiled expression; `None` for a bare column name.
    ex: Option<exmex::FlatEx<f64>>,
    vars: Vec<Var>,
    /// Whether it needs FOG temperatures.
    needs_temp: bool,
}

/// A quantity of the basis (see the module text).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Q {
    /// 1.
    One,
    /// ω_ref component, rad/s.
    Omega(usize),
    /// |r|, rad/s.
    AbsR,
    /// r², (rad/s)².
    R2,
    /// Hours since the first sample.
    Age,
    /// ΔT, °C.
    DT,
    /// ΔT².
    DT2,
    /// ΔT³.
    DT3,
    /// G, °C/s.
    G,
    /// ΔT·G.
    DTG,
    /// Field component, nT.
    Field(usize),
    /// sin 2πft of sinusoid k.
    Sin(usize),
    /// cos 2πft of sinusoid k.
    Cos(usize),
    /// Expression or user column k.
    Expr(usize),
    /// y = ω_raw − r.
    Y,
}

/// The per-FOG basis of a pass: which slot holds which quantity (see the module text). Only
/// the quantities the pass's terms use are there (slot 0 is always 1, the last always y).
#[derive(Debug, Clone)]
pub struct Basis {
    /// Session file (for messages).
    pub file: String,
    /// The quantity in each slot.
    pub slots: Vec<Q>,
    /// Slots.
    pub m: usize,
    /// Number of FOGs.
    pub n_fog: usize,
    /// Whether FOG i has a temperature column.
    pub has_temp: Vec<bool>,
    /// Whether the session has field columns.
    pub has_field: bool,
    /// Sinusoid frequencies, Hz.
    pub sinusoids: Vec<f64>,
    exprs: Vec<ExprSlot>,
    /// Slot of y.
    pub y: usize,
    /// Time of the first sample, s (aging is counted from it).
    pub t0_s: f64,
    /// T_ref, °C.
    pub t_ref_degc: f64,
    axes: [nalgebra::Vector3<f64>; 4],
    /// Per slot, its index in the table [`Basis::fill`] builds ([`TABLE_FIXED`]); empty when
    /// a slot is not in it (sinusoids, compiled expressions: the slot by slot fill).
    gather: Vec<u8>,
    /// The bare columns of the table, after its fixed part.
    gather_cols: Vec<usize>,
}

/// The fixed part of the table of per-row quantities a fill builds for one FOG: 1, ω_x, ω_y,
/// ω_z, |r|, r², age, ΔT, ΔT², ΔT³, G, ΔT·G, B_x, B_y, B_z, y; the bare columns follow, up to
/// [`TABLE_MAX`] entries in all.
const TABLE_FIXED: usize = 16;

/// Entries of the table at most.
const TABLE_MAX: usize = 32;

/// The table index of every slot, and the bare columns the table carries; `None` when a
/// slot is not in the table.
fn table_of(slots: &[Q], exprs: &[ExprSlot]) -> Option<(Vec<u8>, Vec<usize>)> {
    let mut cols: Vec<usize> = Vec::new();
    let mut idx = Vec::with_capacity(slots.len());
    for q in slots {
        let k = match *q {
            Q::One => 0,
            Q::Omega(k) => 1 + k,
            Q::AbsR => 4,
            Q::R2 => 5,
            Q::Age => 6,
            Q::DT => 7,
            Q::DT2 => 8,
            Q::DT3 => 9,
            Q::G => 10,
            Q::DTG => 11,
            Q::Field(k) => 12 + k,
            Q::Y => 15,
            Q::Expr(k) => match (&exprs[k].ex, exprs[k].vars.as_slice()) {
                (None, [Var::Column(c)]) => {
                    let at = cols.iter().position(|x| x == c).unwrap_or_else(|| {
                        cols.push(*c);
                        cols.len() - 1
                    });
                    TABLE_FIXED + at
                }
                _ => return None,
            },
            Q::Sin(_) | Q::Cos(_) => return None,
        };
        if k >= TABLE_MAX {
            return None;
        }
        idx.push(k as u8);
    }
    Some((idx, cols))
}

/// Slot of the constant.
pub const ONE: usize = 0;

/// The quantities a term uses.
fn quantities(kind: &Kind, sinusoids: &[f64], exprs: &[ExprSlot]) -> Vec<Q> {
    match kind {
        Kind::Catalog(c) => match c {
            Catalog::Bias => vec![Q::One],
            Catalog::ScaleFactor | Catalog::Misalignment => vec![Q::Omega(0), Q::Omega(1), Q::Omega(2)],
            Catalog::SfAsymmetry => vec![Q::AbsR],
            Catalog::SfNonlinearity => vec![Q::R2],
            Catalog::ThermalT1 => vec![Q::DT],
            Catalog::ThermalT2 => vec![Q::DT2],
            Catalog::ThermalT3 => vec![Q::DT3],
            Catalog::TempRate => vec![Q::G],
            Catalog::TTimesG => vec![Q::DTG],
            Catalog::Magnetic => vec![Q::Field(0), Q::Field(1), Q::Field(2)],
            Catalog::Aging => vec![Q::Age],
        },
        Kind::Sinusoid(f) => sinusoids.iter().position(|x| x == f).map_or(vec![], |k| vec![Q::Sin(k), Q::Cos(k)]),
        Kind::Expr(e) => exprs.iter().position(|x| x.text == *e).map_or(vec![], |k| vec![Q::Expr(k)]),
    }
}

impl Basis {
    /// The basis for a session with `header` and the terms `kinds` (what they need and the
    /// session has).
    pub fn new(header: &Header, kinds: &[Kind], t0_s: f64, t_ref_degc: f64) -> LabResult<Basis> {
        let l = &header.layout;
        let has_temp: Vec<bool> = l.fog_temp.iter().map(Option::is_some).collect();
        let (any_temp, has_field) = (has_temp.iter().any(|&b| b), l.field.is_some());
        let mut sinusoids: Vec<f64> = Vec::new();
        let mut exprs: Vec<ExprSlot> = Vec::new();
        for k in kinds {
            match k {
                Kind::Sinusoid(f) if !sinusoids.contains(f) => sinusoids.push(*f),
                Kind::Expr(e) if !exprs.iter().any(|x| x.text == *e) => exprs.push(compile(e, header)?),
                _ => {}
            }
        }
        let mut slots = vec![Q::One];
        for k in kinds {
            for q in quantities(k, &sinusoids, &exprs) {
                let feedable = match q {
                    Q::DT | Q::DT2 | Q::DT3 | Q::G | Q::DTG => any_temp,
                    Q::Field(_) => has_field,
                    _ => true,
                };
                if feedable && !slots.contains(&q) {
                    slots.push(q);
                }
            }
        }
        slots.push(Q::Y);
        let (gather, gather_cols) = table_of(&slots, &exprs).unwrap_or_default();
        Ok(Basis {
            file: header.file.clone(),
            m: slots.len(),
            y: slots.len() - 1,
            slots,
            n_fog: l.n_fog,
            has_temp,
            has_field,
            sinusoids,
            exprs,
            t0_s,
            t_ref_degc,
            axes: nominal_axes(),
            gather,
            gather_cols,
        })
    }

    /// The slot of a quantity.
    pub fn slot(&self, q: Q) -> Option<usize> {
        self.slots.iter().position(|x| *x == q)
    }

    /// Fills `z` (length m) for FOG `fog` from a sample and its G per FOG.
    pub fn fill(&self, fog: usize, s: &SampleRef, g_degc_s: &[f64], z: &mut [f64]) -> LabResult<()> {
        if self.batched() {
            self.fill_from_table(fog, s, g_degc_s, z);
            return Ok(());
        }
        let w = s.ref_rad_s;
        let a = self.axes[fog.min(3)];
        let r = a.x * w[0] + a.y * w[1] + a.z * w[2];
        let temp = self.has_temp[fog];
        let (dt, g) = if temp { (s.t_degc[fog] - self.t_ref_degc, g_degc_s[fog]) } else { (0.0, 0.0) };
        let mut sc = [(0.0f64, 0.0f64); 4];
        for (k, f) in self.sinusoids.iter().enumerate().take(4) {
            sc[k] = (2.0 * std::f64::consts::PI * f * s.t_s).sin_cos();
        }
        for (v, q) in z.iter_mut().zip(&self.slots) {
            *v = match *q {
                Q::One => 1.0,
                Q::Omega(k) => w[k],
                Q::AbsR => r.abs(),
                Q::R2 => r * r,
                Q::Age => (s.t_s - self.t0_s) / 3600.0,
                Q::DT => dt,
                Q::DT2 => dt * dt,
                Q::DT3 => dt * dt * dt,
                Q::G => g,
                Q::DTG => dt * g,
                Q::Field(k) => s.field_nt[k],
                Q::Sin(k) if k < 4 => sc[k].0,
                Q::Cos(k) if k < 4 => sc[k].1,
                Q::Sin(k) => (2.0 * std::f64::consts::PI * self.sinusoids[k] * s.t_s).sin(),
                Q::Cos(k) => (2.0 * std::f64::consts::PI * self.sinusoids[k] * s.t_s).cos(),
                Q::Expr(k) => self.expr_value(k, fog, s, r, dt, g)?,
                Q::Y => s.rate_rad_s[fog] - r,
            };
        }
        Ok(())
    }

    /// [`Basis::fill`] without a branch per slot: every quantity of the table computed (the
    /// same operations as the slot by slot fill, so the same values), each slot read from it.
    #[inline]
    fn fill_from_table(&self, fog: usize, s: &SampleRef, g_degc_s: &[f64], z: &mut [f64]) {
        let w = s.ref_rad_s;
        let a = self.axes[fog.min(3)];
        let r = a.x * w[0] + a.y * w[1] + a.z * w[2];
        let (dt, g) = if self.has_temp[fog] { (s.t_degc[fog] - self.t_ref_degc, g_degc_s[fog]) } else { (0.0, 0.0) };
        let b = s.field_nt;
        let age = (s.t_s - self.t0_s) / 3600.0;
        let y = s.rate_rad_s[fog] - r;
        let mut table = [0.0f64; TABLE_MAX];
        table[..TABLE_FIXED].copy_from_slice(&[
            1.0,
            w[0],
            w[1],
            w[2],
            r.abs(),
            r * r,
            age,
            dt,
            dt * dt,
            dt * dt * dt,
            g,
            dt * g,
            b[0],
            b[1],
            b[2],
            y,
        ]);
        for (x, &c) in table[TABLE_FIXED..].iter_mut().zip(&self.gather_cols) {
            *x = s.values[c];
        }
        for (v, &k) in z.iter_mut().zip(&self.gather) {
            *v = table[usize::from(k)];
        }
    }

    /// The slots in the order the Gram sums take them ([`accumulate_gram`]), and how many
    /// come first that hold the same values for every FOG: in a batched pass, the
    /// quantities of the sample (1, ω_ref, hours, B, user columns: every FOG's shift of them
    /// is the same, the first row's value); otherwise none.
    fn gram_order(&self) -> (Vec<usize>, usize) {
        let shared = |k: u8| matches!(usize::from(k), 0..=3 | 6 | 12..=14) || usize::from(k) >= TABLE_FIXED;
        if !self.batched() {
            return ((0..self.m).collect(), 0);
        }
        let mut order: Vec<usize> = (0..self.m).filter(|&a| shared(self.gather[a])).collect();
        let n = order.len();
        order.extend((0..self.m).filter(|&a| !shared(self.gather[a])));
        (order, n)
    }

    /// Whether a batch's columns can be computed from its staged quantities
    /// ([`Basis::fill_batch`]): every slot is in the table (no sinusoid, no compiled
    /// expression).
    fn batched(&self) -> bool {
        !self.gather.is_empty()
    }

    /// [`Basis::fill`] minus `shift` for the first `rows` rows staged in `st`, written
    /// column-major to `cols` (slot a of row i at `cols[a * COL + i]`): a quantity at a time
    /// over the rows, with the same operations in the same order as [`Basis::fill_from_table`]
    /// (the same values), so the loops run on whole vectors of rows.
    fn fill_batch(&self, fog: usize, st: &Staged, rows: usize, shift: &[f64], cols: &mut [f64]) {
        let rows = rows.min(BATCH);
        let ax = self.axes[fog.min(3)];
        let (w0, w1, w2) = (&st.w[..rows], &st.w[BATCH..BATCH + rows], &st.w[2 * BATCH..2 * BATCH + rows]);
        let mut r = [0.0f64; BATCH];
        for (r, ((x, y), z)) in r.iter_mut().zip(w0.iter().zip(w1).zip(w2)) {
            *r = ax.x * x + ax.y * y + ax.z * z;
        }
        let (mut dt, mut g) = ([0.0f64; BATCH], [0.0f64; BATCH]);
        if self.has_temp[fog] {
            for (d, t) in dt.iter_mut().zip(&st.temp[fog * BATCH..fog * BATCH + rows]) {
                *d = t - self.t_ref_degc;
            }
            g[..rows].copy_from_slice(&st.g[fog * BATCH..fog * BATCH + rows]);
        }
        let rate = &st.rate[fog * BATCH..fog * BATCH + rows];
        for (a, &k) in self.gather.iter().enumerate() {
            let sh = shift[a];
            let col = &mut cols[a * COL..a * COL + rows];
            macro_rules! put {
                ($i:ident => $e:expr) => {
                    for ($i, c) in col.iter_mut().enumerate() {
                        *c = $e - sh;
                    }
                };
            }
            match usize::from(k) {
                0 => col.fill(1.0 - sh),
                1 => put!(i => w0[i]),
                2 => put!(i => w1[i]),
                3 => put!(i => w2[i]),
                4 => put!(i => r[i].abs()),
                5 => put!(i => r[i] * r[i]),
                6 => put!(i => (st.t_s[i] - self.t0_s) / 3600.0),
                7 => put!(i => dt[i]),
                8 => put!(i => dt[i] * dt[i]),
                9 => put!(i => dt[i] * dt[i] * dt[i]),
                10 => put!(i => g[i]),
                11 => put!(i => dt[i] * g[i]),
                12..=14 => {
                    let f = &st.field[(usize::from(k) - 12) * BATCH..];
                    put!(i => f[i]);
                }
                15 => put!(i => rate[i] - r[i]),
                c => {
                    let v = &st.cols[(c - TABLE_FIXED) * BATCH..];
                    put!(i => v[i]);
                }
            }
        }
    }

    fn expr_value(&self, k: usize, fog: usize, s: &SampleRef, r: f64, dt: f64, g: f64) -> LabResult<f64> {
        let x = &self.exprs[k];
        if x.needs_temp && !self.has_temp[fog] {
            return Ok(0.0);
        }
        let Some(ex) = &x.ex else {
            return Ok(match x.vars[0] {
                Var::Column(c) => s.values[c],
                _ => 0.0,
            });
        };
        let v: Vec<f64> = x
            .vars
            .iter()
            .map(|var| match *var {
                Var::Column(c) => s.values[c],
                Var::Rate => r,
                Var::TAbs => s.t_degc[fog],
                Var::DTemp => dt,
                Var::TRate => g,
                Var::Fog => fog as f64,
            })
            .collect();
        let e = ex
            .eval(&v)
            .map_err(|e| LabError::Model(format!("expression `{}` at t = {} s ({}): {e}", x.text, s.t_s, self.file)))?;
        if !e.is_finite() {
            return Err(LabError::Model(format!(
                "expression `{}` is not finite at t = {} s ({})",
                x.text, s.t_s, self.file
            )));
        }
        Ok(e)
    }

    /// The regressors of `kind` for FOG `fog` as linear functionals of the basis (one vector
    /// of length m per regressor); `Err` says why the session cannot feed it.
    pub fn functionals(&self, kind: &Kind, fog: usize) -> Result<Vec<Vec<f64>>, String> {
        let at = |pairs: &[(Q, f64)]| -> Result<Vec<f64>, String> {
            let mut v = vec![0.0; self.m];
            for &(q, c) in pairs {
                v[self.slot(q).ok_or_else(|| format!("{}: `{}` is not in this pass", self.file, kind.label()))?] += c;
            }
            Ok(v)
        };
        let on_omega = |a: nalgebra::Vector3<f64>| at(&[(Q::Omega(0), a.x), (Q::Omega(1), a.y), (Q::Omega(2), a.z)]);
        let need_t = |what: &str, q: Q| -> Result<Vec<Vec<f64>>, String> {
            if !self.has_temp[fog] {
                return Err(format!(
                    "{}: term `{what}` needs the temperature of FOG {fog} (column `fog{fog}_t_degc`)",
                    self.file
                ));
            }
            Ok(vec![at(&[(q, 1.0)])?])
        };
        Ok(match kind {
            Kind::Catalog(c) => match c {
                Catalog::Bias => vec![at(&[(Q::One, 1.0)])?],
                Catalog::ScaleFactor => vec![on_omega(self.axes[fog.min(3)])?],
                Catalog::SfAsymmetry => vec![at(&[(Q::AbsR, 1.0)])?],
                Catalog::SfNonlinearity => vec![at(&[(Q::R2, 1.0)])?],
                Catalog::Misalignment => {
                    if fog > 3 {
                        return Err(format!("{}: misalignment is defined for FOGs 0–3", self.file));
                    }
                    misalignment_partials(fog).into_iter().map(on_omega).collect::<Result<_, _>>()?
                }
                Catalog::ThermalT1 => need_t(c.name(), Q::DT)?,
                Catalog::ThermalT2 => need_t(c.name(), Q::DT2)?,
                Catalog::ThermalT3 => need_t(c.name(), Q::DT3)?,
                Catalog::TempRate => need_t(c.name(), Q::G)?,
                Catalog::TTimesG => need_t(c.name(), Q::DTG)?,
                Catalog::Magnetic => {
                    if !self.has_field {
                        return Err(format!(
                            "{}: term `magnetic` needs columns `b_x_nt`, `b_y_nt`, `b_z_nt`",
                            self.file
                        ));
                    }
                    loop_plane(fog)
                        .iter()
                        .map(|u| at(&[(Q::Field(0), u.x), (Q::Field(1), u.y), (Q::Field(2), u.z)]))
                        .collect::<Result<_, _>>()?
                }
                Catalog::Aging => vec![at(&[(Q::Age, 1.0)])?],
            },
            Kind::Sinusoid(f) => {
                let k = self.sinusoids.iter().position(|x| x == f).ok_or("sinusoid not in this pass")?;
                vec![at(&[(Q::Sin(k), 1.0)])?, at(&[(Q::Cos(k), 1.0)])?]
            }
            Kind::Expr(e) => {
                let k = self.exprs.iter().position(|x| x.text == *e).ok_or("expression not in this pass")?;
                if self.exprs[k].needs_temp && !self.has_temp[fog] {
                    return Err(format!(
                        "{}: expression `{e}` needs the temperature of FOG {fog} (column `fog{fog}_t_degc`)",
                        self.file
                    ));
                }
                vec![at(&[(Q::Expr(k), 1.0)])?]
            }
        })
    }

    /// The functional of y.
    pub fn y_functional(&self) -> Vec<f64> {
        let mut v = vec![0.0; self.m];
        v[self.y] = 1.0;
        v
    }
}

/// Compiles an expression over the session's columns and the per-FOG variables.
fn compile(e: &str, header: &Header) -> LabResult<ExprSlot> {
    let column = |name: &str| header.names.iter().position(|n| n == name);
    if let Some(c) = column(e) {
        return Ok(ExprSlot { text: e.into(), ex: None, vars: vec![Var::Column(c)], needs_temp: false });
    }
    let ex = exmex::parse::<f64>(e).map_err(|err| LabError::Model(format!("expression `{e}`: {err}")))?;
    let mut vars = Vec::new();
    for v in ex.var_names() {
        vars.push(match v.as_str() {
            "rate_rad_s" => Var::Rate,
            "t_degc" => Var::TAbs,
            "dt_degc" => Var::DTemp,
            "g_degc_s" => Var::TRate,
            "fog" => Var::Fog,
            name => Var::Column(column(name).ok_or_else(|| {
                LabError::Model(format!(
                    "expression `{e}`: `{v}` is not a column of {} (columns: {}; per FOG: rate_rad_s, t_degc, \
                     dt_degc, g_degc_s, fog)",
                    header.file,
                    header.names.join(", ")
                ))
            })?),
        });
    }
    let needs_temp = vars.iter().any(|v| matches!(v, Var::TAbs | Var::DTemp | Var::TRate));
    Ok(ExprSlot { text: e.into(), ex: Some(ex), vars, needs_temp })
}

/// G = dT/dt of every FOG, as [`temperature_rate`] defines it, over a stream:
/// samples are held until the window ahead of the oldest is complete. They are held as flat
/// records in one array (written and read in order, so the memory is streamed, not chased
/// through each sample's own vectors), with the times and temperatures in flat arrays beside
/// them (the window sums read those); the arrays drop what no later window can use, in
/// chunks.
struct Lookahead {
    half_s: f64,
    n_fog: usize,
    /// Held samples of global index `base ..`, one record each ([`Lookahead::push`]).
    records: Vec<f64>,
    /// f64 per record (0 before the first sample).
    rec: usize,
    /// Times and temperatures (n_fog per sample) of global index `base ..`.
    times: Vec<f64>,
    temps: Vec<f64>,
    base: usize,
    /// Next sample to emit.
    next: usize,
    /// Window of the last emitted sample (true window, before the fallback).
    lo: usize,
    hi: usize,
    /// Summed range [a, b] and its sums about the origin: n, Σu, Σu² (the same for every
    /// FOG), and per FOG Σv, Σuv.
    a: usize,
    b: usize,
    summed: bool,
    sums_t: [f64; 3],
    sums: Vec<[f64; 2]>,
    origin_t: f64,
    origin_temp: Vec<f64>,
    since_origin: usize,
    g: Vec<f64>,
}

impl Lookahead {
    fn new(n_fog: usize, window_s: f64) -> Self {
        Lookahead {
            half_s: window_s / 2.0 * (1.0 + 1e-9),
            n_fog,
            records: Vec::new(),
            rec: 0,
            times: Vec::new(),
            temps: Vec::new(),
            base: 0,
            next: 0,
            lo: 0,
            hi: 0,
            a: 0,
            b: 0,
            summed: false,
            sums_t: [0.0; 3],
            sums: vec![[0.0; 2]; n_fog],
            origin_t: 0.0,
            origin_temp: vec![0.0; n_fog],
            since_origin: 0,
            g: vec![0.0; n_fog],
        }
    }

    #[inline]
    fn t(&self, k: usize) -> f64 {
        self.times[k - self.base]
    }

    /// Holds a copy of a sample's record ([`SampleRef`]; all records of a stream are as
    /// long).
    fn push(&mut self, r: &[f64]) {
        let n = self.n_fog;
        if self.rec == 0 {
            self.rec = r.len();
        }
        self.times.push(r[0]);
        self.temps.extend_from_slice(&r[1 + n..1 + 2 * n]);
        self.records.extend_from_slice(&r[..self.rec]);
    }

    /// Sample k, borrowed from its record.
    #[inline]
    fn load(records: &[f64], rec: usize, n: usize, k: usize) -> SampleRef<'_> {
        SampleRef::of_record(&records[k * rec..(k + 1) * rec], n)
    }

    #[inline]
    fn add(&mut self, k: usize, sign: f64) {
        let u = self.t(k) - self.origin_t;
        let st = &mut self.sums_t;
        st[0] += sign;
        st[1] += sign * u;
        st[2] += sign * u * u;
        let row = (k - self.base) * self.n_fog;
        let temps = &self.temps[row..row + self.n_fog];
        for ((s, &t), &o) in self.sums.iter_mut().zip(temps).zip(&self.origin_temp) {
            let v = t - o;
            s[0] += sign * v;
            s[1] += sign * u * v;
        }
    }

    fn resum(&mut self, a: usize, b: usize, j: usize) {
        self.origin_t = self.t(j);
        let row = (j - self.base) * self.n_fog;
        self.origin_temp.copy_from_slice(&self.temps[row..row + self.n_fog]);
        self.sums_t = [0.0; 3];
        self.sums.iter_mut().for_each(|s| *s = [0.0; 2]);
        for k in a..=b {
            self.add(k, 1.0);
        }
        (self.a, self.b, self.summed, self.since_origin) = (a, b, true, 0);
    }

    /// Drops what no later window can use (from the window's start or the previous sample),
    /// once it is four times what stays (each held record is moved a quarter of a time on
    /// average).
    fn trim(&mut self) {
        let keep_from = self.a.min(self.lo).min(self.next.saturating_sub(1));
        let d = keep_from.saturating_sub(self.base);
        if d >= 4096 && d >= 4 * (self.times.len() - d) {
            self.records.drain(..d * self.rec);
            self.times.drain(..d);
            self.temps.drain(..d * self.n_fog);
            self.base += d;
        }
    }

    /// Emits every sample whose window is complete (all of them at the end, `last`).
    fn drain(&mut self, last: bool, mut f: impl FnMut(usize, &SampleRef, &[f64]) -> LabResult<()>) -> LabResult<()> {
        let end = self.base + self.times.len();
        while self.next < end {
            let j = self.next;
            let tj = self.t(j);
            if !last && self.t(end - 1) <= tj + self.half_s {
                break;
            }
            self.lo = self.lo.max(self.base);
            while self.t(self.lo) < tj - self.half_s {
                self.lo += 1;
            }
            self.hi = self.hi.max(self.lo);
            while self.hi + 1 < end && self.t(self.hi + 1) <= tj + self.half_s {
                self.hi += 1;
            }
            let (a, b) =
                if self.hi > self.lo { (self.lo, self.hi) } else { (j.saturating_sub(1), (j + 1).min(end - 1)) };
            if !self.summed || a < self.a || b < self.b || self.since_origin > 4096.max(4 * (b - a + 1)) {
                self.resum(a, b, j);
            } else {
                while self.b < b {
                    self.b += 1;
                    self.add(self.b, 1.0);
                }
                while self.a < a {
                    self.add(self.a, -1.0);
                    self.a += 1;
                }
            }
            self.since_origin += 1;
            // The least-squares slope of T over the window: (n Σuv − Σu Σv) / (n Σu² − (Σu)²).
            let [n, su, suu] = self.sums_t;
            let den = n * suu - su * su;
            for (g, s) in self.g.iter_mut().zip(&self.sums) {
                *g = if den.abs() < 1e-300 { 0.0 } else { (n * s[1] - su * s[0]) / den };
            }
            f(j, &Self::load(&self.records, self.rec, self.n_fog, j - self.base), &self.g)?;
            self.next += 1;
        }
        self.trim();
        Ok(())
    }
}

/// Runs the samples of `source` through the G window: `f(j, sample, G per FOG)` for every
/// sample j in order.
pub fn for_each_prepared(
    source: Source,
    n_fog: usize,
    g_window_s: f64,
    progress: Option<&ProgressBar>,
    f: impl FnMut(usize, &SampleRef, &[f64]) -> LabResult<()>,
) -> LabResult<usize> {
    for_each_prepared_until(source, n_fog, g_window_s, progress, usize::MAX, f)
}

/// [`for_each_prepared`] for the samples before `limit` only (reading stops once they are
/// out, a G window past the last of them).
pub fn for_each_prepared_until(
    source: Source,
    n_fog: usize,
    g_window_s: f64,
    progress: Option<&ProgressBar>,
    limit: usize,
    mut f: impl FnMut(usize, &SampleRef, &[f64]) -> LabResult<()>,
) -> LabResult<usize> {
    let mut la = Lookahead::new(n_fog, g_window_s);
    let mut g = |j: usize, s: &SampleRef, g: &[f64]| if j < limit { f(j, s, g) } else { Ok(()) };
    source.for_each(progress, |r| {
        la.push(r);
        la.drain(false, &mut g)?;
        Ok(la.next < limit)
    })?;
    la.drain(true, &mut g)?;
    Ok(la.next.min(limit))
}

/// Adds one batch per FOG to that FOG's sums (`grams[f]`, batch `batches[f]`: m columns
/// of [`BATCH`] values, [`COL`] apart, rows past `rows` zero, then a column of zeros).
/// The slots `order[..shared]` hold the same values for every FOG (quantities of the
/// sample, not of a FOG: 1, ω_ref, hours, B, user columns): their entries are summed
/// once, from the first FOG, and added to every FOG's sums. Each entry is one dot
/// product ([`gram_entry`]), the same bits whichever entries are summed with it.
fn accumulate_gram(grams: &mut [&mut Gram], batches: &[Vec<f64>], rows: usize, order: &[usize], shared: usize) {
    let Some(m) = grams.first().map(|g| g.m) else { return };
    // Per row of the triangle, in `order`: the other slots of its entries.
    let mut bs: Vec<usize> = Vec::with_capacity(m + 3);
    let mut vals = vec![0.0f64; m + 3];
    let mut first_shared = vec![0.0f64; m * m];
    for (f, (g, cols)) in grams.iter_mut().zip(batches).enumerate() {
        g.n += rows;
        for (i, &a) in order.iter().enumerate() {
            bs.clear();
            let from = if f > 0 && i < shared { shared } else { i };
            bs.extend_from_slice(&order[from..]);
            if f > 0 && i < shared {
                for &b in &order[i..shared] {
                    let k = a.min(b) * m + a.max(b);
                    g.upper[k] += first_shared[k];
                }
            }
            let n = bs.len();
            // Groups of four: the last padded with the zero column (m).
            while !bs.len().is_multiple_of(4) {
                bs.push(m);
            }
            gram_entries(cols, a, &bs, &mut vals[..bs.len()]);
            for (&b, &v) in bs.iter().zip(&vals).take(n) {
                let k = a.min(b) * m + a.max(b);
                g.upper[k] += v;
                if f == 0 && i < shared {
                    first_shared[k] = v;
                }
            }
        }
    }
}

/// The dot products of column a with columns `bs` (a multiple of four of them) of a batch
/// (columns of [`BATCH`] values, [`COL`] apart), into `out`.
#[inline]
fn gram_entries(cols: &[f64], a: usize, bs: &[usize], out: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked above).
        unsafe { gram_entries_avx2(cols, a, bs, out) };
        return;
    }
    for (o, &b) in out.iter_mut().zip(bs) {
        *o = gram_entry(cols, a, b);
    }
}

/// One entry of the Gram sums of a batch: columns a and b, eight partial sums (partial sum
/// l takes rows l, l + 8, ...), added pairwise in a fixed order, so the result does not
/// depend on the vector width the compiler uses (and no fused multiply-add changes the
/// rounding).
#[inline(always)]
fn gram_entry(cols: &[f64], a: usize, b: usize) -> f64 {
    let (ca, cb) = (&cols[a * COL..a * COL + BATCH], &cols[b * COL..b * COL + BATCH]);
    let mut acc = [0.0f64; 8];
    for (x, y) in ca.chunks_exact(8).zip(cb.chunks_exact(8)) {
        for l in 0..8 {
            acc[l] += x[l] * y[l];
        }
    }
    combine8(&acc)
}

/// The eight partial sums of a Gram entry added in their fixed order.
#[inline(always)]
fn combine8(acc: &[f64; 8]) -> f64 {
    ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
}

/// [`gram_entries`] with AVX2: four entries at a time (eight vector sums in flight instead
/// of two, so the adds do not wait on each other); partial sums l = 0–3 and 4–7 of each
/// entry in two vectors, separate multiply and add, the same operations in the same order
/// as [`gram_entry`] (the same bits).
///
/// # Safety
///
/// The CPU must have AVX2; `bs` a multiple of four columns, each (and a) in `cols`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gram_entries_avx2(cols: &[f64], a: usize, bs: &[usize], out: &mut [f64]) {
    use std::arch::x86_64::{
        __m256d, _mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_setzero_pd, _mm256_storeu_pd,
    };
    let ca = &cols[a * COL..a * COL + BATCH];
    for (group, out) in bs.chunks_exact(4).zip(out.chunks_exact_mut(4)) {
        let cb: [&[f64]; 4] = [0, 1, 2, 3].map(|k| &cols[group[k] * COL..group[k] * COL + BATCH]);
        let mut lo: [__m256d; 4] = [_mm256_setzero_pd(); 4];
        let mut hi: [__m256d; 4] = [_mm256_setzero_pd(); 4];
        for i in (0..BATCH).step_by(8) {
            // SAFETY: i + 8 ≤ BATCH, the length of every column slice.
            let (xl, xh) = unsafe { (_mm256_loadu_pd(ca.as_ptr().add(i)), _mm256_loadu_pd(ca.as_ptr().add(i + 4))) };
            for (k, (l, h)) in lo.iter_mut().zip(hi.iter_mut()).enumerate() {
                // SAFETY: as above.
                let (yl, yh) = unsafe {
                    let q = cb[k].as_ptr().add(i);
                    (_mm256_loadu_pd(q), _mm256_loadu_pd(q.add(4)))
                };
                *l = _mm256_add_pd(*l, _mm256_mul_pd(xl, yl));
                *h = _mm256_add_pd(*h, _mm256_mul_pd(xh, yh));
            }
        }
        for (o, (l, h)) in out.iter_mut().zip(lo.iter().zip(&hi)) {
            let mut acc = [0.0f64; 8];
            // SAFETY: `acc` has room for two vectors of four.
            unsafe {
                _mm256_storeu_pd(acc.as_mut_ptr(), *l);
                _mm256_storeu_pd(acc.as_mut_ptr().add(4), *h);
            }
            *o = combine8(&acc);
        }
    }
}

/// What a pass needs to know.
#[derive(Debug, Clone)]
pub struct DigestSpec {
    /// Every term any fit on the digest will use (its sinusoids and expressions get slots).
    pub kinds: Vec<Kind>,
    /// T_ref, °C.
    pub t_ref_degc: f64,
    /// The model's G window, s (0: automatic, [`effective_window_s`]).
    pub g_window_s: f64,
    /// Time blocks.
    pub n_blocks: usize,
    /// Rows kept at most.
    pub keep: usize,
    /// Terms whose all-rows fit's largest |residual| the pass is to make provable without a
    /// second pass ([`Extremes`]), when it does not keep every row.
    pub track: Option<Vec<Kind>>,
}

/// The G window in use: `g_window_s`, or max(2 × the sample interval, 60 s) when it is 0.
pub fn effective_window_s(g_window_s: f64, dt_s: f64) -> f64 {
    if g_window_s > 0.0 {
        g_window_s
    } else {
        (2.0 * dt_s).max(60.0)
    }
}

/// Rows kept by a pass: every `stride`-th, with their basis vectors (shifted) and the
/// quantities residuals are plotted against.
#[derive(Debug, Clone, Default)]
pub struct Kept {
    /// Every this many rows.
    pub stride: usize,
    /// Row indices.
    pub rows: Vec<usize>,
    /// Their times, s.
    pub t_s: Vec<f64>,
    /// Their blocks.
    pub block: Vec<usize>,
    /// Azimuth ψ where the session has it, rad.
    pub psi_rad: Option<Vec<f64>>,
    /// Reference rate, rad/s.
    pub omega_rad_s: Vec<[f64; 3]>,
    /// Field, nT, where the session has it.
    pub field_nt: Option<Vec<[f64; 3]>>,
    /// Per FOG with a temperature: T, °C, and G, °C/s.
    pub temp: Vec<Option<(Vec<f64>, Vec<f64>)>>,
    /// Per FOG, the shifted basis vectors, row-major (rows × m).
    pub z: Vec<Vec<f64>>,
}

impl Kept {
    /// Keeps row `j` of block `block`: sample `s`, its G per FOG `g`, its azimuth from
    /// column `psi_col` (the basis vectors are kept by the pass).
    fn push_row(&mut self, j: usize, block: usize, s: &SampleRef, g: &[f64], psi_col: Option<usize>) {
        self.rows.push(j);
        self.t_s.push(s.t_s);
        self.block.push(block);
        if let (Some(p), Some(c)) = (self.psi_rad.as_mut(), psi_col) {
            p.push(s.values[c]);
        }
        self.omega_rad_s.push(s.ref_rad_s);
        if let Some(f) = self.field_nt.as_mut() {
            f.push(s.field_nt);
        }
        for (i, t) in self.temp.iter_mut().enumerate() {
            if let Some((temp, rate)) = t.as_mut() {
                temp.push(s.t_degc[i]);
                rate.push(g[i]);
            }
        }
    }
}

/// Rows of the first segment (held until the fit on them ranks them).
pub const FIRST_SEGMENT: usize = 16_384;

impl Extremes {
    /// Rows of segment k: the first, then twice as many as the segment before, up to
    /// `segment`.
    pub fn len_of(&self, k: usize) -> usize {
        match k {
            0 => self.first,
            _ => self.first.saturating_mul(1 << (k - 1).min(32)).min(self.segment),
        }
    }

    /// Samples in the first `k` segments.
    pub fn rows_in(&self, k: usize) -> usize {
        (0..k).map(|i| self.len_of(i)).sum()
    }
}

/// One segment's candidates for the largest |residual| of one FOG: its rows, in order, cut
/// into boxes of a few seconds; per box, the range of each z̃_a, the two largest and the two
/// smallest r = ell·z̃ under the segment's ranking functional, and the rows of the largest and
/// the smallest.
#[derive(Debug, Clone, Default)]
pub struct SegmentExtremes {
    /// The ranking functional ℓ_s (shifted basis): the all-rows fit of the rows before.
    pub ell: Vec<f64>,
    /// Rows per box.
    pub box_rows: usize,
    /// Per box, per slot, the smallest z̃_a (box-major, m a box).
    pub lo: Vec<f64>,
    /// Per box, per slot, the largest z̃_a.
    pub hi: Vec<f64>,
    /// Per box: the largest r, the second largest, the smallest, the second smallest (−∞ or
    /// +∞ where the box has too few rows).
    pub r: Vec<[f64; 4]>,
    /// Per box, the rows of the largest and of the smallest r (box-major, 2m a box).
    pub rows: Vec<f64>,
    /// Rows offered so far.
    seen: usize,
}

impl SegmentExtremes {
    fn new(box_rows: usize) -> Self {
        SegmentExtremes { box_rows: box_rows.max(1), ..Default::default() }
    }

    /// The bound on |ℓ·z̃| of the segment's rows not stored, for a residual functional ℓ.
    /// In a box (lo ≤ z̃ ≤ hi, centre c, half widths h), with d = ℓ − ℓ_s, a row has
    /// ℓ·z̃ = ℓ_s·z̃ + d·z̃ and d·z̃ within d·c ± Σ_a |d_a| h_a; a row not stored has ℓ_s·z̃
    /// between the box's second smallest and second largest. The largest over the boxes, plus
    /// 10⁻¹² of Σ_a max|z̃_a| (|ℓ_a| + |ℓ_s,a|) for the rounding of the sums (each a few
    /// ulps). A box is a few seconds of a session, where the reference rate and the
    /// temperature hardly move: d·z̃ is nearly the constant d·c there, however far the two
    /// fits are apart, and the bound is close to the box's own extremes under ℓ.
    pub fn bound(&self, ell: &[f64]) -> f64 {
        let m = ell.len().max(1);
        let mut worst = 0.0f64;
        for ((lo, hi), r) in self.lo.chunks_exact(m).zip(self.hi.chunks_exact(m)).zip(&self.r) {
            let [_, below_top, _, above_bottom] = *r;
            if below_top < above_bottom {
                continue; // every row of the box stored
            }
            let (mut dc, mut dh, mut scale) = (0.0, 0.0, 0.0);
            for (((&lo, &hi), &l), &ls) in lo.iter().zip(hi).zip(ell).zip(&self.ell) {
                let (c, h, d) = (0.5 * (lo + hi), 0.5 * (hi - lo), l - ls);
                dc += d * c;
                dh += d.abs() * h;
                scale += lo.abs().max(hi.abs()) * (l.abs() + ls.abs());
            }
            let b = (below_top + dc + dh).max(-(above_bottom + dc - dh)) + 1e-12 * scale;
            worst = worst.max(b);
        }
        worst
    }

    /// Takes `rows` rows with their r: slot a of the k-th is `cols[a * stride + k]`.
    fn take(&mut self, rows: usize, m: usize, r: &[f64], cols: &[f64], stride: usize) {
        let mut k0 = 0;
        while k0 < rows {
            let (bx, within) = ((self.seen + k0) / self.box_rows, (self.seen + k0) % self.box_rows);
            let k1 = rows.min(k0 + self.box_rows - within);
            if self.r.len() <= bx {
                self.lo.resize((bx + 1) * m, f64::INFINITY);
                self.hi.resize((bx + 1) * m, f64::NEG_INFINITY);
                self.r.resize(bx + 1, [f64::NEG_INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::INFINITY]);
                self.rows.resize((bx + 1) * 2 * m, 0.0);
            }
            let (lo, hi) = (&mut self.lo[bx * m..(bx + 1) * m], &mut self.hi[bx * m..(bx + 1) * m]);
            for (a, (lo, hi)) in lo.iter_mut().zip(hi.iter_mut()).enumerate() {
                // Four running minima and maxima (exact, the values finite: any order gives
                // the same values).
                let col = &cols[a * stride + k0..a * stride + k1];
                let (mut l, mut h) = ([*lo; 4], [*hi; 4]);
                let mut quads = col.chunks_exact(4);
                for c in &mut quads {
                    for q in 0..4 {
                        l[q] = if c[q] < l[q] { c[q] } else { l[q] };
                        h[q] = if c[q] > h[q] { c[q] } else { h[q] };
                    }
                }
                for &v in quads.remainder() {
                    l[0] = if v < l[0] { v } else { l[0] };
                    h[0] = if v > h[0] { v } else { h[0] };
                }
                *lo = l[0].min(l[1]).min(l[2].min(l[3]));
                *hi = h[0].max(h[1]).max(h[2].max(h[3]));
            }
            let t = &mut self.r[bx];
            let stored = &mut self.rows[bx * 2 * m..(bx + 1) * 2 * m];
            for (k, &v) in r.iter().enumerate().take(k1).skip(k0) {
                if v > t[1] {
                    if v > t[0] {
                        (t[1], t[0]) = (t[0], v);
                        stored[..m].iter_mut().enumerate().for_each(|(a, x)| *x = cols[a * stride + k]);
                    } else {
                        t[1] = v;
                    }
                }
                if v < t[3] {
                    if v < t[2] {
                        (t[3], t[2]) = (t[2], v);
                        stored[m..].iter_mut().enumerate().for_each(|(a, x)| *x = cols[a * stride + k]);
                    } else {
                        t[3] = v;
                    }
                }
            }
            k0 = k1;
        }
        self.seen += rows;
    }

    /// Takes row `z` (r = ell·z summed in slot order).
    fn offer(&mut self, z: &[f64], m: usize) {
        let r: f64 = self.ell.iter().zip(z).fold(0.0, |s, (a, b)| s + a * b);
        self.take(1, m, &[r], z, 1);
    }

    /// [`SegmentExtremes::offer`] for a batch of rows held column-major in `cols` (m columns
    /// of [`BATCH`] values, [`COL`] apart, rows past `rows` zero): every r summed side by side over the
    /// rows, each in slot order from 0 (as `offer` sums it: the same bits).
    fn offer_batch(&mut self, cols: &[f64], rows: usize, m: usize) {
        let mut r = [0.0f64; BATCH];
        for (e, col) in self.ell.iter().zip(cols.chunks_exact(COL)) {
            for (r, v) in r.iter_mut().zip(col) {
                *r += e * v;
            }
        }
        self.take(rows, m, &r, cols, COL);
    }
}

/// What makes the largest |residual| over every row provable after one pass: the session cut
/// into segments (the first [`FIRST_SEGMENT`] rows, then each twice the one before up to 1/64
/// of the session or that many, whichever is more; the early fits are the least sure, their
/// segments the shortest), each segment's rows ranked under the fit of every row before it
/// (the first segment: under its own fit) box by box, a few seconds a box, at most 8192
/// boxes (the memory is bounded): [`SegmentExtremes`]. For final coefficients with residual
/// functional ℓ, the rows stored are evaluated and every other row is bounded
/// ([`SegmentExtremes::bound`]); when the largest |ℓ·z̃| of the stored rows is at least every
/// segment's bound, it is the maximum over all rows (`super::fit` checks; otherwise it reads
/// again the segments up to the last whose bound is above).
#[derive(Debug, Clone, Default)]
pub struct Extremes {
    /// Rows in the first segment.
    pub first: usize,
    /// Rows per later segment at most ([`Extremes::len_of`]).
    pub segment: usize,
    /// Per segment, per FOG.
    pub segs: Vec<Vec<SegmentExtremes>>,
}

/// The running side of [`Extremes`] during a pass.
struct Tracker {
    kinds: Vec<Kind>,
    out: Extremes,
    /// Rows of the first segment, per FOG (ranked once its fit is known).
    first: Vec<Vec<f64>>,
}

impl Tracker {
    /// Offers a summed batch (`rows` rows, m columns [`COL`] apart per FOG) to the current
    /// segment's extremes, or holds its rows (row-major) while the first segment is open.
    fn offer_batch(&mut self, batch: &[Vec<f64>], rows: usize, m: usize) {
        match self.out.segs.last_mut() {
            None => {
                for (f, b) in self.first.iter_mut().zip(batch.iter()) {
                    for i in 0..rows {
                        f.extend((0..m).map(|a| b[a * COL + i]));
                    }
                }
            }
            Some(seg) => {
                for (x, b) in seg.iter_mut().zip(batch.iter()) {
                    x.offer_batch(b, rows, m);
                }
            }
        }
    }

    /// Starts a segment ranked under the all-rows fit of the sums so far; at the end of the
    /// first segment, first ranks the rows held under that same fit.
    fn open_segment(&mut self, basis: &Basis, shift: &[Vec<f64>], gram: &[Vec<Gram>], box_rows: usize) {
        let m = basis.m;
        let ells: Vec<Vec<f64>> =
            (0..shift.len()).map(|fog| self.running_ell(basis, &shift[fog], &gram[fog], fog)).collect();
        if self.out.segs.is_empty() {
            // The first segment, ranked under its own fit.
            let mut seg = Vec::new();
            for (fog, ell) in ells.iter().enumerate() {
                let mut x = SegmentExtremes::new(box_rows);
                x.ell = ell.clone();
                for row in self.first[fog].chunks_exact(m) {
                    x.offer(row, m);
                }
                seg.push(x);
            }
            self.out.segs.push(seg);
            self.first = Vec::new();
        }
        self.out.segs.push(
            ells.into_iter()
                .map(|ell| {
                    let mut x = SegmentExtremes::new(box_rows);
                    x.ell = ell;
                    x
                })
                .collect(),
        );
    }

    /// The residual functional of the all-rows fit of the sums so far, FOG `fog`.
    fn running_ell(&self, basis: &Basis, shift: &[f64], gram: &[Gram], fog: usize) -> Vec<f64> {
        let mut g = Gram::new(basis.m);
        for x in gram {
            g.add(x);
        }
        let sh = |l: &[f64]| shifted(l, shift);
        let mut cols: Vec<Vec<f64>> = Vec::new();
        for k in &self.kinds {
            if let Ok(f) = basis.functionals(k, fog) {
                cols.extend(f.iter().map(|l| sh(l)));
            }
        }
        cols.push(sh(&basis.y_functional()));
        let ls = lstsq_gram(&design_gram(&g, &cols), g.n);
        residual_functional(&cols, &ls.coef)
    }
}

/// One pass over a session: per FOG and block the Gram of the shifted basis, and kept rows.
#[derive(Debug, Clone)]
pub struct Digest {
    /// Session file.
    pub file: String,
    /// Header names.
    pub names: Vec<String>,
    /// User (extra) columns.
    pub extra_columns: Vec<String>,
    /// Samples.
    pub n: usize,
    /// Time blocks.
    pub n_blocks: usize,
    /// Sample interval, s.
    pub dt_s: f64,
    /// Time of the first and last sample, s.
    pub t_span_s: [f64; 2],
    /// The G window used, s.
    pub g_window_s: f64,
    /// The basis.
    pub basis: Basis,
    /// Per FOG, the shift subtracted from each slot (slot 0: none).
    pub shift: Vec<Vec<f64>>,
    /// Per FOG, per block.
    pub gram: Vec<Vec<Gram>>,
    /// Kept rows.
    pub kept: Kept,
    /// Bins of every row (consecutive rows of one block; [`super::noise`]).
    pub bins: Bins,
    /// Per FOG, the sums of the shifted basis over each bin (bins × m, row-major).
    pub bin_sum: Vec<Vec<f64>>,
    /// Gaps in time: steps of more than [`GAP_FACTOR`] sample intervals.
    pub gaps: Gaps,
    /// Candidates for the largest |residual| (when the spec tracks terms and not every row
    /// is kept).
    pub extremes: Option<Extremes>,
}

/// A step in time of more than this many sample intervals (the median) is a gap.
pub const GAP_FACTOR: f64 = 2.5;

/// The gaps in time of a session ([`GAP_FACTOR`]).
#[derive(Debug, Clone, Default)]
pub struct Gaps {
    /// How many.
    pub count: usize,
    /// The largest: the time before it, s, and its length, s.
    pub largest: Option<(f64, f64)>,
    /// Time missing in all, s (the gaps less one sample interval each).
    pub missing_s: f64,
}

/// Rows summed at a time before they are added to a block's sums (a multiple of 8).
const BATCH: usize = 256;

/// The per-bin sums of the basis a pass accumulates, a batch at a time.
struct BinAcc {
    bins: Bins,
    sum: Vec<Vec<f64>>,
    /// The bin of the last row added.
    at: usize,
}

impl BinAcc {
    /// Adds the `rows` rows of a batch (per FOG, m columns [`COL`] apart) whose first row
    /// is row `j0` of the session.
    fn add(&mut self, batch: &[Vec<f64>], j0: usize, rows: usize, m: usize) {
        let mut i = 0;
        while i < rows {
            while self.bins.start.get(self.at + 1).is_some_and(|&e| e <= j0 + i) {
                self.at += 1;
            }
            if self.at >= self.bins.len() {
                return; // rows past the count of the pre-pass (refused after the pass)
            }
            let end = self.bins.start.get(self.at + 1).map_or(rows, |&e| (e - j0).min(rows));
            for (sum, cols) in self.sum.iter_mut().zip(batch) {
                let out = &mut sum[self.at * m..(self.at + 1) * m];
                for (a, o) in out.iter_mut().enumerate() {
                    *o += cols[a * COL + i..a * COL + end].iter().sum::<f64>();
                }
            }
            i = end.max(i + 1);
        }
    }
}

/// The quantities a batch's columns are computed from ([`Basis::fill_batch`]), staged a
/// row at a time, one array of [`BATCH`] rows per quantity (per FOG where it is one).
struct Staged {
    t_s: Vec<f64>,
    /// Raw rate, rad/s, FOG-major.
    rate: Vec<f64>,
    /// T, °C, FOG-major.
    temp: Vec<f64>,
    /// G, °C/s, FOG-major.
    g: Vec<f64>,
    /// ω_ref, component-major.
    w: Vec<f64>,
    /// Field, nT, component-major.
    field: Vec<f64>,
    /// The table's bare columns, column-major.
    cols: Vec<f64>,
}

impl Staged {
    fn new(n_fog: usize, n_cols: usize) -> Self {
        Staged {
            t_s: vec![0.0; BATCH],
            rate: vec![0.0; n_fog * BATCH],
            temp: vec![0.0; n_fog * BATCH],
            g: vec![0.0; n_fog * BATCH],
            w: vec![0.0; 3 * BATCH],
            field: vec![0.0; 3 * BATCH],
            cols: vec![0.0; n_cols * BATCH],
        }
    }

    /// Stages sample `s` with its G per FOG as row i of the batch.
    #[inline]
    fn put(&mut self, i: usize, s: &SampleRef, g_degc_s: &[f64], gather_cols: &[usize]) {
        self.t_s[i] = s.t_s;
        for (k, ((&x, &t), &g)) in s.rate_rad_s.iter().zip(s.t_degc).zip(g_degc_s).enumerate() {
            self.rate[k * BATCH + i] = x;
            self.temp[k * BATCH + i] = t;
            self.g[k * BATCH + i] = g;
        }
        for k in 0..3 {
            self.w[k * BATCH + i] = s.ref_rad_s[k];
            self.field[k * BATCH + i] = s.field_nt[k];
        }
        for (k, &c) in gather_cols.iter().enumerate() {
            self.cols[k * BATCH + i] = s.values[c];
        }
    }
}

/// Distance between two columns of a batch, f64: a batch's column is [`BATCH`] values and
/// then a gap, so that the columns (written a row at a time, one value each) do not all fall
/// in the same few sets of the L1 cache, as a power-of-two distance makes them.
const COL: usize = BATCH + 8;

/// The block of sample j of n: `j · n_blocks / n` (even blocks train, odd blocks test).
pub fn block_of(j: usize, n: usize, n_blocks: usize) -> usize {
    j * n_blocks / n.max(1)
}

/// ℓ of the raw basis as a functional of the basis shifted by `shift`: ℓ·z = ℓ·z̃ + (ℓ·shift)·1.
fn shifted(l: &[f64], shift: &[f64]) -> Vec<f64> {
    let mut v = l.to_vec();
    v[ONE] += l.iter().zip(shift).map(|(a, b)| a * b).sum::<f64>();
    v
}

/// One pass over `source`.
///
/// Longer than a function should be, for a reason: it is the lab's hot loop. The per-row
/// closure and the batch flush share a dozen locals (the batch, the Gram sums, the counters
/// of block, segment and kept row, the first row's shift); held in one frame they stay
/// registers and stack slots the compiler sees whole, and the pass's speed (BENCHMARKS.md)
/// depends on that. What runs once per segment, batch or kept row is in methods of
/// `Tracker` and [`Kept`].
pub fn digest(source: Source, spec: &DigestSpec, progress: Option<&ProgressBar>) -> LabResult<Digest> {
    let shape = source.shape()?;
    if let Some(pb) = progress {
        pb.set_length(shape.bytes);
    }
    let h = &shape.header;
    let n = shape.samples;
    let nb = spec.n_blocks.max(2);
    let basis = Basis::new(h, &spec.kinds, shape.t_span_s[0], spec.t_ref_degc)?;
    let (m, n_fog) = (basis.m, basis.n_fog);
    let g_window_s = effective_window_s(spec.g_window_s, shape.dt_s);
    let stride = n.div_ceil(spec.keep.max(1)).max(1);
    let psi_col = h.layout.turntable.map(|[p, _]| p);
    let mut kept = Kept {
        stride,
        psi_rad: psi_col.map(|_| Vec::new()),
        field_nt: basis.has_field.then(Vec::new),
        temp: basis.has_temp.iter().map(|&t| t.then(|| (Vec::new(), Vec::new()))).collect(),
        z: vec![Vec::new(); n_fog],
        ..Kept::default()
    };
    let mut gram = vec![vec![Gram::new(m); nb]; n_fog];
    let bins = Bins::every_row(n, nb, shape.dt_s);
    let mut bin_acc = BinAcc { sum: vec![vec![0.0; bins.len() * m]; n_fog], bins, at: 0 };
    let mut shift: Vec<Vec<f64>> = Vec::new();
    // Per FOG a batch of rows, column-major (m columns of BATCH values, COL apart) for the Gram sums,
    // and a column of zeros after them (what pads the Gram sums' groups of four).
    let mut batch: Vec<Vec<f64>> = vec![vec![0.0; COL * (m + 1)]; n_fog];
    let (order, shared) = basis.gram_order();
    let (mut batch_rows, mut batch_block) = (0usize, 0usize);
    let mut z = vec![0.0; m];
    // Boxes of a few seconds, at most 8192 in a session (the memory is bounded).
    let box_rows = n.div_ceil(8192).max(1024);
    let mut tracker = spec.track.clone().filter(|_| stride > 1).map(|kinds| Tracker {
        kinds,
        out: Extremes { first: FIRST_SEGMENT, segment: (n / 64).max(FIRST_SEGMENT), segs: Vec::new() },
        first: vec![Vec::new(); n_fog],
    });
    // Rows of the batch staged for their columns ([`Basis::fill_batch`]) and, of these, the
    // kept ones (their basis vectors are kept once computed).
    let batched = basis.batched();
    let mut staged = Staged::new(n_fog, basis.gather_cols.len());
    let mut kept_at: Vec<usize> = Vec::new();
    // A batch summed: its staged columns computed, added to the Gram sums and offered to the
    // extremes (the first segment's rows held, row-major, until its fit ranks them).
    let flush = |batch: &mut [Vec<f64>],
                 rows: usize,
                 gram: &mut Vec<Vec<Gram>>,
                 block: usize,
                 tracker: Option<&mut Tracker>,
                 shift: &[Vec<f64>],
                 staged: &Staged,
                 kept_at: &mut Vec<usize>,
                 kept_z: &mut [Vec<f64>],
                 bin_acc: &mut BinAcc,
                 j0: usize| {
        if rows == 0 {
            return;
        }
        if batched {
            for (fog, (b, kz)) in batch.iter_mut().zip(kept_z.iter_mut()).enumerate() {
                basis.fill_batch(fog, staged, rows, &shift[fog], b);
                for &i in kept_at.iter() {
                    kz.extend((0..m).map(|a| b[a * COL + i]));
                }
            }
            kept_at.clear();
        }
        if rows < BATCH {
            for b in batch.iter_mut() {
                b.chunks_exact_mut(COL).for_each(|col| col[rows..BATCH].fill(0.0));
            }
        }
        bin_acc.add(batch, j0, rows, m);
        let mut grams: Vec<&mut Gram> = gram.iter_mut().map(|g| &mut g[block]).collect();
        accumulate_gram(&mut grams, batch, rows, &order, shared);
        if let Some(t) = tracker {
            t.offer_batch(batch, rows, m);
        }
    };
    // The batch so far summed; its first row is row `$j0` of the session.
    macro_rules! flush_batch {
        ($j0:expr) => {
            flush(
                &mut batch,
                batch_rows,
                &mut gram,
                batch_block,
                tracker.as_mut(),
                &shift,
                &staged,
                &mut kept_at,
                &mut kept.z,
                &mut bin_acc,
                $j0,
            )
        };
    }
    // The block, segment and kept-row tests by counters (j goes 0, 1, 2, ...): the block of j
    // changes at the first j with j · nb / n above the current block.
    let (mut block, mut next_block) = (0usize, 0usize);
    let mut next_segment = tracker.as_ref().map_or(usize::MAX, |t| t.out.first);
    let mut next_keep = 0usize;
    let (mut gaps, mut prev_t) = (Gaps::default(), f64::NAN);
    let seen = for_each_prepared(source, n_fog, g_window_s, progress, |j, s, g| {
        let step = s.t_s - prev_t;
        if step > GAP_FACTOR * shape.dt_s {
            gaps.count += 1;
            gaps.missing_s += step - shape.dt_s;
            if gaps.largest.is_none_or(|(_, l)| step > l) {
                gaps.largest = Some((prev_t, step));
            }
        }
        prev_t = s.t_s;
        if j >= next_block {
            block = block_of(j, n, nb).min(nb - 1);
            next_block = if block + 1 >= nb { usize::MAX } else { ((block + 1) * n.max(1)).div_ceil(nb) };
        }
        let new_segment = j == next_segment;
        if let (true, Some(t)) = (new_segment, tracker.as_ref()) {
            // The segment starting here is the second when none is out yet.
            next_segment += t.out.len_of(t.out.segs.len().max(1));
        }
        if block != batch_block || batch_rows == BATCH || new_segment {
            flush_batch!(j - batch_rows);
            (batch_rows, batch_block) = (0, block);
        }
        if let (Some(t), true) = (tracker.as_mut(), new_segment) {
            t.open_segment(&basis, &shift, &gram, box_rows);
        }
        let keep = j == next_keep;
        if keep {
            next_keep += stride;
            kept.push_row(j, block, s, g, psi_col);
        }
        if shift.len() < n_fog {
            // The first row: the shift is its basis vector (slot 0 stays 1).
            for _ in 0..n_fog {
                basis.fill(shift.len(), s, g, &mut z)?;
                let mut sh = z.clone();
                sh[ONE] = 0.0;
                shift.push(sh);
            }
        }
        if batched {
            staged.put(batch_rows, s, g, &basis.gather_cols);
            if keep {
                kept_at.push(batch_rows);
            }
        } else {
            for fog in 0..n_fog {
                basis.fill(fog, s, g, &mut z)?;
                let col = &mut batch[fog][batch_rows..];
                for (a, (v, sh)) in z.iter_mut().zip(&shift[fog]).enumerate() {
                    *v -= sh;
                    col[a * COL] = *v;
                }
                if keep {
                    kept.z[fog].extend_from_slice(&z);
                }
            }
        }
        batch_rows += 1;
        Ok(())
    })?;
    flush_batch!(seen - batch_rows);
    if seen != n {
        return Err(LabError::Numeric(format!(
            "{}: {seen} samples read, {n} counted before: did the file change while it was read?",
            h.file
        )));
    }
    check_rate_columns(h, &basis, &shift, &kept)?;
    let extra_columns = h
        .names
        .iter()
        .zip(&h.roles)
        .filter(|(_, r)| **r == super::session::Role::Extra)
        .map(|(n, _)| n.clone())
        .collect();
    Ok(Digest {
        file: h.file.clone(),
        names: h.names.clone(),
        extra_columns,
        n,
        n_blocks: nb,
        dt_s: shape.dt_s,
        t_span_s: shape.t_span_s,
        g_window_s,
        basis,
        shift,
        gram,
        kept,
        bins: bin_acc.bins,
        bin_sum: bin_acc.sum,
        gaps,
        extremes: tracker.map(|t| t.out).filter(|e| !e.segs.is_empty()),
    })
}

/// Refuses a FOG column whose values are not that FOG's rate in rad/s: at the kept rows, the
/// FOG's output ω against its reference rate r = s⁰·ω_ref (where r varies or is large:
/// RMS above 2 °/h, the Earth rate on most axes) has q = Σωr / Σr² near 1 (scale factor,
/// bias and misalignment move it by far less than 0.5). Near −1 the sign is flipped (a FOG
/// wired or mounted the other way); near 57.3 or 206,265 the column holds °/s or °/h; any
/// other q far from 1 is named too. Where r is too small for q (an east axis on a level
/// turntable), an error ω − r of more than [`MAX_ERROR_DEG_H`] RMS is named instead.
/// The largest RMS of a FOG's error about its reference rate a session may have, °/h (a
/// bias of the lab's FOGs is a fraction of a °/h; the table's plausible range ends far below).
const MAX_ERROR_DEG_H: f64 = 360.0;

fn check_rate_columns(h: &Header, basis: &Basis, shift: &[Vec<f64>], kept: &Kept) -> LabResult<()> {
    let axes = nominal_axes();
    for (fog, z) in kept.z.iter().enumerate() {
        let Some(sh) = shift.get(fog) else { continue };
        let a = axes[fog.min(3)];
        let (mut sxr, mut srr, mut syy) = (0.0, 0.0, 0.0);
        for (zk, w) in z.chunks_exact(basis.m).zip(&kept.omega_rad_s) {
            let r = a.x * w[0] + a.y * w[1] + a.z * w[2];
            let y = zk[basis.y] + sh[basis.y];
            sxr += (y + r) * r;
            srr += r * r;
            syy += y * y;
        }
        let n = kept.omega_rad_s.len().max(1) as f64;
        let dh = |x: f64| (x / n).sqrt() * ssis_common::DEG_H_PER_RAD_S;
        let q = if dh(srr) < 2.0 { 1.0 } else { sxr / srr };
        let near = |x: f64, tol: f64| (q / x - 1.0).abs() < tol;
        let what = if (q - 1.0).abs() < 0.5 {
            // The error ω − r: bias and drift of a few °/h at most.
            if dh(syy) < MAX_ERROR_DEG_H {
                continue;
            }
            format!(
                "its error about the reference rate is {:.0} °/h RMS, beyond any FOG's bias and drift ({MAX_ERROR_DEG_H} °/h): \
                 a column in another unit (°/h or °/s)?",
                dh(syy)
            )
        } else {
            let why = if (q + 1.0).abs() < 0.5 {
                "its sign looks flipped (the FOG's output is minus its reference rate)".to_string()
            } else if near(180.0 / std::f64::consts::PI, 0.2) {
                "it looks like °/s, not rad/s (57.3 × the reference rate)".to_string()
            } else if near(ssis_common::DEG_H_PER_RAD_S, 0.2) {
                "it looks like °/h, not rad/s (206,265 × the reference rate)".to_string()
            } else {
                format!("its values are {q:.4} × the reference rate (another unit or another FOG's axis?)")
            };
            format!(
                "{why}: Σωr/Σr² = {q:.4} over {} rows against the reference rate r = s⁰·ω_ref ({:.2} °/h RMS); a \
                 FOG's rate in rad/s gives about 1",
                kept.omega_rad_s.len(),
                dh(srr)
            )
        };
        let name = format!("fog{fog}_rad_s");
        let column = h.names.iter().position(|c| *c == name).map(|k| (k + 1, name));
        return Err(LabError::Session(super::session::SessionError {
            kind: super::session::SessionErrorKind::BadValue,
            file: h.file.clone(),
            line: h.line.max(1),
            column,
            message: what,
        }));
    }
    Ok(())
}

impl Digest {
    /// What the user should know about the session the figures do not say: its gaps in time
    /// (the lab takes rows as equally spaced: the time blocks, the noise model's bins, τ-means
    /// and Allan deviations count rows, so a window or bin over a gap joins times apart).
    pub fn notes(&self) -> Vec<String> {
        let mut v = Vec::new();
        if let Some((t, len)) = self.gaps.largest {
            v.push(format!(
                "{}: {} gap(s) in time, {:.1} s missing in all, the largest {:.1} s after t = {} s (sample interval \
                 {} s): the lab takes rows as equally spaced (time blocks, the noise model's bins, tau-means and \
                 Allan deviations count rows), so figures over a gap join times apart",
                self.file, self.gaps.count, self.gaps.missing_s, len, t, self.dt_s
            ));
        }
        v
    }

    /// A functional of the raw basis as one of the shifted basis: x = ℓ·z = ℓ·z̃ + (ℓ·shift)·1.
    pub fn shifted(&self, fog: usize, l: &[f64]) -> Vec<f64> {
        shifted(l, &self.shift[fog])
    }

    /// The sums of FOG `fog` over the blocks `pick` selects.
    pub fn gram_of(&self, fog: usize, pick: impl Fn(usize) -> bool) -> Gram {
        let mut g = Gram::new(self.basis.m);
        for (b, x) in self.gram[fog].iter().enumerate() {
            if pick(b) {
                g.add(x);
            }
        }
        g
    }

    /// Whether every sample is kept.
    pub fn all_kept(&self) -> bool {
        self.kept.stride == 1
    }
}

/// Temperature rate G = dT/dt of one series: at each sample the slope of the least-squares
/// line through the temperature samples within ±`window_s`/2 (at least the two neighbours;
/// one-sided at the ends). A local line, not a raw difference: the frame's 1/256 °C
/// quantisation would otherwise dominate at short sample intervals. The passes over a
/// session compute the same per FOG with running sums over the window (`Lookahead`).
pub fn temperature_rate(t_s: &[f64], temp_degc: &[f64], window_s: f64) -> Vec<f64> {
    let mut la = Lookahead::new(1, window_s);
    let mut out = Vec::with_capacity(t_s.len());
    let mut rec = Vec::new();
    let mut emit = |_: usize, _: &SampleRef, g: &[f64]| {
        out.push(g[0]);
        Ok(())
    };
    for (&t, &temp) in t_s.iter().zip(temp_degc) {
        write_record(&mut rec, t, [0.0], [temp], [0.0; 3], [0.0; 3], []);
        la.push(&rec);
        let _ = la.drain(false, &mut emit);
    }
    let _ = la.drain(true, &mut emit);
    out
}

/// The quantities every term of a model is built from, per FOG and sample, for a session in
/// memory (for tests and tools that want every row).
#[derive(Debug, Clone)]
pub struct Prepared {
    /// Error of each FOG, y_i = ω_i,raw − s_i⁰·ω_ref, rad/s.
    pub y: Vec<Vec<f64>>,
    /// Nominal input rate of each FOG, r_i = s_i⁰·ω_ref, rad/s.
    pub r: Vec<Vec<f64>>,
    /// ΔT = T_i − T_ref per FOG, °C.
    pub dtemp_degc: Vec<Option<Vec<f64>>>,
    /// G_i, °C/s.
    pub g_degc_s: Vec<Option<Vec<f64>>>,
    /// T_ref, °C.
    pub t_ref_degc: f64,
}

/// y, r, ΔT and G of `session` with the model's T_ref and G window.
pub fn prepare(session: &Session, model: &super::model::Model) -> LabResult<Prepared> {
    let n_fog = session.fogs.len();
    let window = effective_window_s(model.g_window_s, session.median_dt_s());
    let axes = nominal_axes();
    let has_t: Vec<bool> = session.fogs.iter().map(|f| f.t_degc.is_some()).collect();
    let mut p = Prepared {
        y: vec![Vec::new(); n_fog],
        r: vec![Vec::new(); n_fog],
        dtemp_degc: has_t.iter().map(|&h| h.then(Vec::new)).collect(),
        g_degc_s: has_t.iter().map(|&h| h.then(Vec::new)).collect(),
        t_ref_degc: model.t_ref_degc,
    };
    for_each_prepared(Source::Memory(session), n_fog, window, None, |_, s, g| {
        for i in 0..n_fog {
            let a = axes[i.min(3)];
            let r = a.x * s.ref_rad_s[0] + a.y * s.ref_rad_s[1] + a.z * s.ref_rad_s[2];
            p.r[i].push(r);
            p.y[i].push(s.rate_rad_s[i] - r);
            if let Some(d) = p.dtemp_degc[i].as_mut() {
                d.push(s.t_degc[i] - model.t_ref_degc);
            }
            if let Some(x) = p.g_degc_s[i].as_mut() {
                x.push(g[i]);
            }
        }
        Ok(())
    })?;
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The box bound holds for every row: a segment of rows with a slow drift in one slot
    /// (a temperature) and steps in others (a rate table), ranked under one functional and
    /// checked under others far from it; every row's |ℓ·z̃| is at most the larger of the
    /// bound and the stored rows' largest. Batches of odd sizes cross the boxes' edges.
    #[test]
    fn box_bound_holds_for_every_row() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (m, n, box_rows) = (5usize, 5000usize, 300usize);
        let rows: Vec<Vec<f64>> = (0..n)
            .map(|k| {
                let step = ((k / 700) % 3) as f64 - 1.0;
                vec![1.0, step, 0.002 * k as f64, step.abs(), rng.random_range(-1.0..1.0)]
            })
            .collect();
        for trial in 0..20 {
            let ell_s: Vec<f64> = (0..m).map(|a| if a == m - 1 { 1.0 } else { rng.random_range(-1.0..1.0) }).collect();
            let mut x = SegmentExtremes::new(box_rows);
            x.ell = ell_s;
            let mut k = 0;
            while k < n {
                let rows_now = (1 + (k * 7 + trial) % BATCH).min(n - k);
                let mut cols = vec![0.0; COL * m];
                for i in 0..rows_now {
                    for a in 0..m {
                        cols[a * COL + i] = rows[k + i][a];
                    }
                }
                x.offer_batch(&cols, rows_now, m);
                k += rows_now;
            }
            assert_eq!(x.r.len(), n.div_ceil(box_rows));
            for _ in 0..20 {
                let ell: Vec<f64> =
                    (0..m).map(|a| if a == m - 1 { 1.0 } else { rng.random_range(-2.0..2.0) }).collect();
                let eval = |z: &[f64]| z.iter().zip(&ell).map(|(a, b)| a * b).sum::<f64>().abs();
                let stored = x.rows.chunks_exact(m).map(eval).fold(0.0, f64::max);
                let worst = rows.iter().map(|z| eval(z)).fold(0.0, f64::max);
                let bound = x.bound(&ell);
                assert!(worst <= stored.max(bound), "trial {trial}: a row at {worst}, stored {stored}, bound {bound}");
                // The stored rows are rows of the segment.
                assert!(stored <= worst);
            }
        }
    }
}
