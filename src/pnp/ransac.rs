//! Robust estimation: PROSAC (score-ordered) or uniform sampling of P3P samples, SPRT + MSAC
//! scoring with early exit, LO-RANSAC, adaptive termination, final refinement, covariance.
//!
//! The correspondences are stored once in a random order ("positions") so that scoring streams
//! through memory and the SPRT sees an unbiased sequence; PROSAC works on score ranks mapped to
//! positions. Nothing is allocated inside the sampling loop.

use super::epnp::epnp_normalized;
use super::lm::{
    check_basic, checked_pairs, covariance, finite_pairs, lm_refine, refine_all, reproj_err2, Cam, Loss, RefineOptions,
    RefineResult, MIN_DEPTH,
};
use super::p3p::p3p_unit;
use super::rng::WyRand;
use super::{Agreement, Guidance, MapToCamera, PnpError, PnpParams, PnpSolution, RobustLoss, Verification};
use crate::geometry::{Intrinsics, PriorSpace};
use nalgebra::{Matrix3, Point2, Point3, SymmetricEigen, Vector2, Vector3};

/// Sample size of the minimal solver.
const M: usize = 3;
/// Assumed probability that a correspondence agrees with a wrong model (SPRT δ).
const SPRT_DELTA: f64 = 0.02;
/// SPRT assumes at least this inlier ratio for a good model, so that it also prunes before a
/// good model is found (a good model with fewer inliers is rarely drawn within the budget).
const SPRT_MIN_EPS: f64 = 0.05;
/// SPRT decision threshold A: a good model is wrongly rejected with probability ≲ 1/A.
const SPRT_A: f64 = 300.0;
/// Rounds of local optimisation per new best model, and LM iterations per round.
const LO_ROUNDS: usize = 4;
const LO_LM_ITERATIONS: usize = 6;
/// Rounds of the final refinement and their LM iterations.
const FINAL_ROUNDS: usize = 3;
const FINAL_LM_ITERATIONS: usize = 30;
/// Non-randomness test of PROSAC's stopping length: tail at `z` σ of a binomial with this rate.
const NONRANDOM_BETA: f64 = 0.05;
const NONRANDOM_Z: f64 = 3.0;

/// PROSAC sampler (Chum & Matas 2005) over ranks `0..n`, best score first; it draws from a
/// growing prefix and reaches uniform sampling over all ranks after about `t_max` samples.
struct Prosac {
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

/// Samples needed to draw an all-inlier minimal sample with probability `confidence` when a
/// fraction `eps` are inliers; `sprt_keep` is the probability that SPRT keeps a good model.
fn samples_needed(eps: f64, confidence: f64, sprt_keep: f64) -> f64 {
    let p = eps.powi(M as i32) * sprt_keep;
    if p >= 1.0 {
        return 0.0;
    }
    if !(p > 0.0) {
        return f64::INFINITY;
    }
    ((1.0 - confidence).ln() / (-p).ln_1p()).max(0.0)
}

/// Outcome of scoring one hypothesis.
enum Score {
    /// Stopped early: it cannot beat the best, or SPRT rejected it.
    Rejected,
    /// Fully evaluated and better than the best: MSAC score and inlier count.
    Better(f64, usize),
}

/// SPRT log-likelihood increments, active once the best model's inlier ratio clearly exceeds δ.
#[derive(Clone, Copy)]
struct Sprt {
    log_in: f64,
    log_out: f64,
    log_a: f64,
}

impl Sprt {
    fn new(eps: f64) -> Option<Self> {
        let eps = eps.max(SPRT_MIN_EPS);
        (eps > 1.5 * SPRT_DELTA && eps < 1.0).then(|| Self {
            log_in: (SPRT_DELTA / eps).ln(),
            log_out: ((1.0 - SPRT_DELTA) / (1.0 - eps)).ln(),
            log_a: SPRT_A.ln(),
        })
    }
}

struct Acc {
    score: f64,
    inliers: usize,
    lambda: f64,
}

struct Data {
    cam: Cam,
    px: Vec<Vector2<f64>>,
    pw: Vec<Vector3<f64>>,
    th2: f64,
}

impl Data {
    /// MSAC score with early exit once it reaches `best` or SPRT rejects. Evaluation starts at
    /// position `start` and wraps around, so no fixed prefix decides every SPRT.
    #[inline(always)]
    fn score_bounded(&self, pose: &MapToCamera, best: f64, sprt: Option<Sprt>, start: usize) -> Score {
        let mut acc = Acc { score: 0.0, inliers: 0, lambda: 0.0 };
        let (pw, px) = (&self.pw, &self.px);
        if !self.score_range(pose, &pw[start..], &px[start..], best, &sprt, &mut acc)
            || !self.score_range(pose, &pw[..start], &px[..start], best, &sprt, &mut acc)
        {
            return Score::Rejected;
        }
        Score::Better(acc.score, acc.inliers)
    }

