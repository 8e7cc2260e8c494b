//! How sure a pose is, from the frame itself: the number of false alarms (NFA) of its support
//! under a random-match model, as a-contrario RANSAC (ORSA, AC-RANSAC) measures it — counted in
//! image cells, not matches. Wrong matches are not independent: a matcher's mistakes come in
//! patches that one rigid motion explains (a repeated object, a moved keyframe), and a pose that
//! explains such a patch gathers many matches in a few cells. Counting the cells that hold an
//! inlier (the coverage PnP ranks by) takes each patch once.
//!
//! A wrong match lands within `r` px of where a pose projects its map point by chance with
//! probability `p = π r² / (W·H)` (uniform over the image), so a cell holding `m̄` matches (the
//! frame's mean over the `C` cells that hold any) holds a chance inlier with probability
//! `q = 1 − (1 − p)^m̄`. A pose drawn from a minimal sample of 3 matches (one cell it explains by
//! construction; P3P gives up to four poses, `N = 4·C(n, 3)` could have been tested) and
//! explaining `k` cells is as likely by chance as `k − 1` of the other `C − 1` cells:
//!
//! `NFA = 4·C(n, 3) · P[Binomial(C − 1, q) ≥ k − 1]`
//!
//! A pose with NFA ≤ 1 is meaningful (fewer than one such pose expected from wrong matches
//! alone); the smaller, the surer. No scene quantity enters: the image size, the threshold, the
//! cell size and the frame's own matches set the scale, so the same level reads alike on any
//! sensor, map and matcher.

use nalgebra::Isometry3;

use super::arbiter::{self, CellGrid};
use crate::frame::Correspondence;
use crate::geometry::Intrinsics;

/// Matches of a minimal sample, and poses one sample can give.
const SAMPLE: usize = 3;
const POSES_PER_SAMPLE: f64 = 4.0;

/// The support of a pose among a frame's correspondences and what it says about the pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Significance {
    /// Correspondences within the inlier threshold, of `matches`.
    pub inliers: usize,
    pub matches: usize,
    /// Cells holding an inlier, of the `occupied` cells that hold any correspondence.
    pub cells: usize,
    pub occupied: usize,
    /// log₁₀ of the number of false alarms (see the module doc); +∞ for a pose that explains
    /// a single cell or fewer than a minimal sample.
    pub log10_nfa: f64,
}

impl Significance {
    /// Of the camera-to-map `pose` among `correspondences`: inliers by PnP's rule at
    /// `threshold_px`, cells `cell_px` wide (PnP's coverage cells).
    pub fn of(
        k: &Intrinsics,
        correspondences: &[Correspondence],
        pose: &Isometry3<f64>,
        threshold_px: f64,
        cell_px: f64,
    ) -> Self {
        let (support, _) = arbiter::support(k, correspondences, pose, threshold_px, cell_px);
        let occupied = CellGrid::new(k, cell_px).occupied(correspondences.iter().map(|c| &c.pixel));
        let area = (k.width as f64 * k.height as f64).max(1.0);
        let p = (std::f64::consts::PI * threshold_px * threshold_px / area).clamp(0.0, 1.0);
        let n = correspondences.len();
        let per_cell = n as f64 / occupied.max(1) as f64;
        let q = -(per_cell * (-p).ln_1p()).exp_m1();
        let log10_nfa =
            if support.inliers <= SAMPLE { f64::INFINITY } else { log10_nfa(n, occupied, support.cells, q) };
        Self { inliers: support.inliers, matches: n, cells: support.cells, occupied, log10_nfa }
    }

    /// Whether fewer than `nfa` poses this well supported are expected from wrong matches alone.
    pub fn below(&self, nfa: f64) -> bool {
        nfa > 0.0 && self.log10_nfa <= nfa.log10()
    }
}

/// log₁₀ NFA of a pose found among `n` matches that explains `k` of the `occupied` cells, a cell
/// holding a chance inlier with probability `q`; +∞ when it explains one cell or none.
pub fn log10_nfa(n: usize, occupied: usize, k: usize, q: f64) -> f64 {
    if k <= 1 || n <= SAMPLE || occupied <= 1 {
        return f64::INFINITY;
    }
    let tests = POSES_PER_SAMPLE.ln() + ln_choose(n, SAMPLE);
    (tests + ln_binomial_tail(occupied - 1, k - 1, q)) / std::f64::consts::LN_10
}

/// ln C(n, k).
fn ln_choose(n: usize, k: usize) -> f64 {
    let k = k.min(n - k.min(n));
    (0..k).map(|i| ((n - i) as f64).ln() - ((i + 1) as f64).ln()).sum()
}

