//! Running error statistics per axis.

/// Per-axis running mean, RMS and maximum of an error series.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AxisStats {
    n: u64,
    sum: [f64; 3],
    sum_sq: [f64; 3],
    max_abs: [f64; 3],
}

impl AxisStats {
    /// Adds one sample.
    pub fn push(&mut self, e: [f64; 3]) {
        self.n += 1;
        for (k, v) in e.iter().enumerate() {
            self.sum[k] += v;
            self.sum_sq[k] += v * v;
            self.max_abs[k] = self.max_abs[k].max(v.abs());
        }
    }

    /// Samples.
    pub fn count(&self) -> u64 {
        self.n
    }

    /// Mean per axis.
    pub fn mean(&self) -> [f64; 3] {
        let n = self.n.max(1) as f64;
        self.sum.map(|s| s / n)
    }

    /// Standard deviation per axis (about the mean).
    pub fn std(&self) -> [f64; 3] {
        let n = self.n.max(1) as f64;
        let m = self.mean();
        [0, 1, 2].map(|k| (self.sum_sq[k] / n - m[k] * m[k]).max(0.0).sqrt())
    }

    /// "3σ" as |mean| + 3 std per axis: a bound that counts a bias too.
    pub fn three_sigma(&self) -> [f64; 3] {
        let m = self.mean();
        let s = self.std();
        [0, 1, 2].map(|k| m[k].abs() + 3.0 * s[k])
    }

    /// Largest |error| per axis.
    pub fn max_abs(&self) -> [f64; 3] {
        self.max_abs
    }
}