    /// Accumulates over one contiguous range; `false` once rejected.
    #[inline(always)]
    fn score_range(
        &self,
        pose: &MapToCamera,
        pw: &[Vector3<f64>],
        px: &[Vector2<f64>],
        best: f64,
        sprt: &Option<Sprt>,
        acc: &mut Acc,
    ) -> bool {
        let (cam, th2) = (&self.cam, self.th2);
        let r = &pose.rotation;
        let t = &pose.translation;
        for (p, q) in pw.iter().zip(px) {
            let x = r * p + t;
            let e2 = if x.z > MIN_DEPTH {
                let iz = 1.0 / x.z;
                let du = cam.fx * x.x * iz + cam.cx - q.x;
                let dv = cam.fy * x.y * iz + cam.cy - q.y;
                du * du + dv * dv
            } else {
                f64::INFINITY
            };
            let inlier = e2 < th2;
            if inlier {
                acc.score += e2;
                acc.inliers += 1;
            } else {
                acc.score += th2;
            }
            if acc.score >= best {
                return false;
            }
            if let Some(s) = sprt {
                acc.lambda += if inlier { s.log_in } else { s.log_out };
                if acc.lambda > s.log_a {
                    return false;
                }
            }
        }
        true
    }

    /// MSAC score and inlier count, no early exit.
    fn score_full(&self, pose: &MapToCamera) -> (f64, usize) {
        let mut score = 0.0;
        let mut inliers = 0;
        for (p, q) in self.pw.iter().zip(&self.px) {
            let e2 = reproj_err2(&self.cam, pose, p, q);
            if e2 < self.th2 {
                score += e2;
                inliers += 1;
            } else {
                score += self.th2;
            }
        }
        (score, inliers)
    }

    /// Depth of the map point at `pos` in the camera of `pose`.
    fn pose_depth(&self, pose: &MapToCamera, pos: usize) -> f64 {
        (pose.rotation * self.pw[pos] + pose.translation).z
    }

    fn collect_inliers(&self, pose: &MapToCamera, out: &mut Vec<usize>) {
        out.clear();
        for (i, (p, q)) in self.pw.iter().zip(&self.px).enumerate() {
            if reproj_err2(&self.cam, pose, p, q) < self.th2 {
                out.push(i);
            }
        }
    }
}

/// The prior's check on a hypothesis' inliers: their depths under it must agree with the prior
/// coordinates through one increasing affine map in `space`, within `tolerance` (relative).
struct PriorCheck {
    values: Vec<f64>,
    space: PriorSpace,
    tolerance: f64,
}

/// Coverage scoring (see [`PnpParams::coverage_cell_px`]): each position's image cell, and a
/// stamped scratch array that counts distinct cells without clearing. With prior depths, only
/// inliers whose depth under the pose agrees with the prior count (see [`depth_agreement`]).
struct Coverage {
    cell: Vec<u32>,
    seen: Vec<u32>,
    stamp: u32,
    /// Prior coordinate per position (affine in its space; NaN where unknown).
    prior: Option<PriorCheck>,
    inliers: Vec<usize>,
    depths: Vec<(f64, f64)>,
}

impl Coverage {
    fn new(px: &[Vector2<f64>], cell_px: f64, prior: Option<PriorCheck>) -> Option<Self> {
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
    /// One pass from position `start` (wrapping), as [`Data::score_bounded`]: `None` once SPRT
    /// rejects the pose or it can no longer cover `best_cells` cells; a pose that cannot beat
    /// `best` is not checked against the prior. Returns (cost, inliers, cells).
    fn cost(
        &mut self,
        data: &Data,
        pose: &MapToCamera,
        (best, best_cells): (f64, usize),
        sprt: Option<Sprt>,
        start: usize,
    ) -> Option<(f64, usize, usize)> {
        let stamp = self.next_stamp();
        let (mut cells, mut msac, mut lambda) = (0usize, 0.0, 0.0);
        let n_pos = data.pw.len();
        self.inliers.clear();
        for (k, i) in (start..n_pos).chain(0..start).enumerate() {
            let e2 = reproj_err2(&data.cam, pose, &data.pw[i], &data.px[i]);
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
        let n = data.pw.len() as f64;
        let cost = |cells: usize, inliers: usize, msac: f64| {
            -(cells as f64) - 0.5 * inliers as f64 / (n + 1.0) + 0.25 * msac / (n * data.th2 + 1.0)
        };
        let plain = cost(cells, self.inliers.len(), msac);
        let Some(prior) = &self.prior else { return Some((plain, self.inliers.len(), cells)) };
        if plain >= best {
            return Some((plain, self.inliers.len(), cells));
        }
        // Inliers whose pose depth disagrees with the prior count as outliers.
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
        Some((cost(cells, kept, msac), kept, cells))
    }
}

/// A hypothesis kept for verification: its pose, ranking cost, covered cells and inliers.
struct Candidate {
    pose: MapToCamera,
    cost: f64,
    cells: usize,
    inliers: usize,
    /// Inlier positions as a bit set, for the cluster test.
    members: Vec<u64>,
    /// The verifier's agreement once verified (after local optimisation).
    agreement: Option<Agreement>,
}

/// The best distinct hypotheses by coverage cost, and the verifier that chooses among them (see
/// [`Verification`]). Two hypotheses are one when most of the smaller inlier set is shared:
/// the cluster keeps its best.
struct Pool<'a> {
    verification: Verification<'a>,
    /// Each candidate is locally optimised before it is verified.
    local_optimize: bool,
    items: Vec<Candidate>,
}

impl<'a> Pool<'a> {
    fn new(verification: Verification<'a>, local_optimize: bool) -> Self {
        Self { verification, local_optimize, items: Vec::with_capacity(verification.candidates + 1) }
    }

