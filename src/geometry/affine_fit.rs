//! Robust fit of one increasing affine map `z ≈ a·d + b` (`a > 0`) to `(d, z)` pairs: a monocular
//! depth prior is right up to an unknown scale and shift, so the prior coordinate `d` of the
//! points seen correctly and their depth coordinate `z` under a pose lie on one such map.
//!
//! RANSAC with two-pair minimal samples: each candidate map passes through two pairs, the map
//! that puts the most pairs within `tolerance`·z wins. Used by PnP's prior check on a
//! hypothesis' inliers and by the dense verifier on image cells, with their own settings
//! ([`AffineFitParams`]).

use nalgebra::RealField;

use crate::rng::Lcg64;

/// How [`fit_increasing_affine`] draws and counts its candidate maps.
#[derive(Clone, Copy, Debug)]
pub struct AffineFitParams<T> {
    /// Candidate maps tried at most.
    pub candidates: usize,
    /// Every two pairs are candidates while there are at most `candidates` of them; else (or
    /// when false) `candidates` pairs `(x, x + offset)` are spread over the pairs, `x` evenly and
    /// the offsets drawn by an [`Lcg64`] seeded with `seed`.
    pub exhaustive_when_few: bool,
    pub seed: u64,
    /// With `Some(m)`, stop after at least `m` candidates once enough were tried that one of them
    /// passed through two pairs of the best map so far with 99.99 % confidence.
    pub adaptive_after: Option<usize>,
    /// A candidate is counted on at most this many pairs (evenly strided); the count of the
    /// result is over those.
    pub max_counted: usize,
    /// Two pairs whose `d` differ by less than `min_gap_abs + min_gap_rel·max(|d|)` define no map.
    pub min_gap_abs: T,
    pub min_gap_rel: T,
}

/// `z ≈ scale·d + offset`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffineMap<T> {
    pub scale: T,
    pub offset: T,
}

impl<T: RealField + Copy> AffineMap<T> {
    /// Whether `(d, z)` lies on the map within `tolerance`·z.
    #[inline]
    pub fn agrees(&self, (d, z): (T, T), tolerance: T) -> bool {
        (z - (self.scale * d + self.offset)).abs() < tolerance * z
    }
}

/// The winning map and its support.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffineFit<T> {
    pub map: AffineMap<T>,
    /// Counted pairs (see [`AffineFitParams::max_counted`]) that agree with `map`.
    pub agreeing: usize,
    /// Pairs counted.
    pub counted: usize,
}

/// The increasing affine map that the most pairs agree with (the first found on a tie), among
/// candidates through two pairs each; `None` below two pairs or when no candidate has support
/// (e.g. every pair at one `d`). Pairs must be finite.
pub fn fit_increasing_affine<T: RealField + Copy>(
    pairs: &[(T, T)],
    tolerance: T,
    params: &AffineFitParams<T>,
) -> Option<AffineFit<T>> {
    let k = pairs.len();
    if k < 2 {
        return None;
    }
    let stride = k.div_ceil(params.max_counted.max(1));
    let counted = k.div_ceil(stride);
    let mut best: Option<AffineFit<T>> = None;
    for (tried, (i, j)) in candidate_pairs(k, params).enumerate() {
        let best_count = best.map_or(0, |b| b.agreeing);
        if let Some(min) = params.adaptive_after {
            if tried >= min && tried as f64 >= two_point_draws(best_count as f64 / counted as f64) {
                break;
            }
        }
        let Some(map) = map_through(pairs[i], pairs[j], params) else { continue };
        let agreeing = pairs.iter().step_by(stride).filter(|&&p| map.agrees(p, tolerance)).count();
        if agreeing > best_count {
            best = Some(AffineFit { map, agreeing, counted });
        }
    }
    best
}

