//! The candidate pool of verified robust estimation: the best distinct hypotheses by coverage
//! cost, and the verifier that chooses among them (see [`Verification`]). Two hypotheses are one
//! when most of the smaller inlier set is shared: the cluster keeps its best.

use super::evaluator::Evaluator;
use super::hypothesis::{Bound, Hypothesis};
use super::{Agreement, MapToCamera, Verification};

/// A hypothesis kept for verification.
struct Candidate {
    /// Its `inliers` are the geometric inliers (before any prior check), which the cluster test
    /// compares; `support` is its cells.
    hypothesis: Hypothesis,
    /// Inlier positions as a bit set, for the cluster test.
    members: Vec<u64>,
    /// The verifier's agreement once verified (after local optimisation).
    agreement: Option<Agreement>,
}

pub(crate) struct Pool<'a> {
    pub verification: Verification<'a>,
    /// Each candidate is locally optimised before it is verified.
    local_optimize: bool,
    items: Vec<Candidate>,
}

impl<'a> Pool<'a> {
    pub(crate) fn new(verification: Verification<'a>, local_optimize: bool) -> Self {
        Self { verification, local_optimize, items: Vec::with_capacity(verification.candidates + 1) }
    }

    fn is_full(&self) -> bool {
        self.items.len() >= self.verification.candidates
    }

    /// Index of the candidate with the highest (`worst`) or lowest cost.
    fn extreme(&self, worst: bool) -> Option<usize> {
        let by_cost = |&a: &usize, &b: &usize| self.items[a].hypothesis.cost.total_cmp(&self.items[b].hypothesis.cost);
        let indices = 0..self.items.len();
        if worst {
            indices.max_by(by_cost)
        } else {
            indices.min_by(by_cost)
        }
    }

    /// What a hypothesis must beat to enter: the worst kept once full.
    pub(crate) fn bound(&self) -> Bound {
        match self.extreme(true) {
            Some(w) if self.is_full() => Bound::of(&self.items[w].hypothesis),
            _ => Bound::NONE,
        }
    }

    /// Offers a hypothesis with its (geometric) inlier positions among `n`.
    pub(crate) fn offer(&mut self, hypothesis: &Hypothesis, inliers: &[usize], n: usize) {
        let mut members = vec![0u64; n.div_ceil(64)];
        for &i in inliers {
            members[i / 64] |= 1 << (i % 64);
        }
        let hypothesis = Hypothesis { inliers: inliers.len(), ..*hypothesis };
        let candidate = Candidate { hypothesis, members, agreement: None };
        let cost = hypothesis.cost;
        if let Some(same) = self.items.iter_mut().find(|c| same_cluster(c, &candidate)) {
            if cost < same.hypothesis.cost {
                *same = candidate;
            }
            return;
        }
        if self.is_full() {
            match self.extreme(true) {
                Some(w) if cost < self.items[w].hypothesis.cost => {
                    self.items.swap_remove(w);
                }
                _ => return,
            }
        }
        self.items.push(candidate);
    }

    /// Candidate `i` made ready for verification: locally optimised once (optional).
    fn optimize(&mut self, i: usize, evaluator: &mut Evaluator) {
        let c = &mut self.items[i];
        if c.agreement.is_none() && self.local_optimize {
            let lo = evaluator.local_optimization(c.hypothesis);
            // The cluster test keeps comparing the inliers it was offered with.
            c.hypothesis = Hypothesis { inliers: c.hypothesis.inliers, ..lo };
        }
    }

    /// The agreement of candidate `i`, verified once: after local optimisation (optional).
    fn verify(&mut self, i: usize, evaluator: &mut Evaluator) -> Agreement {
        if let Some(agreement) = self.items[i].agreement {
            return agreement;
        }
        self.optimize(i, evaluator);
        let c = &mut self.items[i];
        let agreement = self.verification.verifier.verify(&c.hypothesis.pose.to_camera_to_map());
        c.agreement = Some(agreement);
        agreement
    }

    /// Verifies every candidate (those not verified yet: optimised in turn, then rendered in
    /// parallel); the best in-view agreement.
    pub(crate) fn verify_all(&mut self, evaluator: &mut Evaluator) -> f64 {
        use rayon::prelude::*;
        let pending: Vec<usize> = (0..self.items.len()).filter(|&i| self.items[i].agreement.is_none()).collect();
        for &i in &pending {
            self.optimize(i, evaluator);
        }
        let verifier = self.verification.verifier;
        let poses: Vec<_> = pending.iter().map(|&i| self.items[i].hypothesis.pose.to_camera_to_map()).collect();
        let agreements: Vec<Agreement> = poses.par_iter().map(|pose| verifier.verify(pose)).collect();
        for (&i, agreement) in pending.iter().zip(agreements) {
            self.items[i].agreement = Some(agreement);
        }
        self.trust()
    }