    fn is_full(&self) -> bool {
        self.items.len() >= self.verification.candidates
    }

    /// Index of the candidate with the highest (`worst`) or lowest cost.
    fn extreme(&self, worst: bool) -> Option<usize> {
        let by_cost = |&a: &usize, &b: &usize| self.items[a].cost.total_cmp(&self.items[b].cost);
        let indices = 0..self.items.len();
        if worst {
            indices.max_by(by_cost)
        } else {
            indices.min_by(by_cost)
        }
    }

    /// The (cost, cells) a hypothesis must beat to enter: the worst kept once full.
    fn bound(&self) -> (f64, usize) {
        match self.extreme(true) {
            Some(w) if self.is_full() => (self.items[w].cost, self.items[w].cells),
            _ => (f64::INFINITY, 0),
        }
    }

    /// Offers a hypothesis with its inlier positions among `n`.
    fn offer(&mut self, pose: &MapToCamera, cost: f64, cells: usize, inliers: &[usize], n: usize) {
        let mut members = vec![0u64; n.div_ceil(64)];
        for &i in inliers {
            members[i / 64] |= 1 << (i % 64);
        }
        let candidate = Candidate { pose: *pose, cost, cells, inliers: inliers.len(), members, agreement: None };
        if let Some(same) = self.items.iter_mut().find(|c| same_cluster(c, &candidate)) {
            if cost < same.cost {
                *same = candidate;
            }
            return;
        }
        if self.is_full() {
            match self.extreme(true) {
                Some(w) if cost < self.items[w].cost => {
                    self.items.swap_remove(w);
                }
                _ => return,
            }
        }
        self.items.push(candidate);
    }

    /// The agreement of candidate `i`, verified once: after local optimisation (optional).
    fn verify(
        &mut self,
        i: usize,
        data: &Data,
        coverage: Option<&mut Coverage>,
        idx_buf: &mut Vec<usize>,
    ) -> Agreement {
        let c = &mut self.items[i];
        if let Some(agreement) = c.agreement {
            return agreement;
        }
        if self.local_optimize {
            let lo = local_optimization(data, coverage, idx_buf, (c.pose, c.cost, c.inliers, c.cells));
            (c.pose, c.cost, c.cells) = (lo.0, lo.1, lo.3);
        }
        let agreement = self.verification.verifier.verify(&c.pose.to_camera_to_map());
        c.agreement = Some(agreement);
        agreement
    }

    /// Verifies every candidate; the best in-view agreement.
    fn verify_all(&mut self, data: &Data, mut coverage: Option<&mut Coverage>, idx_buf: &mut Vec<usize>) -> f64 {
        let min_view = self.verification.min_view;
        (0..self.items.len())
            .map(|i| self.verify(i, data, coverage.as_deref_mut(), idx_buf).in_view_share(min_view))
            .fold(0.0, f64::max)
    }

    /// Verifies the lowest-cost candidate alone; its in-view agreement.
    fn verify_best(&mut self, data: &Data, coverage: Option<&mut Coverage>, idx_buf: &mut Vec<usize>) -> f64 {
        let min_view = self.verification.min_view;
        self.extreme(false).map_or(0.0, |i| self.verify(i, data, coverage, idx_buf).in_view_share(min_view))
    }