/// The increasing map through two pairs, if they define one.
#[inline]
fn map_through<T: RealField + Copy>(
    (di, zi): (T, T),
    (dj, zj): (T, T),
    params: &AffineFitParams<T>,
) -> Option<AffineMap<T>> {
    if (di - dj).abs() < params.min_gap_abs + params.min_gap_rel * di.abs().max(dj.abs()) {
        return None;
    }
    let scale = (zi - zj) / (di - dj);
    if !(scale > T::zero()) {
        return None;
    }
    Some(AffineMap { scale, offset: zi - scale * di })
}

/// The index pairs the candidates pass through, in the order they are tried (`k ≥ 2`).
fn candidate_pairs<T>(k: usize, params: &AffineFitParams<T>) -> impl Iterator<Item = (usize, usize)> {
    let n = params.candidates;
    let exhaustive = params.exhaustive_when_few && k * (k - 1) / 2 <= n;
    let all = (0..k).flat_map(move |x| (x + 1..k).map(move |y| (x, y)));
    let mut lcg = Lcg64(params.seed);
    let spread = (0..n).map(move |c| {
        let offset = lcg.next_high31() % (k - 1);
        let x = c * k / n;
        (x, (x + 1 + offset) % k)
    });
    let (all, spread) = if exhaustive { (Some(all), None) } else { (None, Some(spread)) };
    all.into_iter().flatten().chain(spread.into_iter().flatten())
}

/// Draws of two pairs needed to have drawn two agreeing ones with 99.99 % confidence when a share
/// `agreeing` of the pairs agree (∞ for none).
fn two_point_draws(agreeing: f64) -> f64 {
    let both = agreeing * agreeing;
    if both >= 1.0 {
        return 1.0;
    }
    (1e-4f64).ln() / (1.0 - both).ln()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> AffineFitParams<f64> {
        AffineFitParams {
            candidates: 120,
            exhaustive_when_few: true,
            seed: 1,
            adaptive_after: None,
            max_counted: usize::MAX,
            min_gap_abs: 1e-9,
            min_gap_rel: 0.0,
        }
    }

    #[test]
    fn finds_the_map_most_pairs_share() {
        // 30 pairs on z = 2d + 1, 10 on a decreasing line, 10 scattered.
        let mut pairs: Vec<(f64, f64)> = (0..30).map(|i| (i as f64, 2.0 * i as f64 + 1.0)).collect();
        pairs.extend((0..10).map(|i| (i as f64 + 0.5, 40.0 - i as f64)));
        pairs.extend((0..10).map(|i| (i as f64 * 3.1, 7.0 + (i * 7 % 5) as f64)));
        for p in [params(), AffineFitParams { exhaustive_when_few: false, adaptive_after: Some(16), ..params() }] {
            let fit = fit_increasing_affine(&pairs, 0.01, &p).expect("a map");
            assert!((fit.map.scale - 2.0).abs() < 1e-9 && (fit.map.offset - 1.0).abs() < 1e-9, "{fit:?}");
            assert!(fit.agreeing >= 30);
            assert_eq!(fit.counted, pairs.len());
        }
    }

    #[test]
    fn no_map_without_two_distinct_increasing_pairs() {
        assert!(fit_increasing_affine(&[(1.0, 2.0)], 0.1, &params()).is_none());
        assert!(fit_increasing_affine(&[(1.0, 2.0), (1.0, 3.0), (1.0, 4.0)], 0.1, &params()).is_none());
        assert!(fit_increasing_affine(&[(1.0, 3.0), (2.0, 2.0)], 0.1, &params()).is_none());
    }

    #[test]
    fn counts_on_a_strided_subset() {
        let pairs: Vec<(f32, f32)> = (0..100).map(|i| (i as f32, 0.5 * i as f32 + 3.0)).collect();
        let p = AffineFitParams {
            candidates: 64,
            exhaustive_when_few: false,
            seed: 3,
            adaptive_after: None,
            max_counted: 10,
            min_gap_abs: 0.0,
            min_gap_rel: 1e-6,
        };
        let fit = fit_increasing_affine(&pairs, 0.01, &p).expect("a map");
        assert_eq!((fit.agreeing, fit.counted), (10, 10));
    }
}