/// ln P[Binomial(m, p) ≥ k], summed in log space from the first term (the terms fall fast once
/// past the mean, which a meaningful `k` is far beyond).
fn ln_binomial_tail(m: usize, k: usize, p: f64) -> f64 {
    if k == 0 {
        return 0.0;
    }
    if k > m || !(p > 0.0) {
        return f64::NEG_INFINITY;
    }
    if p >= 1.0 {
        return 0.0;
    }
    let (ln_p, ln_q) = (p.ln(), (-p).ln_1p());
    let mut term = ln_choose(m, k) + k as f64 * ln_p + (m - k) as f64 * ln_q;
    let (mut max, mut terms) = (term, vec![term]);
    for j in k..m {
        // C(m, j+1)/C(m, j) = (m − j)/(j + 1).
        term += ((m - j) as f64).ln() - ((j + 1) as f64).ln() + ln_p - ln_q;
        terms.push(term);
        max = max.max(term);
        if term < max - 40.0 {
            break;
        }
    }
    max + terms.iter().map(|t| (t - max).exp()).sum::<f64>().ln()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point2, Point3};

    /// The tail matches a direct sum of the binomial terms.
    #[test]
    fn the_tail_is_the_binomial_sum() {
        let (m, p) = (40usize, 0.05f64);
        for k in [1usize, 3, 7, 15] {
            let direct: f64 =
                (k..=m).map(|j| ln_choose(m, j).exp() * p.powi(j as i32) * (1.0 - p).powi((m - j) as i32)).sum();
            let ours = ln_binomial_tail(m, k, p).exp();
            assert!((ours - direct).abs() <= 1e-12 + 1e-9 * direct, "k {k}: {ours} vs {direct}");
        }
        assert_eq!(ln_binomial_tail(m, 0, p), 0.0);
        assert_eq!(ln_binomial_tail(m, m + 1, p), f64::NEG_INFINITY);
    }

    /// More cells are surer; more matches (more tests) are less sure of the same count; one
    /// cell alone means nothing.
    #[test]
    fn coverage_grows_sureness_and_matches_dilute_it() {
        let q = 0.0013;
        assert!(log10_nfa(300, 150, 12, q) < log10_nfa(300, 150, 8, q));
        assert!(log10_nfa(3000, 150, 8, q) > log10_nfa(300, 150, 8, q));
        assert_eq!(log10_nfa(300, 150, 1, q), f64::INFINITY);
        // 300 matches over 150 cells of 640×480 at 8 px: 7 cells is about where a pose becomes
        // meaningful (scipy: log₁₀(4·C(300,3)) + binom.logsf(5, 149, q)/ln 10 = 0.003 for 7).
        assert!((log10_nfa(300, 150, 7, q) - 0.00297).abs() < 1e-3, "{}", log10_nfa(300, 150, 7, q));
    }

    /// Measured on a pose: its inliers under PnP's rule, and the level it passes.
    #[test]
    fn a_pose_that_explains_its_matches_is_significant() {
        let k = Intrinsics { fx: 500.0, fy: 500.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
        let pose = Isometry3::identity();
        let mut correspondences: Vec<Correspondence> = (0..30)
            .map(|i| {
                let pixel = Point2::new(20.0 + 20.0 * i as f64, 100.0 + 10.0 * (i % 7) as f64);
                Correspondence { pixel, point: k.back_project(&pixel, 2.0), score: 1.0 }
            })
            .collect();
        correspondences.extend((0..270).map(|i| Correspondence {
            pixel: Point2::new((i * 37 % 640) as f64, (i * 53 % 480) as f64),
            point: Point3::new(5.0, 5.0, -1.0 - i as f64),
            score: 0.0,
        }));
        let s = Significance::of(&k, &correspondences, &pose, 8.0, 32.0);
        assert_eq!((s.inliers, s.matches), (30, 300));
        assert!(s.below(1e-10), "{s:?}");
        let few = Significance::of(&k, &correspondences[25..], &pose, 8.0, 32.0);
        assert_eq!(few.inliers, 5);
        assert!(!few.below(1.0), "{few:?}");
        // The same 30 inliers piled into one patch of a few cells: no longer sure.
        let mut patch = correspondences.clone();
        for (i, c) in patch.iter_mut().take(30).enumerate() {
            c.pixel = Point2::new(100.0 + (i % 6) as f64 * 5.0, 100.0 + (i / 6) as f64 * 5.0);
            c.point = k.back_project(&c.pixel, 2.0);
        }
        let piled = Significance::of(&k, &patch, &pose, 8.0, 32.0);
        assert_eq!(piled.inliers, 30);
        assert!(piled.cells <= 2 && !piled.below(1.0), "{piled:?}");
    }
}