    /// The best in-view agreement of any verified candidate: how far the frame's evidence can be
    /// trusted.
    fn trust(&self) -> f64 {
        let min_view = self.verification.min_view;
        self.items.iter().filter_map(|c| c.agreement).map(|a| a.in_view_share(min_view)).fold(0.0, f64::max)
    }

    /// The verified candidate with the most agreement + `coverage_weight`·cells / most cells;
    /// when no candidate reaches `min_trust`, the lowest-cost one (geometry alone).
    fn choose(&self) -> Option<MapToCamera> {
        if self.trust() < self.verification.min_trust {
            return self.extreme(false).map(|i| self.items[i].pose);
        }
        let most_cells = self.items.iter().map(|c| c.cells).max()?.max(1) as f64;
        let weight = self.verification.coverage_weight;
        self.items
            .iter()
            .filter_map(|c| Some((c.agreement?.share() + weight * c.cells as f64 / most_cells, c)))
            .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cost.total_cmp(&a.1.cost)))
            .map(|(_, c)| c.pose)
    }
}

/// Counts the verifications in a row that chose the same pose: a frame whose choice stays put
/// while more hypotheses are drawn is settled, whatever its prior agreement.
#[derive(Default)]
struct Settling {
    last: Option<MapToCamera>,
    same: usize,
}

impl Settling {
    /// Records this check's choice; whether it was the same in the last `checks` checks (0: never).
    fn unchanged(&mut self, choice: Option<MapToCamera>, checks: usize) -> bool {
        if choice.is_some() && choice == self.last {
            self.same += 1;
        } else {
            self.same = 1;
            self.last = choice;
        }
        checks > 0 && self.same >= checks
    }
}

/// Whether two candidates share more than half of the smaller inlier set.
fn same_cluster(a: &Candidate, b: &Candidate) -> bool {
    let shared: u32 = a.members.iter().zip(&b.members).map(|(x, y)| (x & y).count_ones()).sum();
    2 * shared as usize > a.inliers.min(b.inliers)
}

/// Candidate maps [`depth_agreement`] tries at most (every pair while there are few).
const DEPTH_MAP_CANDIDATES: usize = 120;
/// Known pairs a candidate map is counted on, at most.
const DEPTH_AGREEMENT_SAMPLE: usize = 64;
/// Candidate maps [`depth_agreement`] tries at least before its adaptive stop.
const MIN_DEPTH_MAP_CANDIDATES: usize = 16;

/// Draws of two pairs needed to have drawn two agreeing ones with 99.99 % confidence when a share
/// `agreeing` of the pairs agree (∞ for none).
fn two_point_draws(agreeing: f64) -> f64 {
    let both = agreeing * agreeing;
    if both >= 1.0 {
        return 1.0;
    }
    (1e-4f64).ln() / (1.0 - both).ln()
}

/// Which (prior, depth) pairs agree with one affine map `depth ≈ a·prior + b`, `a > 0`, within
/// `tolerance`·depth: the map agreed on by the most pairs, each candidate defined by two pairs
/// (a monocular prior is right up to scale and shift) — every two while there are at most
/// [`DEPTH_MAP_CANDIDATES`], else that many spread deterministically. Pairs with an unknown
/// prior always agree (no evidence against them); below three known pairs every pair agrees.
pub(crate) fn depth_agreement(pairs: &[(f64, f64)], tolerance: f64) -> Vec<bool> {
    let known: Vec<usize> = (0..pairs.len()).filter(|&i| pairs[i].0.is_finite() && pairs[i].1 > 0.0).collect();
    let mut best = vec![true; pairs.len()];
    if known.len() < 3 {
        return best;
    }
    let agrees = |a: f64, b: f64, (d, z): (f64, f64)| (z - (a * d + b)).abs() < tolerance * z;
    let k = known.len();
    let all_pairs = k * (k - 1) / 2;
    let candidates: Vec<(usize, usize)> = if all_pairs <= DEPTH_MAP_CANDIDATES {
        let known = &known;
        (0..k).flat_map(|x| (x + 1..k).map(move |y| (known[x], known[y]))).collect()
    } else {
        // Pairs spread over the index space: (x, x + offset) with offsets drawn by a fixed LCG.
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        (0..DEPTH_MAP_CANDIDATES)
            .map(|c| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let x = c * k / DEPTH_MAP_CANDIDATES;
                let y = (x + 1 + (state >> 33) as usize % (k - 1)) % k;
                (known[x], known[y])
            })
            .collect()
    };
    // Candidates are counted on at most DEPTH_AGREEMENT_SAMPLE known pairs (evenly strided);
    // the winner then decides every pair.
    let stride = k.div_ceil(DEPTH_AGREEMENT_SAMPLE);
    let mut best_count = 0;
    let mut best_map = None;
    let sampled = known.len().div_ceil(stride);
    for (tried, (i, j)) in candidates.into_iter().enumerate() {
        // Adaptive stopping, as RANSAC's: enough two-pair draws that one of them lies on the
        // best map so far with 99.99 % confidence (most frames: a few dozen instead of 120).
        if tried >= MIN_DEPTH_MAP_CANDIDATES && tried as f64 >= two_point_draws(best_count as f64 / sampled as f64) {
            break;
        }
        let ((di, zi), (dj, zj)) = (pairs[i], pairs[j]);
        if (di - dj).abs() < 1e-9 {
            continue;
        }
        let a = (zi - zj) / (di - dj);
        if !(a > 0.0) {
            continue;
        }
        let b = zi - a * di;
        let count = known.iter().step_by(stride).filter(|&&k| agrees(a, b, pairs[k])).count();
        if count > best_count {
            best_count = count;
            best_map = Some((a, b));
        }
    }
    if let Some((a, b)) = best_map {
        for &k in &known {
            best[k] = agrees(a, b, pairs[k]);
        }
    }
    if best_count == 0 {
        // No two pairs define an increasing map (e.g. all at one prior depth): no evidence.
        best.iter_mut().for_each(|b| *b = true);
    }
    best
}

