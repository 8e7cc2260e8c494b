//! Coverage scoring (see [`super::PnpParams::coverage_cell_px`]): a hypothesis is ranked by the
//! distinct image cells its inliers occupy, and with prior depths only inliers whose depth under
//! the pose agrees with the prior count ([`depth_agreement`]).

use nalgebra::Vector2;

use super::hypothesis::{Bound, Hypothesis, Sprt};
use super::ops::Positions;
use super::MapToCamera;
use crate::geometry::{fit_increasing_affine, AffineFitParams, PriorSpace};

/// The prior's check on a hypothesis' inliers: their depths under it must agree with the prior
/// coordinates through one increasing affine map in `space`, within `tolerance` (relative).
pub(crate) struct PriorCheck {
    /// Prior coordinate per position (affine in its space; NaN where unknown).
    pub values: Vec<f64>,
    pub space: PriorSpace,
    pub tolerance: f64,
}

/// Each position's image cell, and a stamped scratch array that counts distinct cells without
/// clearing.
pub(crate) struct Coverage {
    cell: Vec<u32>,
    seen: Vec<u32>,
    stamp: u32,
    prior: Option<PriorCheck>,
    /// The inlier positions of the last scored pose, ascending.
    pub inliers: Vec<usize>,
    depths: Vec<(f64, f64)>,
}

impl Coverage {
    /// `None` when off (`cell_px` not > 0) or without correspondences.
    pub(crate) fn new(px: &[Vector2<f64>], cell_px: f64, prior: Option<PriorCheck>) -> Option<Self> {
        if !(cell_px.is_finite() && cell_px > 0.0) || px.is_empty() {
            return None;
        }
        let (mut lo, mut hi) = (px[0], px[0]);
        for p in px {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let cols = (((hi.x - lo.x) / cell_px).floor() as u32).saturating_add(1).min(1 << 12);
        let rows = (((hi.y - lo.y) / cell_px).floor() as u32).saturating_add(1).min(1 << 12);
        let cell: Vec<u32> = px
            .iter()
            .map(|p| {
                let c = (((p.x - lo.x) / cell_px) as u32).min(cols - 1);
                let r = (((p.y - lo.y) / cell_px) as u32).min(rows - 1);
                r * cols + c
            })
            .collect();
        let seen = vec![0; (rows * cols) as usize];
        Some(Self { cell, seen, stamp: 0, prior, inliers: Vec::new(), depths: Vec::new() })
    }

    fn next_stamp(&mut self) -> u32 {
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.seen.fill(0);
            self.stamp = 1;
        }
        self.stamp
    }

    /// Ranking cost of a pose, lower is better: minus the number of distinct cells holding an
    /// inlier; the inlier count and the MSAC score (both scaled below one cell) break ties.
    /// One pass from position `start` (wrapping), as [`super::scorer::msac_bounded`]: `None` once
    /// SPRT rejects the pose or it can no longer cover `bound.support` cells; a pose that cannot
    /// beat `bound.cost` is not checked against the prior. Support: the cells.
    pub(crate) fn cost(
        &mut self,
        data: &Positions,
        pose: &MapToCamera,
        bound: Bound,
        sprt: Option<Sprt>,
        start: usize,
    ) -> Option<Hypothesis> {
        let (cells, msac) = self.first_pass(data, pose, bound.support, sprt, start)?;
        let n = data.len() as f64;
        let cost = |cells: usize, inliers: usize, msac: f64| {
            -(cells as f64) - 0.5 * inliers as f64 / (n + 1.0) + 0.25 * msac / (n * data.th2 + 1.0)
        };
        let plain = Hypothesis {
            pose: *pose,
            cost: cost(cells, self.inliers.len(), msac),
            inliers: self.inliers.len(),
            support: cells,
        };
        if self.prior.is_none() || plain.cost >= bound.cost {
            return Some(plain);
        }
        let (cells, kept) = self.prior_agreeing_cells(data, pose);
        Some(Hypothesis { pose: *pose, cost: cost(cells, kept, msac), inliers: kept, support: cells })
    }

