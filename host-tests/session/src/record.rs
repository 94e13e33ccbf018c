//! A sample as a flat record ([`write_record`], [`SampleRef`]) and the conversion of a row
//! into one ([`Converter`]: rates from increments, the reference from the turntable).

use crate::*;

/// One sample of a session, in the model's quantities, borrowed from its flat record: t;
/// the FOGs' rates (n); their temperatures (n); ω_ref (3); B (3); every column's value in
/// file order ([`write_record`]). A pass holds samples as records, one after
/// another in one array, and hands them out as views ([`SampleRef::of_record`]).
#[derive(Debug, Clone, Copy)]
pub struct SampleRef<'a> {
    /// Time (end of the sample interval), s.
    pub t_s: f64,
    /// Raw rate of each FOG, rad/s.
    pub rate_rad_s: &'a [f64],
    /// Temperature of each FOG, °C (NaN where the session has none).
    pub t_degc: &'a [f64],
    /// Reference rate of the ICS, ICS components, rad/s.
    pub ref_rad_s: [f64; 3],
    /// Magnetic induction, nT (zeros without field columns).
    pub field_nt: [f64; 3],
    /// Every column's value in file order (increments as they are in the file).
    pub values: &'a [f64],
}

/// Writes the record of a sample to `rec` (its previous contents dropped): t, the FOGs'
/// rates, their temperatures (as many), ω_ref, B, the columns ([`SampleRef::of_record`]
/// reads it).
pub fn write_record(
    rec: &mut Vec<f64>,
    t_s: f64,
    rate_rad_s: impl IntoIterator<Item = f64>,
    t_degc: impl IntoIterator<Item = f64>,
    ref_rad_s: [f64; 3],
    field_nt: [f64; 3],
    values: impl IntoIterator<Item = f64>,
) {
    rec.clear();
    rec.push(t_s);
    rec.extend(rate_rad_s);
    rec.extend(t_degc);
    rec.extend_from_slice(&ref_rad_s);
    rec.extend_from_slice(&field_nt);
    rec.extend(values);
}

impl<'a> SampleRef<'a> {
    /// The sample whose record is `r` (n_fog FOGs; the columns are the rest).
    #[inline]
    pub fn of_record(r: &'a [f64], n_fog: usize) -> Self {
        let w = 1 + 2 * n_fog;
        SampleRef {
            t_s: r[0],
            rate_rad_s: &r[1..1 + n_fog],
            t_degc: &r[1 + n_fog..w],
            ref_rad_s: [r[w], r[w + 1], r[w + 2]],
            field_nt: [r[w + 3], r[w + 4], r[w + 5]],
            values: &r[w + 6..],
        }
    }
}

/// Turns rows into samples: FOG increments into rates over (t_{k−1}, t_k] (the first row of
/// an increment session has no interval and gives no sample), the turntable geometry into
/// the reference rate.
#[derive(Debug, Clone)]
pub struct Converter {
    layout: Layout,
    last_t: Option<f64>,
}

impl Converter {
    /// For sessions with `layout`.
    pub fn new(layout: &Layout) -> Converter {
        Converter { layout: layout.clone(), last_t: None }
    }

    /// Writes the record of the sample of `row` to `rec` ([`SampleRef`]); `false` (and
    /// `rec` empty) when the row gives no sample (first row of increments).
    pub fn convert(&mut self, row: &[f64], rec: &mut Vec<f64>) -> bool {
        let l = &self.layout;
        let t = row[l.t];
        let prev = self.last_t.replace(t);
        rec.clear();
        if l.increments() && prev.is_none() {
            return false;
        }
        let w = match (l.reference, l.turntable) {
            (Some([x, y, z]), _) => [row[x], row[y], row[z]],
            (None, Some([psi, lat])) => {
                let mut w = earth_rate_ics(row[psi], row[lat]);
                w[2] += l.table_rate.map_or(0.0, |c| row[c]);
                w
            }
            (None, None) => [0.0; 3],
        };
        write_record(
            rec,
            t,
            l.fog.iter().map(|&(k, inc)| if inc { row[k] / (t - prev.unwrap_or(t)) } else { row[k] }),
            l.fog_temp.iter().map(|c| c.map_or(f64::NAN, |c| row[c])),
            w,
            l.field.map_or([0.0; 3], |[x, y, z]| [row[x], row[y], row[z]]),
            row.iter().copied(),
        );
        true
    }

    /// FOGs of the records it writes.
    pub fn n_fog(&self) -> usize {
        self.layout.n_fog
    }
}
