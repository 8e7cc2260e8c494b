//! Alignment of the depth prior's unknown affine map from the correspondences themselves: a
//! monocular prior is known only up to scale and shift, in depth (metric-like networks) or in
//! inverse depth (affine-invariant disparity). The paper estimates a scale only (eq. 8) and lists
//! the shift as a limitation; here pairs of correspondences vote for both.

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::scale_votes::ScaleVotes;
use super::PriorSpace;
use crate::rng::SplitMix64;

/// The prior's affine map to metric depth: in [`PriorSpace::Depth`] depth = `scale`·x + `shift`,
/// in [`PriorSpace::Disparity`] 1/depth = `scale`·x + `shift` (x = the prior coordinate,
/// [`crate::geometry::DepthKind::coordinate`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScaleShift {
    pub scale: f64,
    pub shift: f64,
    /// How many sampled pairs agreed with the estimate (a confidence, not a probability).
    pub support: usize,
    #[serde(default)]
    pub space: PriorSpace,
}

impl ScaleShift {
    /// Depth = prior coordinate.
    pub const IDENTITY: Self = Self::identity(PriorSpace::Depth);

    /// The unit map of `space`: depth = x, or 1/depth = x.
    pub const fn identity(space: PriorSpace) -> Self {
        Self { scale: 1.0, shift: 0.0, support: 0, space }
    }

    /// Metric depth of prior coordinate `x` (non-finite or ≤ 0 where the map says nothing).
    pub fn depth(&self, x: f64) -> f64 {
        let y = self.scale * x + self.shift;
        match self.space {
            PriorSpace::Depth => y,
            PriorSpace::Disparity => 1.0 / y,
        }
    }

    /// ∂depth/∂scale and ∂depth/∂shift at `x`.
    fn gradient(&self, x: f64) -> (f64, f64) {
        match self.space {
            PriorSpace::Depth => (x, 1.0),
            PriorSpace::Disparity => {
                let z = self.depth(x);
                (-x * z * z, -z * z)
            }
        }
    }
}

/// Parameters of [`estimate_scale_shift`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScaleShiftParams {
    /// Neighbours per correspondence in the image, whose pairs vote (local pairs keep their
    /// length even inside a wrongly placed but rigid patch).
    pub local_neighbours: usize,
    /// At most this many local pairs in all (fewer neighbours each for large frames).
    pub max_local_pairs: usize,
    /// Random global pairs that vote as well.
    pub global_pairs: usize,
    /// Shifts tried, as a fraction of the median prior coordinate: −range..=range.
    pub shift_range: f64,
    /// Coarse grid of shifts, then `fine_steps` on each side of the best between its neighbours.
    pub shift_steps: usize,
    pub fine_steps: usize,
    /// Width of the voting window on log(scale): the relative length error a pair may have.
    pub log_scale_window: f64,
    /// Pairs shorter than this share of the median map-pair length do not vote (their length
    /// is dominated by noise). Relative, so that it holds at any range and map scale.
    pub min_pair_fraction: f64,
    /// Gauss–Newton refinement rounds on the agreeing pairs.
    pub refine_iterations: usize,
    pub seed: u64,
}

impl Default for ScaleShiftParams {
    fn default() -> Self {
        Self {
            local_neighbours: 10,
            max_local_pairs: 4000,
            global_pairs: 4000,
            shift_range: 0.6,
            shift_steps: 9,
            fine_steps: 3,
            log_scale_window: 0.06,
            min_pair_fraction: 0.05,
            refine_iterations: 5,
            seed: 0x5eed,
        }
    }
}

/// One voting pair: its prior coordinates, map length and correspondence indices, and for
/// depth space the terms of its image length as a quadratic in the shift (and in the scale:
/// the refinement's residuals). 64 bytes, so that a frame's thousands of pairs, read once per
/// candidate shift, stay in the core's cache.
struct PairTerms {
    aa: f64,
    two_ab: f64,
    bb: f64,
    xi: f64,
    xj: f64,
    map_len: f64,
    log_map_len2: f64,
    i: u32,
    j: u32,
}