    /// The cells and MSAC score of the inliers of `pose`, which are left in `self.inliers`.
    fn first_pass(
        &mut self,
        data: &Positions,
        pose: &MapToCamera,
        best_cells: usize,
        sprt: Option<Sprt>,
        start: usize,
    ) -> Option<(usize, f64)> {
        let stamp = self.next_stamp();
        let (mut cells, mut msac, mut lambda) = (0usize, 0.0, 0.0);
        let n_pos = data.len();
        self.inliers.clear();
        for (k, i) in (start..n_pos).chain(0..start).enumerate() {
            let e2 = data.err2(pose, i);
            let inlier = e2 < data.th2;
            if inlier {
                self.inliers.push(i);
                msac += e2;
                let c = self.cell[i] as usize;
                if self.seen[c] != stamp {
                    self.seen[c] = stamp;
                    cells += 1;
                }
            } else {
                msac += data.th2;
            }
            if cells + (n_pos - k - 1) < best_cells {
                return None;
            }
            if let Some(s) = &sprt {
                lambda += if inlier { s.log_in } else { s.log_out };
                if lambda > s.log_a {
                    return None;
                }
            }
        }
        // Visited from `start`, wrapping: two ascending runs, the wrapped one first.
        let wrapped = self.inliers.iter().take_while(|&&i| i >= start).count();
        self.inliers.rotate_left(wrapped);
        debug_assert!(self.inliers.is_sorted());
        Some((cells, msac))
    }

    /// Cells and count of the inliers whose pose depth agrees with the prior (the others count
    /// as outliers).
    fn prior_agreeing_cells(&mut self, data: &Positions, pose: &MapToCamera) -> (usize, usize) {
        let Some(prior) = &self.prior else { return (0, 0) };
        self.depths.clear();
        for &i in &self.inliers {
            let z = data.pose_depth(pose, i);
            self.depths.push((prior.values[i], prior.space.of_depth(z)));
        }
        let agree = depth_agreement(&self.depths, prior.tolerance);
        let stamp = self.next_stamp();
        let (mut cells, mut kept) = (0usize, 0usize);
        for (&i, &ok) in self.inliers.iter().zip(&agree) {
            if ok {
                kept += 1;
                let c = self.cell[i] as usize;
                if self.seen[c] != stamp {
                    self.seen[c] = stamp;
                    cells += 1;
                }
            }
        }
        (cells, kept)
    }
}

/// How PnP's prior check fits the prior to a hypothesis' depths: every two known pairs while
/// there are at most 120 such maps, else 120 spread; counted on at most 64 pairs; an adaptive
/// stop after 16 (most frames: a few dozen maps instead of 120).
const DEPTH_FIT: AffineFitParams<f64> = AffineFitParams {
    candidates: 120,
    exhaustive_when_few: true,
    seed: 0x9E37_79B9_7F4A_7C15,
    adaptive_after: Some(16),
    max_counted: 64,
    min_gap_abs: 1e-9,
    min_gap_rel: 0.0,
};

/// Which (prior, depth) pairs agree with one affine map `depth ≈ a·prior + b`, `a > 0`, within
/// `tolerance`·depth: the map of [`fit_increasing_affine`] on the known pairs (a monocular
/// prior is right up to scale and shift). Pairs with an unknown prior always agree (no
/// evidence against them); below three known pairs, or without a map, every pair agrees.
pub(crate) fn depth_agreement(pairs: &[(f64, f64)], tolerance: f64) -> Vec<bool> {
    let known: Vec<usize> = (0..pairs.len()).filter(|&i| pairs[i].0.is_finite() && pairs[i].1 > 0.0).collect();
    let mut agree = vec![true; pairs.len()];
    if known.len() < 3 {
        return agree;
    }
    let known_pairs: Vec<(f64, f64)> = known.iter().map(|&i| pairs[i]).collect();
    if let Some(fit) = fit_increasing_affine(&known_pairs, tolerance, &DEPTH_FIT) {
        for (&i, &pair) in known.iter().zip(&known_pairs) {
            agree[i] = fit.map.agrees(pair, tolerance);
        }
    }
    agree
}
