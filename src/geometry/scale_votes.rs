//! The alignment's vote histogram on log(scale) ([`super::align`]), and the binning of a vote
//! ½·(log ‖q_i − q_j‖² − ln ‖o_i − o_j‖²) without calling `ln` for almost every vote: the
//! alignment casts one per voting pair and candidate shift (~120 k a frame), and libm's `ln` was a
//! quarter of it. A table-driven `ln` within 1e-12 brackets the vote; only a vote whose bracket
//! meets a bin boundary (a few per million) is binned through libm's `ln`. Every vote lands in
//! the bin the plain `ln` puts it in, so the alignment is bit for bit what it was.

/// Votes on log(scale) in a fine histogram; the densest window of the vote width wins.
pub(crate) struct ScaleVotes {
    bins: Vec<u32>,
    /// Bins per vote window.
    window: usize,
    bin_width: f64,
    /// 1/`bin_width` and the half-width, in bins, of a vote's bracket: ½·(ln error)/width plus
    /// the roundings by which the bracket's k (multiplied by the inverse) and the exact one
    /// (divided, with libm's ln) can differ — a few ulps of numbers below ~1e4.
    inverse_width: f64,
    margin: f64,
    ln: TableLn,
}

impl ScaleVotes {
    /// log-scales outside ±`LOG_RANGE` (a factor of ~3000) do not vote.
    const LOG_RANGE: f64 = 8.0;
    const BINS_PER_WINDOW: usize = 4;
    /// What the table `ln` may be off by, with a wide margin (it is within 1e-12).
    const LN_SLACK: f64 = 1e-7;

    pub(crate) fn new(window: f64) -> Self {
        let bin_width = window.max(1e-4) / Self::BINS_PER_WINDOW as f64;
        let n = (2.0 * Self::LOG_RANGE / bin_width).ceil() as usize + 1;
        Self {
            bins: vec![0; n],
            window: Self::BINS_PER_WINDOW,
            bin_width,
            inverse_width: 1.0 / bin_width,
            margin: 0.5 * Self::LN_SLACK / bin_width + 1e-9,
            ln: TableLn::new(),
        }
    }

    pub(crate) fn clear(&mut self) {
        self.bins.fill(0);
    }

    /// The bin of `log_scale`, `None` outside the histogram.
    fn bin(&self, log_scale: f64) -> Option<usize> {
        let k = (log_scale + Self::LOG_RANGE) / self.bin_width;
        (k >= 0.0 && (k as usize) < self.bins.len()).then_some(k as usize)
    }

    /// Adds a vote (the reference [`ScaleVotes::add_half_log_ratio`] is tested against).
    #[cfg(test)]
    fn add(&mut self, log_scale: f64) {
        if let Some(k) = self.bin(log_scale) {
            self.bins[k] += 1;
        }
    }

    /// Adds the vote ½·(`log_a` − ln `b`), in the bin `add(0.5 * (log_a - b.ln()))` puts it in.
    pub(crate) fn add_half_log_ratio(&mut self, log_a: f64, b: f64) {
        let bin = match self.bracketed_bin(log_a, b) {
            Some(decided) => decided,
            None => self.bin(0.5 * (log_a - b.ln())),
        };
        if let Some(k) = bin {
            self.bins[k] += 1;
        }
    }

    /// The bin of ½·(`log_a` − ln `b`) from the table `ln`, when every value within its error
    /// falls in one bin (or all outside the histogram); `None` when undecided.
    fn bracketed_bin(&self, log_a: f64, b: f64) -> Option<Option<usize>> {
        let ln_b = self.ln.ln(b)?;
        let k = (0.5 * (log_a - ln_b) + Self::LOG_RANGE) * self.inverse_width;
        let (lo, hi) = (k - self.margin, k + self.margin);
        if hi < 0.0 {
            return Some(None);
        }
        if !(lo >= 0.0) {
            return None;
        }
        // Both non-negative: `as` truncates, which is the floor (and saturates as `bin` does).
        let (first, last) = (lo as usize, hi as usize);
        if first != last {
            return None;
        }
        Some((first < self.bins.len()).then_some(first))
    }

    /// (votes, centre log-scale) of the densest window.
    pub(crate) fn densest(&self) -> Option<(usize, f64)> {
        let mut count: u32 = self.bins[..self.window.min(self.bins.len())].iter().sum();
        let (mut best, mut best_start) = (count, 0);
        for start in 1..=self.bins.len().saturating_sub(self.window) {
            count = count + self.bins[start + self.window - 1] - self.bins[start - 1];
            if count > best {
                best = count;
                best_start = start;
            }
        }
        (best > 0)
            .then(|| (best as usize, (best_start as f64 + self.window as f64 / 2.0) * self.bin_width - Self::LOG_RANGE))
    }
}

