//! Fixed timing histograms for the RT path: 1 µs bins up to a fixed range,
//! an overflow bin, and the exact maximum. Recording is a bounds check and an
//! increment (no allocation after construction); percentiles are read after
//! the fact by another thread or at the end of the run.

use serde::Serialize;

/// Number of 1 µs bins: values from 0 to 19 999 µs are binned exactly to the
/// microsecond; larger ones go to the overflow bin (and still set `max`).
pub const BINS: usize = 20_000;

/// A histogram of durations in microseconds.
#[derive(Debug, Clone)]
pub struct Histogram {
    bins: Box<[u32]>,
    overflow: u64,
    count: u64,
    max_us: f64,
    sum_us: f64,
}

/// Percentiles of a histogram (µs), the report's shape.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct Percentiles {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// 99.9th percentile.
    pub p999: f64,
    /// Maximum (exact).
    pub max: f64,
}

impl Percentiles {
    /// Exact percentiles of a set of samples (nearest rank), for threads
    /// that may allocate and whose times can exceed the histogram's range
    /// (e.g. the background solve); zeros when empty.
    pub fn of(samples: &[f64]) -> Percentiles {
        let mut v: Vec<f64> = samples.iter().copied().filter(|x| x.is_finite()).collect();
        v.sort_by(f64::total_cmp);
        let at = |q: f64| {
            v.get(((v.len() as f64 - 1.0) * q).round() as usize)
                .copied()
                .unwrap_or(0.0)
        };
        Percentiles {
            p50: at(0.5),
            p99: at(0.99),
            p999: at(0.999),
            max: v.last().copied().unwrap_or(0.0),
        }
    }
}

impl Default for Histogram {
    fn default() -> Self {
        Histogram::new()
    }
}

impl Histogram {
    /// An empty histogram (allocates its bins once).
    pub fn new() -> Histogram {
        Histogram {
            bins: vec![0u32; BINS].into_boxed_slice(),
            overflow: 0,
            count: 0,
            max_us: 0.0,
            sum_us: 0.0,
        }
    }

    /// Records one value (µs); negative values count as 0, non-finite ones
    /// are ignored.
    #[inline]
    pub fn record(&mut self, us: f64) {
        if !us.is_finite() {
            return;
        }
        let us = us.max(0.0);
        let b = us as usize;
        match self.bins.get_mut(b) {
            Some(c) => *c = c.saturating_add(1),
            None => self.overflow += 1,
        }
        self.count += 1;
        self.sum_us += us;
        if us > self.max_us {
            self.max_us = us;
        }
    }

    /// Number of values recorded.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// Mean (µs), 0 when empty.
    pub fn mean(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum_us / self.count as f64
        }
    }

    /// Largest value recorded (µs).
    pub fn max(&self) -> f64 {
        self.max_us
    }

    /// Values above the binned range.
    pub fn overflow(&self) -> u64 {
        self.overflow
    }

    /// The `p`-quantile (p in [0, 1]) as the upper edge of its 1 µs bin,
    /// capped at the maximum; 0 when empty.
    pub fn quantile(&self, p: f64) -> f64 {
        if self.count == 0 {
            return 0.0;
        }
        let rank = ((p.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0u64;
        for (i, &c) in self.bins.iter().enumerate() {
            seen += c as u64;
            if seen >= rank {
                return ((i + 1) as f64).min(self.max_us);
            }
        }
        self.max_us
    }

    /// p50, p99, p99.9 and max.
    pub fn percentiles(&self) -> Percentiles {
        Percentiles {
            p50: self.quantile(0.5),
            p99: self.quantile(0.99),
            p999: self.quantile(0.999),
            max: self.max_us,
        }
    }

    /// Adds another histogram's counts.
    pub fn merge(&mut self, other: &Histogram) {
        for (a, b) in self.bins.iter_mut().zip(other.bins.iter()) {
            *a = a.saturating_add(*b);
        }
        self.overflow += other.overflow;
        self.count += other.count;
        self.sum_us += other.sum_us;
        self.max_us = self.max_us.max(other.max_us);
    }

    /// Empties the histogram (keeps its memory).
    pub fn clear(&mut self) {
        self.bins.iter_mut().for_each(|c| *c = 0);
        self.overflow = 0;
        self.count = 0;
        self.max_us = 0.0;
        self.sum_us = 0.0;
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn exact_percentiles_of_samples() {
        let v: Vec<f64> = (1..=1000).map(|i| i as f64).collect();
        let p = Percentiles::of(&v);
        assert_eq!((p.p50, p.p99, p.p999, p.max), (501.0, 990.0, 999.0, 1000.0));
        assert_eq!(Percentiles::of(&[]), Percentiles::default());
        assert_eq!(Percentiles::of(&[f64::NAN, 3.0]).max, 3.0);
    }

    use super::*;

    #[test]
    fn percentiles_of_a_known_distribution() {
        let mut h = Histogram::new();
        for i in 0..1000 {
            h.record(i as f64 + 0.5);
        }
        h.record(50_000.0);
        h.record(f64::NAN);
        h.record(-3.0);
        assert_eq!(h.count(), 1002);
        assert_eq!(h.overflow(), 1);
        assert_eq!(h.max(), 50_000.0);
        let p = h.percentiles();
        assert_eq!(p.p50, 500.0);
        assert_eq!(p.p99, 991.0);
        assert_eq!(p.p999, 1000.0);
        let mut g = Histogram::new();
        g.merge(&h);
        assert_eq!(g.percentiles(), p);
        g.clear();
        assert_eq!(g.count(), 0);
        assert_eq!(g.quantile(0.5), 0.0);
    }
}