fn validate(params: &PnpParams) -> Result<(), PnpError> {
    if !(params.threshold_px.is_finite() && params.threshold_px > 0.0) {
        return Err(PnpError::InvalidParams("threshold_px must be finite and > 0"));
    }
    if !(params.confidence > 0.0 && params.confidence <= 1.0) {
        return Err(PnpError::InvalidParams("confidence must be in (0, 1]"));
    }
    if params.max_iterations == 0 {
        return Err(PnpError::InvalidParams("max_iterations must be > 0"));
    }
    if !(params.loss_scale_px.is_finite() && params.loss_scale_px > 0.0) {
        return Err(PnpError::InvalidParams("loss_scale_px must be finite and > 0"));
    }
    Ok(())
}

/// Rejects coincident or collinear map point sets.
fn check_spread(pw: &[Vector3<f64>]) -> Result<(), PnpError> {
    let n = pw.len() as f64;
    let c = pw.iter().sum::<Vector3<f64>>() / n;
    let mut cov = Matrix3::zeros();
    for p in pw {
        let d = p - c;
        cov += d * d.transpose();
    }
    if !cov.iter().all(|v| v.is_finite()) {
        return Err(PnpError::Degenerate("map point spread overflows"));
    }
    let eig =
        SymmetricEigen::try_new(cov, f64::EPSILON, 1000).ok_or(PnpError::Degenerate("eigen decomposition failed"))?;
    let mut ev: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    if !(ev[0].is_finite() && ev[0] > 0.0) {
        return Err(PnpError::Degenerate("map points coincide"));
    }
    if ev[1] <= 1e-10 * ev[0] {
        return Err(PnpError::Degenerate("map points are collinear"));
    }
    Ok(())
}

/// Robust PnP: the camera-to-map pose from putative pixel ↔ map-point correspondences, most
/// possibly wrong.
///
/// * `scores` (higher = more likely correct, one per correspondence) switch on PROSAC sampling
///   from the top-ranked correspondences, growing to uniform; `None` samples uniformly
///   (plain LO-RANSAC, which also serves as the baseline on raw correspondences).
/// * Inliers: reprojection error below `params.threshold_px` and in front of the camera.
/// * Deterministic for a given `seed`.
/// * Non-finite correspondences are ignored (never inliers); errors for invalid intrinsics or
///   parameters, mismatched lengths, fewer than `max(4, min_inliers)` usable correspondences,
///   coincident/collinear map points, or no pose with `min_inliers` inliers.
pub fn solve_pnp_ransac(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    scores: Option<&[f32]>,
    params: &PnpParams,
    seed: u64,
) -> Result<PnpSolution, PnpError> {
    solve_pnp_ransac_with_prior(intrinsics, pixels, points, scores, None, params, seed)
}

/// [`solve_pnp_ransac`] that also knows each pixel's depth from a monocular prior (right up to
/// an unknown scale and shift; NaN where unknown). With coverage scoring and
/// `params.prior_tolerance > 0`, a hypothesis' inliers count only when their depths under it
/// agree with the prior through one increasing affine map: a pose that explains true matches
/// and a displaced patch at once puts the two at depths the prior contradicts.
pub fn solve_pnp_ransac_with_prior(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    scores: Option<&[f32]>,
    prior_depths: Option<&[f64]>,
    params: &PnpParams,
    seed: u64,
) -> Result<PnpSolution, PnpError> {
    let guidance = Guidance { scores, prior_depths, ..Guidance::default() };
    solve_pnp_ransac_guided(intrinsics, pixels, points, &guidance, params, seed)
}

