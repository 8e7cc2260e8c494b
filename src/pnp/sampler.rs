//! Minimal samples of three positions: uniform, or PROSAC over score ranks (Chum & Matas 2005),
//! which draws from a growing prefix of the best-scored correspondences.

use super::ops::Positions;
use crate::rng::WyRand;

/// Sample size of the minimal solver.
pub(crate) const M: usize = 3;

/// Where the minimal samples come from.
pub(crate) enum Sampler {
    /// Three distinct positions among `n`, uniformly.
    Uniform { n: usize },
    /// PROSAC over ranks; `pos_of_rank` maps each rank (best score first) to its position.
    Prosac { prosac: Prosac, pos_of_rank: Vec<usize> },
}

impl Sampler {
    /// PROSAC with `scores` (one per input correspondence; NaN ranks last), else uniform.
    pub(crate) fn new(positions: &Positions, scores: Option<&[f32]>, max_iterations: usize) -> Self {
        let n = positions.len();
        let Some(s) = scores else { return Self::Uniform { n } };
        let orig = &positions.original;
        let key = |pos: usize| {
            let v = s[orig[pos]];
            if v.is_nan() {
                f32::NEG_INFINITY
            } else {
                v
            }
        };
        let mut ranks: Vec<usize> = (0..n).collect();
        ranks.sort_by(|&a, &b| key(b).total_cmp(&key(a)).then(orig[a].cmp(&orig[b])));
        Self::Prosac { prosac: Prosac::new(n, max_iterations), pos_of_rank: ranks }
    }

    #[inline]
    pub(crate) fn sample(&mut self, rng: &mut WyRand) -> [usize; 3] {
        match self {
            Self::Uniform { n } => distinct3(rng, *n),
            Self::Prosac { prosac, pos_of_rank: map } => {
                let r = prosac.sample(rng);
                [map[r[0]], map[r[1]], map[r[2]]]
            }
        }
    }

    /// Rank → position, with PROSAC.
    pub(crate) fn pos_of_rank(&self) -> Option<&[usize]> {
        match self {
            Self::Uniform { .. } => None,
            Self::Prosac { pos_of_rank, .. } => Some(pos_of_rank),
        }
    }
}

/// PROSAC's sampler over ranks `0..n`, best score first; it draws from a growing prefix and
/// reaches uniform sampling over all ranks after about `t_max` samples.
pub(crate) struct Prosac {
    n: usize,
    big_n: usize,
    t: usize,
    tn: f64,
    tn_prime: f64,
}

impl Prosac {
    fn new(big_n: usize, t_max: usize) -> Self {
        let mut tn = t_max.max(1) as f64;
        for i in 0..M {
            tn *= (M - i) as f64 / (big_n - i) as f64;
        }
        Self { n: M, big_n, t: 0, tn, tn_prime: 1.0 }
    }

    #[inline]
    fn sample(&mut self, rng: &mut WyRand) -> [usize; 3] {
        self.t += 1;
        while self.t as f64 > self.tn_prime && self.n < self.big_n {
            let next = self.tn * (self.n + 1) as f64 / (self.n + 1 - M) as f64;
            self.tn_prime += (next - self.tn).ceil();
            self.tn = next;
            self.n += 1;
        }
        if self.tn_prime < self.t as f64 {
            distinct3(rng, self.n)
        } else {
            // The newest rank plus two from the ranks before it.
            let (a, b) = distinct2(rng, self.n - 1);
            [self.n - 1, a, b]
        }
    }
}

#[inline(always)]
fn distinct2(rng: &mut WyRand, n: usize) -> (usize, usize) {
    let a = rng.below(n);
    let mut b = rng.below(n - 1);
    if b >= a {
        b += 1;
    }
    (a, b)
}

#[inline(always)]
fn distinct3(rng: &mut WyRand, n: usize) -> [usize; 3] {
    let (a, b) = distinct2(rng, n);
    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
    let mut c = rng.below(n - 2);
    if c >= lo {
        c += 1;
    }
    if c >= hi {
        c += 1;
    }
    [a, b, c]
}