    /// Verifies the lowest-cost candidate alone; its in-view agreement.
    pub(crate) fn verify_best(&mut self, evaluator: &mut Evaluator) -> f64 {
        let min_view = self.verification.min_view;
        self.extreme(false).map_or(0.0, |i| self.verify(i, evaluator).in_view_share(min_view))
    }

    /// Whether the lowest-cost candidate, verified, is not trusted by the verifier (the prior
    /// is unreliable for it) yet its geometry explains `settle_support` of the `n`
    /// correspondences: then geometry alone decides, as without a verifier.
    pub(crate) fn settled_by_geometry(&self, n: usize) -> bool {
        let v = &self.verification;
        let Some(best) = self.extreme(false).map(|i| &self.items[i]) else { return false };
        let Some(agreement) = best.agreement else { return false };
        let share = best.hypothesis.inliers as f64 / n.max(1) as f64;
        v.settle_support > 0.0 && agreement.in_view_share(v.min_view) < v.min_trust && share >= v.settle_support
    }

    /// The best in-view agreement of any verified candidate with enough support (see
    /// [`Pool::supported`]): how far the frame's evidence can be trusted.
    fn trust(&self) -> f64 {
        let min_view = self.verification.min_view;
        self.supported().filter_map(|(_, c)| c.agreement).map(|a| a.in_view_share(min_view)).fold(0.0, f64::max)
    }

    /// The candidates (with their index) covering at least `min_support_share` of the most
    /// cells of any.
    fn supported(&self) -> impl Iterator<Item = (usize, &Candidate)> {
        let floor = self.verification.min_support_share * self.most_cells();
        self.items.iter().enumerate().filter(move |(_, c)| c.hypothesis.support as f64 >= floor)
    }

    /// The most cells any candidate covers (at least one).
    fn most_cells(&self) -> f64 {
        self.items.iter().map(|c| c.hypothesis.support).max().unwrap_or(0).max(1) as f64
    }

    /// A verified candidate's choice score: its agreement + `coverage_weight`·cells / most cells.
    fn choice_score(&self, c: &Candidate, most_cells: f64) -> Option<f64> {
        Some(c.agreement?.share() + self.verification.coverage_weight * c.hypothesis.support as f64 / most_cells)
    }

    /// The supported verified candidate with the most agreement + `coverage_weight`·cells / most
    /// cells; when none reaches `min_trust`, the lowest-cost one (geometry alone).
    pub(crate) fn choose(&self) -> Option<MapToCamera> {
        self.chosen().map(|i| self.items[i].hypothesis.pose)
    }

    /// The inlier set (bit set) of the candidate [`Pool::choose`] returns.
    pub(crate) fn chosen_members(&self) -> Option<&[u64]> {
        self.chosen().map(|i| self.items[i].members.as_slice())
    }

    /// The supported candidates other than the chosen one, best choice first (verified ones by
    /// their choice score, then the others by cost).
    pub(crate) fn alternatives(&self) -> Vec<MapToCamera> {
        let (chosen, most_cells) = (self.chosen(), self.most_cells());
        let mut ranked: Vec<(f64, f64, MapToCamera)> = self
            .supported()
            .filter(|(i, _)| Some(*i) != chosen)
            .map(|(_, c)| {
                let score = self.choice_score(c, most_cells).unwrap_or(f64::NEG_INFINITY);
                (score, c.hypothesis.cost, c.hypothesis.pose)
            })
            .collect();
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.total_cmp(&b.1)));
        ranked.into_iter().map(|(_, _, pose)| pose).collect()
    }

    /// The index of the candidate [`Pool::choose`] returns.
    fn chosen(&self) -> Option<usize> {
        if self.trust() < self.verification.min_trust {
            return self.extreme(false);
        }
        let most_cells = self.most_cells();
        self.supported()
            .filter_map(|(i, c)| Some((self.choice_score(c, most_cells)?, i)))
            .max_by(|a, b| {
                let cost = |i: usize| self.items[i].hypothesis.cost;
                a.0.total_cmp(&b.0).then(cost(b.1).total_cmp(&cost(a.1)))
            })
            .map(|(_, i)| i)
    }
}

/// Whether two candidates share more than half of the smaller inlier set (their counts known).
fn same_cluster(a: &Candidate, b: &Candidate) -> bool {
    shares_most(&a.members, &b.members, a.hypothesis.inliers.min(b.hypothesis.inliers))
}

/// Whether two inlier sets (bit sets) share more than half of the smaller one: one answer.
pub(crate) fn same_inliers(a: &[u64], b: &[u64]) -> bool {
    let count = |s: &[u64]| s.iter().map(|x| x.count_ones() as usize).sum::<usize>();
    shares_most(a, b, count(a).min(count(b)))
}

/// Whether bit sets `a` and `b` share more than half of `smaller` members.
fn shares_most(a: &[u64], b: &[u64], smaller: usize) -> bool {
    let shared: u32 = a.iter().zip(b).map(|(x, y)| (x & y).count_ones()).sum();
    2 * shared as usize > smaller
}