/// Robust PnP with everything beyond the correspondences that guides it ([`Guidance`]): scores
/// (PROSAC), prior depths (see [`solve_pnp_ransac_with_prior`]) and a verifier. With a verifier
/// and coverage scoring, the `candidates` best distinct hypotheses are kept (a hypothesis
/// competes with the pool's worst, not the best, and SPRT assumes that one's support) and the
/// verifier's choice among them is refined and returned.
pub fn solve_pnp_ransac_guided(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    guidance: &Guidance,
    params: &PnpParams,
    seed: u64,
) -> Result<PnpSolution, PnpError> {
    let Guidance { scores, prior_depths, prior_space, verification } = *guidance;
    check_basic(intrinsics, pixels.len(), points.len())?;
    if let Some(d) = prior_depths {
        if d.len() != pixels.len() {
            return Err(PnpError::LengthMismatch { pixels: pixels.len(), points: points.len(), scores: Some(d.len()) });
        }
    }
    if let Some(s) = scores {
        if s.len() != pixels.len() {
            return Err(PnpError::LengthMismatch { pixels: pixels.len(), points: points.len(), scores: Some(s.len()) });
        }
    }
    validate(params)?;
    let (px0, pw0, orig0) = finite_pairs(pixels, points);
    let n = px0.len();
    let required = params.min_inliers.max(4);
    if n < required {
        return Err(PnpError::TooFewPoints { usable: n, required });
    }
    check_spread(&pw0)?;

    let mut rng = WyRand::new(seed);
    // Positions: a random order of the usable correspondences.
    let mut order: Vec<usize> = (0..n).collect();
    rng.shuffle(&mut order);
    let cam = Cam::new(intrinsics);
    let data = Data {
        cam,
        px: order.iter().map(|&i| px0[i]).collect(),
        pw: order.iter().map(|&i| pw0[i]).collect(),
        th2: params.threshold_px * params.threshold_px,
    };
    let orig: Vec<usize> = order.iter().map(|&i| orig0[i]).collect();
    let bearings: Vec<Vector3<f64>> = data
        .px
        .iter()
        .map(|p| Vector3::new((p.x - cam.cx) / cam.fx, (p.y - cam.cy) / cam.fy, 1.0).normalize())
        .collect();
    // Rank → position (best score first) for PROSAC.
    let pos_of_rank: Option<Vec<usize>> = scores.map(|s| {
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
        ranks
    });
    let mut prosac = pos_of_rank.as_ref().map(|_| Prosac::new(n, params.max_iterations));
    let prior = prior_depths.filter(|_| params.prior_tolerance > 0.0).map(|d| PriorCheck {
        values: orig.iter().map(|&i| d[i]).collect(),
        space: prior_space,
        tolerance: params.prior_tolerance,
    });
    let mut coverage = Coverage::new(&data.px, params.coverage_cell_px, prior);
    let mut pool = verification
        .filter(|v| v.candidates > 0 && coverage.is_some())
        .map(|v| Pool::new(v, params.local_optimization));

    let sprt_keep = 1.0 - 1.0 / SPRT_A;
    let mut best: Option<MapToCamera> = None;
    let mut best_score = f64::INFINITY;
    let mut best_support = 0usize;
    let mut sprt: Option<Sprt> = Sprt::new(0.0);
    let mut needed = f64::INFINITY;
    let mut idx_buf: Vec<usize> = Vec::with_capacity(n);
    let mut flags: Vec<bool> = vec![false; n];
    let mut iterations = 0usize;

    // A verifier can only choose a hypothesis that was drawn: sample at least its minimum, then
    // verify the pool every as many samples, and go on while no candidate agrees well enough.
    let (min_iterations, max_iterations) = match &pool {
        Some(p) => (
            params.min_iterations.max(p.verification.min_iterations),
            params.max_iterations.max(p.verification.max_iterations),
        ),
        None => (params.min_iterations, params.max_iterations),
    };
    let mut accepted = false;
    let mut settled = Settling::default();
    let mut early_checked = false;
    let mut early_accepted = false;
    while iterations < max_iterations {
        // Where plain RANSAC stops.
        let plain_done = iterations >= params.min_iterations && (iterations as f64) >= needed;
        match pool.as_mut() {
            Some(p) => {
                let accept = p.verification.accept;
                // There the best hypothesis alone is verified first: an easy frame stops there.
                if plain_done && !early_checked {
                    early_checked = true;
                    if p.verify_best(&data, coverage.as_mut(), &mut idx_buf) >= accept {
                        early_accepted = true;
                        break;
                    }
                }
                let check_every = p.verification.check_every.max(1);
                if !accepted && iterations >= min_iterations && iterations % check_every == 0 {
                    accepted = p.verify_all(&data, coverage.as_mut(), &mut idx_buf) >= accept
                        || settled.unchanged(p.choose(), p.verification.settle_checks);
                }
                if accepted && (plain_done || iterations >= params.max_iterations) {
                    break;
                }
            }
            None if plain_done => break,
            None => {}
        }
        iterations += 1;
        let s = match (&mut prosac, &pos_of_rank) {
            (Some(p), Some(map)) => {
                let r = p.sample(&mut rng);
                [map[r[0]], map[r[1]], map[r[2]]]
            }
            _ => distinct3(&mut rng, n),
        };
        let sols =
            p3p_unit(&[bearings[s[0]], bearings[s[1]], bearings[s[2]]], &[data.pw[s[0]], data.pw[s[1]], data.pw[s[2]]]);
        let mut improved = false;
        let start = if sols.is_empty() { 0 } else { rng.below(n) };
        for pose in sols.iter() {
            // `support`: what SPRT and the stopping rule count, cells with coverage scoring
            // (never more than the inliers, so both stay conservative), else inliers.
            let (score, inliers, support) = match coverage.as_mut() {
                // One pass: cells, SPRT and the cell bound together.
                Some(cov) => {
                    // With a pool, a hypothesis must beat the pool's worst, and SPRT assumes
                    // that one's support.
                    let (bound, sprt) = match &pool {
                        Some(p) => (p.bound(), Sprt::new(p.bound().1 as f64 / n as f64)),
                        None => ((best_score, best_support), sprt),
                    };
                    match cov.cost(&data, pose, bound, sprt, start) {
                        Some((c, i, cells)) => {
                            if let Some(p) = pool.as_mut() {
                                p.offer(pose, c, cells, &cov.inliers, n);
                            }
                            if c < best_score {
                                (c, i, cells)
                            } else {
                                continue;
                            }
                        }
                        None => continue,
                    }
                }
                None => match data.score_bounded(pose, best_score, sprt, start) {
                    Score::Better(score, inliers) => (score, inliers, inliers),
                    Score::Rejected => continue,
                },
            };
            let (mut pose, mut score, inliers, mut support) = (*pose, score, inliers, support);
            if params.local_optimization && inliers >= 4 {
                (pose, score, _, support) =
                    local_optimization(&data, coverage.as_mut(), &mut idx_buf, (pose, score, inliers, support));
            }
            if let (Some(p), Some(cov)) = (pool.as_mut(), coverage.as_mut()) {
                // The local optimum joins the pool (its cluster keeps the better of the two).
                if let Some((c, _, cells)) = cov.cost(&data, &pose, (f64::INFINITY, 0), None, 0) {
                    p.offer(&pose, c, cells, &cov.inliers, n);
                }
            }
            best = Some(pose);
            best_score = score;
            best_support = support;
            improved = true;
        }
        if let (true, Some(pose)) = (improved, &best) {
            sprt = Sprt::new(best_support as f64 / n as f64);
            needed = match &pos_of_rank {
                None => samples_needed(best_support as f64 / n as f64, params.confidence, sprt_keep),
                Some(map) => {
                    for (pos, f) in flags.iter_mut().enumerate() {
                        *f = reproj_err2(&cam, pose, &data.pw[pos], &data.px[pos]) < data.th2;
                    }
                    prosac_needed(map, &flags, params, sprt_keep)
                }
            };
        }
    }

    if let (Some(pool), false) = (pool.as_mut(), early_accepted) {
        pool.verify_all(&data, coverage.as_mut(), &mut idx_buf);
        if let Some(chosen) = pool.choose() {
            best = Some(chosen);
        }
    }
    let Some(mut pose) = best else {
        return Err(PnpError::NoConsensus { inliers: 0, required });
    };
    if params.refine {
        let loss = Loss::new(params.loss, params.loss_scale_px);
        let mut prev: Vec<usize> = Vec::new();
        data.collect_inliers(&pose, &mut idx_buf);
        for _ in 0..FINAL_ROUNDS {
            if idx_buf.len() < 4 || idx_buf == prev {
                break;
            }
            let (cand, _, _) = lm_refine(&cam, &data.px, &data.pw, &idx_buf, pose, &loss, FINAL_LM_ITERATIONS);
            std::mem::swap(&mut prev, &mut idx_buf);
            data.collect_inliers(&cand, &mut idx_buf);
            if idx_buf.len() < required.min(prev.len()) {
                // Refinement lost the consensus: keep the unrefined pose.
                std::mem::swap(&mut prev, &mut idx_buf);
                break;
            }
            pose = cand;
        }
    }
    data.collect_inliers(&pose, &mut idx_buf);
    let num_inliers = idx_buf.len();
    if num_inliers < required {
        return Err(PnpError::NoConsensus { inliers: num_inliers, required });
    }
    let sq: f64 = idx_buf.iter().map(|&i| reproj_err2(&cam, &pose, &data.pw[i], &data.px[i])).sum();
    let rmse_px = (sq / num_inliers as f64).sqrt();
    let cov = covariance(&cam, &data.px, &data.pw, &idx_buf, &pose)
        .ok_or(PnpError::Degenerate("pose covariance is not finite"))?;
    let mut inliers = vec![false; pixels.len()];
    for &i in &idx_buf {
        inliers[orig[i]] = true;
    }
    Ok(PnpSolution { pose: pose.to_camera_to_map(), inliers, num_inliers, iterations, rmse_px, covariance: cov })
}