/// Depth up to scale under candidate shift `t`: x + t, or 1/(x + t) in disparity space;
/// `None` where that is not a positive depth.
fn unit_depth(space: PriorSpace, x: f64, t: f64) -> Option<f64> {
    let y = x + t;
    match space {
        PriorSpace::Depth => (y > 0.0).then_some(y),
        PriorSpace::Disparity => (y > 0.0).then(|| 1.0 / y),
    }
}

/// Estimates the prior's affine map in `space` from putative correspondences, robust to a large
/// share of outliers: for each candidate shift t of the prior coordinate, every voting pair
/// (i, j) proposes the scale ‖q_i − q_j‖ / ‖u_i·r_i − u_j·r_j‖ (r = the pixel's ray with z = 1,
/// u = x + t, or 1/(x + t) in disparity space); the shift whose proposals agree most (densest
/// window of log-scale) wins, then Gauss–Newton fits the map on the agreeing pairs.
///
/// `rays[i]` is pixel i's ray scaled to z = 1, `prior[i]` its prior coordinate, `local_pairs`
/// the local pairs (e.g. image-space kNN). Returns `None` when nothing agrees.
pub fn estimate_scale_shift(
    rays: &[Vector3<f64>],
    prior: &[f64],
    map: &[Point3<f64>],
    local_pairs: &[(u32, u32)],
    space: PriorSpace,
    params: &ScaleShiftParams,
) -> Option<ScaleShift> {
    let n = rays.len().min(prior.len()).min(map.len());
    if n < 3 {
        return None;
    }
    let mut pairs: Vec<(u32, u32)> =
        local_pairs.iter().copied().filter(|&(i, j)| i != j && (i as usize) < n && (j as usize) < n).collect();
    let mut rng = SplitMix64(params.seed);
    for _ in 0..params.global_pairs {
        let i = rng.below(n) as u32;
        let j = rng.below(n) as u32;
        if i != j {
            pairs.push((i, j));
        }
    }
    let map_len: Vec<f64> = pairs.iter().map(|&(i, j)| (map[i as usize] - map[j as usize]).norm()).collect();
    let median_x = median(prior[..n].iter().copied().filter(|d| d.is_finite() && *d > 0.0).collect())?;
    let min_len = params.min_pair_fraction * median(map_len.clone()).unwrap_or(0.0);
    let terms: Vec<PairTerms> = pairs
        .iter()
        .zip(&map_len)
        .filter(|(_, &len)| len >= min_len && len > 0.0)
        .map(|(&(i, j), &len)| {
            let (ri, rj, xi, xj) = (rays[i as usize], rays[j as usize], prior[i as usize], prior[j as usize]);
            let (a, b) = (ri * xi - rj * xj, ri - rj);
            PairTerms {
                aa: a.norm_squared(),
                two_ab: 2.0 * a.dot(&b),
                bb: b.norm_squared(),
                xi,
                xj,
                map_len: len,
                log_map_len2: (len * len).ln(),
                i,
                j,
            }
        })
        .collect();

    let vote = |t: f64| -> Option<Vote> {
        let mut votes = ScaleVotes::new(params.log_scale_window);
        cast_votes(&terms, rays, space, t, &mut votes);
        votes.densest().map(|(count, log_scale)| Vote { count, scale: log_scale.exp(), shift: t })
    };
    let best = search_shift(&vote, params.shift_range * median_x, params)?;
    // depth = s·(x + t) = s·x + s·t; 1/depth = (x + t)/s.
    let mut estimate = match space {
        PriorSpace::Depth => {
            ScaleShift { scale: best.scale, shift: best.scale * best.shift, support: best.count, space }
        }
        PriorSpace::Disparity => {
            ScaleShift { scale: 1.0 / best.scale, shift: best.shift / best.scale, support: best.count, space }
        }
    };
    refine_scale_shift(&terms, rays, params, &mut estimate);
    (estimate.scale.is_finite() && estimate.scale > 0.0 && estimate.shift.is_finite()).then_some(estimate)
}