/// ln x for positive normal x within 1e-12: x = 2^e·m, m = c·(1 + r) with c the centre of one of
/// 2^`BITS` mantissa intervals (|r| < 2^−`BITS`), ln x = e·ln 2 + ln c + ln(1 + r), the last
/// from its series to r⁴ (remainder below r⁵/5 < 2e-12).
struct TableLn {
    /// Per interval: 1/c (rounded) and −ln of that rounded value, so ln c + ln(1 + r) is exact
    /// math for r = m·(1/c) − 1 whatever the rounding of 1/c.
    inverse: [f64; 1 << TableLn::BITS],
    ln_centre: [f64; 1 << TableLn::BITS],
}

impl TableLn {
    const BITS: u32 = 7;

    fn new() -> Self {
        let mut inverse = [0.0; 1 << Self::BITS];
        let mut ln_centre = [0.0; 1 << Self::BITS];
        for (i, (inv, ln)) in inverse.iter_mut().zip(&mut ln_centre).enumerate() {
            let centre = 1.0 + (i as f64 + 0.5) / (1u32 << Self::BITS) as f64;
            *inv = 1.0 / centre;
            *ln = -inv.ln();
        }
        Self { inverse, ln_centre }
    }

    /// `None` for zero, negative, subnormal or non-finite x.
    fn ln(&self, x: f64) -> Option<f64> {
        let bits = x.to_bits();
        let biased = bits >> 52; // the sign bit set makes it over 0x7ff
        if biased == 0 || biased >= 0x7ff {
            return None;
        }
        let exponent = biased as i64 - 1023;
        let mantissa = f64::from_bits((bits & 0x000f_ffff_ffff_ffff) | 0x3ff0_0000_0000_0000);
        let i = ((bits >> (52 - Self::BITS)) & ((1 << Self::BITS) - 1)) as usize;
        let r = mantissa * self.inverse[i] - 1.0;
        let series = r * (1.0 - r * (0.5 - r * (1.0 / 3.0 - r * 0.25)));
        Some(exponent as f64 * std::f64::consts::LN_2 + (self.ln_centre[i] + series))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    #[test]
    fn scale_votes_find_the_mode() {
        let mut votes = ScaleVotes::new(0.06);
        for v in [0.0, 0.5, 0.51, 0.52, 0.53, -2.0, 9.0] {
            votes.add(v);
        }
        let (count, centre) = votes.densest().unwrap();
        assert_eq!(count, 4);
        assert!((centre - 0.515).abs() < 0.03, "{centre}");
    }

    #[test]
    fn table_ln_is_within_its_bound() {
        let table = TableLn::new();
        let mut rng = SplitMix64(17);
        for _ in 0..200_000 {
            // Any positive normal: a random mantissa and exponent.
            let exponent = rng.below(2045) as u64 + 1;
            let x = f64::from_bits((rng.next_u64() & 0x000f_ffff_ffff_ffff) | (exponent << 52));
            let ln = table.ln(x).unwrap();
            assert!((ln - x.ln()).abs() < 1e-12 * (1.0 + x.ln().abs()), "{x}: {ln} vs {}", x.ln());
        }
        assert_eq!((table.ln(0.0), table.ln(-1.0), table.ln(f64::INFINITY)), (None, None, None));
    }

    /// Every vote lands where libm's `ln` puts it: random votes, and votes placed on bin
    /// boundaries (where the bracket must give up and ask libm).
    #[test]
    fn half_log_ratio_votes_bin_as_the_plain_ln() {
        let mut rng = SplitMix64(5);
        let mut unit = || rng.next_u64() as f64 / u64::MAX as f64;
        let mut fast = ScaleVotes::new(0.06);
        let mut plain = ScaleVotes::new(0.06);
        let mut cases = Vec::new();
        for _ in 0..300_000 {
            cases.push(((unit() - 0.5) * 16.0, (unit() * 24.0 - 12.0).exp()));
        }
        for k in 0..plain.bins.len() + 2 {
            // ½·(a − ln b) = k·width − 8, nudged by a few ulps either way.
            let a = (unit() - 0.5) * 10.0;
            let b = (a - 2.0 * (k as f64 * plain.bin_width - ScaleVotes::LOG_RANGE)).exp();
            for ulps in -3i64..=3 {
                cases.push((a, f64::from_bits((b.to_bits() as i64 + ulps) as u64)));
            }
        }
        for &(a, b) in &cases {
            fast.add_half_log_ratio(a, b);
            plain.add(0.5 * (a - b.ln()));
        }
        assert_eq!(fast.bins, plain.bins);
        assert!(plain.bins.iter().sum::<u32>() > 150_000);
    }
}