/// LO-RANSAC's inner step: rounds of least squares on the inliers while the ranking cost
/// improves and the inliers grow. Takes and returns (pose, cost, inliers, support).
fn local_optimization(
    data: &Data,
    mut coverage: Option<&mut Coverage>,
    idx_buf: &mut Vec<usize>,
    (mut pose, mut score, mut inliers, mut support): (MapToCamera, f64, usize, usize),
) -> (MapToCamera, f64, usize, usize) {
    let loss = Loss::new(RobustLoss::Trivial, 1.0);
    for _ in 0..LO_ROUNDS {
        data.collect_inliers(&pose, idx_buf);
        if idx_buf.len() < 4 {
            break;
        }
        let (cand, _, _) = lm_refine(&data.cam, &data.px, &data.pw, idx_buf, pose, &loss, LO_LM_ITERATIONS);
        let (cs, ci, csup) = match coverage.as_deref_mut() {
            Some(cov) => match cov.cost(data, &cand, (score, support), None, 0) {
                Some(c) => c,
                None => break,
            },
            None => {
                let (cs, ci) = data.score_full(&cand);
                (cs, ci, ci)
            }
        };
        if !(cs < score) {
            break;
        }
        let grew = ci > inliers;
        (pose, score, inliers, support) = (cand, cs, ci, csup);
        if !grew {
            break;
        }
    }
    (pose, score, inliers, support)
}