/// Every pair's vote for log(scale) = ½·(log ‖q_i − q_j‖² − log ‖o_i − o_j‖²) at shift `t`, into
/// `votes` (cleared first); a pair votes when both its depths are positive. One loop per space,
/// so the hot depth-space one tests no space per pair.
fn cast_votes(terms: &[PairTerms], rays: &[Vector3<f64>], space: PriorSpace, t: f64, votes: &mut ScaleVotes) {
    votes.clear();
    match space {
        PriorSpace::Depth => {
            for c in terms {
                if c.xi + t > 0.0 && c.xj + t > 0.0 {
                    // ‖a + t·b‖², a = r_i x_i − r_j x_j and b = r_i − r_j formed once (in f64: the
                    // difference of neighbouring pixels' rays is small, and its digits must survive).
                    let img_len2 = c.aa + t * (c.two_ab + t * c.bb);
                    if img_len2 > 1e-18 {
                        votes.add(0.5 * (c.log_map_len2 - img_len2.ln()));
                    }
                }
            }
        }
        PriorSpace::Disparity => {
            for c in terms {
                let (Some(ui), Some(uj)) = (unit_depth(space, c.xi, t), unit_depth(space, c.xj, t)) else { continue };
                let (Some(ri), Some(rj)) = (rays.get(c.i as usize), rays.get(c.j as usize)) else { continue };
                let img_len2 = (ri * ui - rj * uj).norm_squared();
                if img_len2 > 1e-18 {
                    votes.add(0.5 * (c.log_map_len2 - img_len2.ln()));
                }
            }
        }
    }
}

/// The densest vote at one candidate shift.
#[derive(Clone, Copy)]
struct Vote {
    count: usize,
    scale: f64,
    shift: f64,
}

/// Coarse-to-fine search over the shift in ±`range`: a coarse grid, then a fine one around its
/// best; the shift with the most votes wins (the first of equals, in the order listed). The
/// shifts of a grid are voted on in parallel, each with its own histogram, and compared in
/// order, so the result does not depend on the threads.
fn search_shift(vote: &(impl Fn(f64) -> Option<Vote> + Sync), range: f64, params: &ScaleShiftParams) -> Option<Vote> {
    use rayon::prelude::*;
    let steps = params.shift_steps.max(1);
    let step = if steps > 1 { 2.0 * range / (steps - 1) as f64 } else { 0.0 };
    let better = |a: Option<Vote>, b: Option<Vote>| match (a, b) {
        (Some(x), Some(y)) => Some(if y.count > x.count { y } else { x }),
        (x, y) => x.or(y),
    };
    let best_of = |best: Option<Vote>, shifts: Vec<f64>| -> Option<Vote> {
        let votes: Vec<Option<Vote>> = shifts.into_par_iter().map(vote).collect();
        votes.into_iter().fold(best, better)
    };
    let best = best_of(None, (0..steps).map(|k| -range + step * k as f64).collect());
    let Some(centre) = best.map(|b| b.shift) else { return best };
    let fine = (1..=params.fine_steps).flat_map(|k| {
        let offset = step * k as f64 / (params.fine_steps + 1) as f64;
        [centre - offset, centre + offset]
    });
    best_of(best, fine.collect())
}

