//! The basis z of each row and FOG ([`Basis`], [`Q`]): the per-row quantities every term's
//! regressor is a linear function of, the expressions and user columns compiled over the
//! header, and the functionals that turn the sums of z zᵀ into each term's normal equations.

use super::*;

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
    pub(super) gather_cols: Vec<usize>,
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
    pub(super) fn gram_order(&self) -> (Vec<usize>, usize) {
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
    pub(super) fn batched(&self) -> bool {
        !self.gather.is_empty()
    }

    /// [`Basis::fill`] minus `shift` for the first `rows` rows staged in `st`, written
    /// column-major to `cols` (slot a of row i at `cols[a * COL + i]`): a quantity at a time
    /// over the rows, with the same operations in the same order as [`Basis::fill_from_table`]
    /// (the same values), so the loops run on whole vectors of rows.
    pub(super) fn fill_batch(&self, fog: usize, st: &Staged, rows: usize, shift: &[f64], cols: &mut [f64]) {
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
        let e = ex.eval(&v).map_err(|e| {
            LabError::model(
                ModelErrorKind::Expression,
                format!("expression `{}` at t = {} s ({}): {e}", x.text, s.t_s, self.file),
            )
        })?;
        if !e.is_finite() {
            return Err(LabError::model(
                ModelErrorKind::Expression,
                format!("expression `{}` is not finite at t = {} s ({})", x.text, s.t_s, self.file),
            ));
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
    let ex = exmex::parse::<f64>(e)
        .map_err(|err| LabError::model(ModelErrorKind::Expression, format!("expression `{e}`: {err}")))?;
    let mut vars = Vec::new();
    for v in ex.var_names() {
        vars.push(match v.as_str() {
            "rate_rad_s" => Var::Rate,
            "t_degc" => Var::TAbs,
            "dt_degc" => Var::DTemp,
            "g_degc_s" => Var::TRate,
            "fog" => Var::Fog,
            name => Var::Column(column(name).ok_or_else(|| {
                LabError::model(
                    ModelErrorKind::Unfed,
                    format!(
                        "expression `{e}`: `{v}` is not a column of {} (columns: {}; per FOG: rate_rad_s, t_degc, \
                     dt_degc, g_degc_s, fog)",
                        header.file,
                        header.names.join(", ")
                    ),
                )
            })?),
        });
    }
    let needs_temp = vars.iter().any(|v| matches!(v, Var::TAbs | Var::DTemp | Var::TRate));
    Ok(ExprSlot { text: e.into(), ex: Some(ex), vars, needs_temp })
}