/// PROSAC stopping length: the fewest samples over prefix lengths `n*` whose best-model inliers
/// `I(n*)` pass the non-randomness test, using the inlier ratio `I(n*)/n*` of that prefix.
fn prosac_needed(pos_of_rank: &[usize], inlier_at_pos: &[bool], params: &PnpParams, sprt_keep: f64) -> f64 {
    let n = pos_of_rank.len();
    let mut count = 0usize;
    let mut needed = f64::INFINITY;
    let min_len = 10.min(n);
    for (r, &pos) in pos_of_rank.iter().enumerate() {
        count += inlier_at_pos[pos] as usize;
        let len = r + 1;
        if len < min_len {
            continue;
        }
        let k = (len - M) as f64;
        let i_min = M as f64 + NONRANDOM_BETA * k + NONRANDOM_Z * (NONRANDOM_BETA * (1.0 - NONRANDOM_BETA) * k).sqrt();
        if (count as f64) < i_min || count < params.min_inliers.max(4) {
            continue;
        }
        needed = needed.min(samples_needed(count as f64 / len as f64, params.confidence, sprt_keep));
    }
    needed
}

/// Non-minimal PnP: EPnP on all finite correspondences (≥ 4 non-planar map points, assumed
/// inliers) then Levenberg–Marquardt on the reprojection error. The pose is camera-to-map.
pub fn solve_pnp_nonminimal(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    options: &RefineOptions,
) -> Result<RefineResult, PnpError> {
    let (px, pw) = checked_pairs(intrinsics, pixels, points)?;
    let cam = Cam::new(intrinsics);
    let uv: Vec<Vector2<f64>> =
        px.iter().map(|p| Vector2::new((p.x - cam.cx) / cam.fx, (p.y - cam.cy) / cam.fy)).collect();
    let init = epnp_normalized(&uv, &pw)?;
    Ok(refine_all(&cam, &px, &pw, init, options))
}
