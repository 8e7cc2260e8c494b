//! The alignment's vote histogram on log(scale) ([`super::align`]).

/// Votes on log(scale) in a fine histogram; the densest window of the vote width wins.
pub(crate) struct ScaleVotes {
    bins: Vec<u32>,
    /// Bins per vote window.
    window: usize,
    bin_width: f64,
    /// 1 / `bin_width`: a vote's bin by a product, not a division (the division's latency was
    /// a quarter of the alignment; the bins differ only for a vote within an ulp of an edge).
    per_bin: f64,
}

impl ScaleVotes {
    /// log-scales outside ±`LOG_RANGE` (a factor of ~3000) do not vote.
    const LOG_RANGE: f64 = 8.0;
    const BINS_PER_WINDOW: usize = 4;

    pub(crate) fn new(window: f64) -> Self {
        let bin_width = window.max(1e-4) / Self::BINS_PER_WINDOW as f64;
        let n = (2.0 * Self::LOG_RANGE / bin_width).ceil() as usize + 1;
        Self { bins: vec![0; n], window: Self::BINS_PER_WINDOW, bin_width, per_bin: 1.0 / bin_width }
    }

    pub(crate) fn clear(&mut self) {
        self.bins.fill(0);
    }

    pub(crate) fn add(&mut self, log_scale: f64) {
        let k = (log_scale + Self::LOG_RANGE) * self.per_bin;
        // For k ≥ 0, `k < len` is `(k as usize) < len` (len is whole), and then `k as u32` is the
        // same floor: the hot loop (a vote per pair and shift) skips the saturating conversion
        // to u64, which baseline x86-64 does in software.
        if k >= 0.0 && k < self.bins.len() as f64 {
            self.bins[k as u32 as usize] += 1;
        }
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

#[cfg(test)]
mod tests {
    use super::*;

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

    /// Votes land in the bin of the plain `(k as usize) < len` test, at the edges too.
    #[test]
    fn votes_bin_as_the_saturating_conversion_does() {
        let mut votes = ScaleVotes::new(0.06);
        let len = votes.bins.len();
        let edges = [0.0, 1e-300, 0.5, 1.0, (len - 1) as f64, len as f64 - 1e-9, len as f64, 1e20, f64::INFINITY];
        for k in edges.into_iter().flat_map(|k| [k, -k, f64::from_bits(k.to_bits().wrapping_sub(1))]) {
            votes.clear();
            votes.add(k * votes.bin_width - ScaleVotes::LOG_RANGE);
            let kk = (k * votes.bin_width - ScaleVotes::LOG_RANGE + ScaleVotes::LOG_RANGE) / votes.bin_width;
            let expected = (kk >= 0.0 && (kk as usize) < len).then(|| kk as usize);
            let got = votes.bins.iter().position(|&c| c > 0);
            assert_eq!(got, expected, "k {k}");
        }
        votes.clear();
        votes.add(f64::NAN);
        assert!(votes.bins.iter().all(|&c| c == 0));
    }
}