/// Gauss–Newton on (scale, shift) minimising Σ (‖z_i r_i − z_j r_j‖ − ‖q_i − q_j‖)² over the
/// pairs that agree with the current estimate (relative residual below the vote window).
fn refine_scale_shift(terms: &[PairTerms], rays: &[Vector3<f64>], params: &ScaleShiftParams, est: &mut ScaleShift) {
    let tol = params.log_scale_window;
    for _ in 0..params.refine_iterations {
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut used = 0usize;
        for c in terms {
            let Some(PairResidual { r, js, jt }) = pair_residual(c, rays, est, tol) else { continue };
            if r.abs() > tol * c.map_len {
                continue;
            }
            a11 += js * js;
            a12 += js * jt;
            a22 += jt * jt;
            b1 += js * r;
            b2 += jt * r;
            used += 1;
        }
        let det = a11 * a22 - a12 * a12;
        if used < 3 || !(det.abs() > 1e-12 * (a11 * a22).abs().max(1e-300)) {
            break;
        }
        let ds = (a22 * b1 - a12 * b2) / det;
        let dt = (a11 * b2 - a12 * b1) / det;
        let before = *est;
        est.scale -= ds;
        est.shift -= dt;
        est.support = used;
        if !(est.scale > 0.0) || !est.shift.is_finite() {
            *est = before;
            break;
        }
        if ds.abs() < 1e-6 * est.scale.abs() && dt.abs() < 1e-6 * est.shift.abs().max(1e-6) {
            break;
        }
    }
}

/// A pair's image length under `est` minus its map length, and that residual's derivatives by
/// scale and shift.
struct PairResidual {
    r: f64,
    js: f64,
    jt: f64,
}

/// [`PairResidual`] of pair `c`; `None` where a depth is not positive, the image length vanishes,
/// or (depth space) the length is clearly outside `tol` of the map length, decided on its square
/// before the root and divisions (most pairs are outliers): with a margin far above rounding, so
/// a pair that the caller's exact test `|r| ≤ tol·map_len` keeps is never dropped here.
/// In depth space the image difference is scale·a + shift·b (a = r_i x_i − r_j x_j, b = r_i − r_j),
/// so its length and derivatives come from the pair's a·a, a·b, b·b alone.
fn pair_residual(c: &PairTerms, rays: &[Vector3<f64>], est: &ScaleShift, tol: f64) -> Option<PairResidual> {
    let (zi, zj) = (est.depth(c.xi), est.depth(c.xj));
    if !(zi > 0.0 && zj > 0.0 && zi.is_finite() && zj.is_finite()) {
        return None;
    }
    match est.space {
        PriorSpace::Depth => {
            let (s, h) = (est.scale, est.shift);
            let ab = 0.5 * c.two_ab;
            let (diff_a, diff_b) = (s * c.aa + h * ab, s * ab + h * c.bb);
            let len2 = s * diff_a + h * diff_b;
            if !(len2 >= 1e-18) || clearly_outside(len2, c.map_len, tol) {
                return None;
            }
            let len = len2.sqrt();
            Some(PairResidual { r: len - c.map_len, js: diff_a / len, jt: diff_b / len })
        }
        PriorSpace::Disparity => {
            let (ri, rj) = (rays.get(c.i as usize)?, rays.get(c.j as usize)?);
            let diff = ri * zi - rj * zj;
            let len = diff.norm();
            if len < 1e-9 {
                return None;
            }
            let ((si, ti), (sj, tj)) = (est.gradient(c.xi), est.gradient(c.xj));
            let js = diff.dot(&(ri * si - rj * sj)) / len;
            let jt = diff.dot(&(ri * ti - rj * tj)) / len;
            Some(PairResidual { r: len - c.map_len, js, jt })
        }
    }
}

/// Whether a squared length `len2` is surely off `map_len` by more than `tol`·`map_len`: outside
/// the squared band widened by 1e-9 relative (the exact test's rounding is ~1e-16).
fn clearly_outside(len2: f64, map_len: f64, tol: f64) -> bool {
    const MARGIN: f64 = 1e-9;
    let high = map_len * (1.0 + tol);
    let low = map_len * (1.0 - tol);
    len2 > high * high * (1.0 + MARGIN) || (low > 0.0 && len2 < low * low * (1.0 - MARGIN))
}

/// The upper median of `v` (its middle value for an odd count, the upper of the two middle ones
/// for an even one); `None` when empty.
pub fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn scene(seed: u64, n: usize) -> (Vec<Point3<f64>>, Vec<Point3<f64>>) {
        let mut rng = SplitMix64(seed);
        let mut u = || rng.next_u64() as f64 / u64::MAX as f64;
        let cam: Vec<_> = (0..n).map(|_| Point3::new(u() * 4.0 - 2.0, u() * 3.0 - 1.5, 1.0 + u() * 4.0)).collect();
        let pose =
            Isometry3::from_parts(Translation3::new(0.3, -0.2, 1.0), UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3));
        let map = cam.iter().map(|p| pose.transform_point(p)).collect();
        (cam, map)
    }

    /// 60 % of the prior values replaced by random ones.
    fn corrupt(prior: &mut [f64], lo: f64, hi: f64) {
        let mut rng = SplitMix64(99);
        let count = prior.len() * 3 / 5;
        for d in prior.iter_mut().take(count) {
            *d = lo + (hi - lo) * rng.next_u64() as f64 / u64::MAX as f64;
        }
    }

    #[test]
    fn scale_and_shift_are_recovered_with_outliers() {
        // Prior coordinate d = (z − t)/s.
        let (s_true, t_true) = (1.7, 0.45);
        let (cam, map) = scene(5, 300);
        let rays: Vec<_> = cam.iter().map(|p| p.coords / p.z).collect();
        let mut prior: Vec<_> = cam.iter().map(|p| (p.z - t_true) / s_true).collect();
        corrupt(&mut prior, 0.2, 3.2);
        let est =
            estimate_scale_shift(&rays, &prior, &map, &[], PriorSpace::Depth, &ScaleShiftParams::default()).unwrap();
        assert!((est.scale - s_true).abs() < 0.02 * s_true, "{est:?}");
        assert!((est.shift - t_true).abs() < 0.03, "{est:?}");
    }

    #[test]
    fn affine_disparity_is_aligned_in_inverse_depth() {
        // An affine-invariant disparity: prior = a/z + b with a large shift b (40 % of the median).
        let (a_true, b_true) = (3.0, 0.4);
        let (cam, map) = scene(7, 300);
        let rays: Vec<_> = cam.iter().map(|p| p.coords / p.z).collect();
        let mut prior: Vec<_> = cam.iter().map(|p| a_true / p.z + b_true).collect();
        corrupt(&mut prior, 0.9, 3.4);
        let est = estimate_scale_shift(&rays, &prior, &map, &[], PriorSpace::Disparity, &ScaleShiftParams::default())
            .unwrap();
        // 1/z = (prior − b)/a.
        assert!((est.scale - 1.0 / a_true).abs() < 0.02 / a_true, "{est:?}");
        assert!((est.shift + b_true / a_true).abs() < 0.02, "{est:?}");
        for p in cam.iter().skip(200).take(20) {
            let z = est.depth(a_true / p.z + b_true);
            assert!((z - p.z).abs() < 0.03 * p.z, "{z} vs {}", p.z);
        }
    }

    #[test]
    fn alignment_is_blind_to_the_map_units() {
        // The same scene in millimetres: the pair-length filter is relative, so the same pairs vote.
        let (cam, map) = scene(11, 200);
        let rays: Vec<_> = cam.iter().map(|p| p.coords / p.z).collect();
        let prior: Vec<_> = cam.iter().map(|p| p.z / 2.0).collect();
        let p = ScaleShiftParams::default();
        let metres = estimate_scale_shift(&rays, &prior, &map, &[], PriorSpace::Depth, &p).unwrap();
        let mm: Vec<_> = map.iter().map(|q| Point3::from(q.coords * 1000.0)).collect();
        let millimetres = estimate_scale_shift(&rays, &prior, &mm, &[], PriorSpace::Depth, &p).unwrap();
        assert!((millimetres.scale / metres.scale - 1000.0).abs() < 1.0, "{metres:?} {millimetres:?}");
    }
}
