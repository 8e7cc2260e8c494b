//! When robust estimation stops: RANSAC's adaptive rule (enough samples for an all-inlier one
//! with the wanted confidence; PROSAC's non-random prefix test), and with a verifier its
//! schedule (verify the best first, then the pool every `check_every` samples until a candidate
//! is accepted or the choice settles).

use super::evaluator::Evaluator;
use super::hypothesis::{Hypothesis, Sprt};
use super::pool::Pool;
use super::sampler::{Sampler, M};
use super::PnpParams;

/// Non-randomness test of PROSAC's stopping length: tail at `z` σ of a binomial with this rate.
const NONRANDOM_BETA: f64 = 0.05;
const NONRANDOM_Z: f64 = 3.0;

/// The verifier's early check (the best hypothesis alone, where plain RANSAC stops) waits until
/// uniform sampling would have found a larger consensus than the best's, at most this share of
/// the verifier's `min_iterations`. PROSAC stops on its best-ranked prefix; when that prefix is
/// mostly one wrong cluster (a pose degrees off that explains part of the true matches and a
/// few wrong ones) its hypothesis explains a minority of the kept set, and a prior agrees with a
/// slightly wrong pose often enough to accept it. Drawing on grows the prefix to the true
/// matches; a frame still unsure after half the verifier's minimum is left to the pool's
/// verification (a floor of the whole minimum delayed extreme frames the early check settles).
const EARLY_FLOOR_SHARE: f64 = 0.5;

/// The stopping state of one solve, and the SPRT the scorer uses meanwhile.
pub(crate) struct Termination {
    /// PnP's own sampling limits.
    min_iterations: usize,
    max_iterations: usize,
    /// The loop's limits: PnP's, raised by the verifier's.
    pub loop_min: usize,
    pub loop_max: usize,
    confidence: f64,
    min_inliers: usize,
    /// SPRT for the best model so far.
    pub sprt: Option<Sprt>,
    /// Samples plain RANSAC needs.
    needed: f64,
    /// Samples drawn at least before the verifier's early check (see [`Termination::should_stop`]).
    early_floor: f64,
    /// Scratch: inlier flag per position.
    flags: Vec<bool>,
    schedule: Schedule,
}

/// Where the verification schedule stands.
#[derive(Default)]
struct Schedule {
    accepted: bool,
    settled: Settling,
    early_checked: bool,
    /// The best hypothesis alone was accepted when plain RANSAC stopped.
    early_accepted: bool,
}

impl Termination {
    pub(crate) fn new(params: &PnpParams, pool: Option<&Pool>, n: usize) -> Self {
        // A verifier can only choose a hypothesis that was drawn: sample at least its minimum.
        let (loop_min, loop_max) = match pool {
            Some(p) => (
                params.min_iterations.max(p.verification.min_iterations),
                params.max_iterations.max(p.verification.max_iterations),
            ),
            None => (params.min_iterations, params.max_iterations),
        };
        Self {
            min_iterations: params.min_iterations,
            max_iterations: params.max_iterations,
            loop_min,
            loop_max,
            confidence: params.confidence,
            min_inliers: params.min_inliers,
            sprt: Sprt::new(0.0),
            needed: f64::INFINITY,
            early_floor: f64::INFINITY,
            flags: vec![false; n],
            schedule: Schedule::default(),
        }
    }

    /// Whether the pool was settled by its best hypothesis alone (no final verification needed).
    /// The limits of a search's next stage (see [`super::RansacSearch::run_until`]): at least
    /// `min_iterations` draws in all, at most `max_iterations`.
    pub(crate) fn extend(&mut self, min_iterations: usize, max_iterations: usize) {
        self.min_iterations = min_iterations;
        self.max_iterations = max_iterations;
        self.loop_min = self.loop_min.max(min_iterations);
        self.loop_max = max_iterations;
    }

    /// Whether plain RANSAC's adaptive rule (PROSAC's, with scores) is met after `iterations`
    /// draws: enough samples that a consensus larger than the best one's would have been drawn
    /// with the search's confidence.
    pub(crate) fn confident(&self, iterations: usize) -> bool {
        iterations as f64 >= self.needed
    }

    pub(crate) fn early_accepted(&self) -> bool {
        self.schedule.early_accepted
    }

    /// Whether to stop before drawing sample `iterations + 1`; verifies the pool when due.
    pub(crate) fn should_stop(
        &mut self,
        iterations: usize,
        pool: Option<&mut Pool>,
        evaluator: &mut Evaluator,
    ) -> bool {
        // Where plain RANSAC stops.
        let plain_done = iterations >= self.min_iterations && (iterations as f64) >= self.needed;
        let Some(p) = pool else { return plain_done };
        let accept = p.verification.accept;
        let schedule = &mut self.schedule;
        // There the best hypothesis alone is verified first: an easy frame stops there, and so
        // does one whose prior does not confirm it but whose geometry is unambiguous. Not before
        // the early floor, though (see `EARLY_FLOOR_SHARE`).
        let floor_done = (iterations as f64) >= self.early_floor;
        if plain_done && floor_done && !schedule.early_checked {
            schedule.early_checked = true;
            if p.verify_best(evaluator) >= accept {
                schedule.early_accepted = true;
                return true;
            }
            if p.settled_by_geometry(evaluator.data.len()) {
                schedule.early_accepted = true;
                return true;
            }
        }
        // Then the pool every as many samples, going on while no candidate agrees well enough.
        let check_every = p.verification.check_every.max(1);
        if !schedule.accepted && iterations >= self.loop_min && iterations % check_every == 0 {
            schedule.accepted = p.verify_all(evaluator) >= accept
                || schedule.settled.unchanged(p.chosen_members(), p.verification.settle_checks);
        }
        schedule.accepted && (plain_done || iterations >= self.max_iterations)
    }

    /// A new best hypothesis: SPRT and the samples needed follow its support.
    pub(crate) fn on_new_best(&mut self, best: &Hypothesis, sampler: &Sampler, evaluator: &Evaluator) {
        let data = &evaluator.data;
        let eps = best.support as f64 / data.len() as f64;
        self.sprt = Sprt::new(eps);
        let keep = Sprt::keep_probability();
        let uniform = samples_needed(best.inliers as f64 / data.len() as f64, self.confidence, keep);
        self.early_floor = uniform.min(self.loop_min as f64 * EARLY_FLOOR_SHARE);
        self.needed = match sampler.pos_of_rank() {
            None => samples_needed(eps, self.confidence, keep),
            Some(map) => {
                for (pos, f) in self.flags.iter_mut().enumerate() {
                    *f = data.err2(&best.pose, pos) < data.th2;
                }
                prosac_needed(map, &self.flags, self.confidence, self.min_inliers, keep)
            }
        };
    }
}

/// Counts the verifications in a row that chose the same answer (a candidate sharing most of its
/// inliers with the one chosen before, so a better hypothesis of the same cluster, which only
/// sharpens the pose, does not count as a change): a frame whose choice stays put while more
/// hypotheses are drawn is settled, whatever its prior agreement.
#[derive(Default)]
struct Settling {
    last: Option<Vec<u64>>,
    same: usize,
}

impl Settling {
    /// Records this check's choice; whether it was the same in the last `checks` checks (0: never).
    fn unchanged(&mut self, choice: Option<&[u64]>, checks: usize) -> bool {
        let same = match (choice, self.last.as_deref()) {
            (Some(c), Some(l)) => super::pool::same_inliers(c, l),
            _ => false,
        };
        if same {
            self.same += 1;
        } else {
            self.same = 1;
            self.last = choice.map(<[u64]>::to_vec);
        }
        checks > 0 && self.same >= checks
    }
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

/// PROSAC stopping length: the fewest samples over prefix lengths `n*` whose best-model inliers
/// `I(n*)` pass the non-randomness test, using the inlier ratio `I(n*)/n*` of that prefix.
fn prosac_needed(
    pos_of_rank: &[usize],
    inlier_at_pos: &[bool],
    confidence: f64,
    min_inliers: usize,
    sprt_keep: f64,
) -> f64 {
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
        if (count as f64) < i_min || count < min_inliers.max(4) {
            continue;
        }
        needed = needed.min(samples_needed(count as f64 / len as f64, confidence, sprt_keep));
    }
    needed
}

#[cfg(test)]
mod tests {
    use super::Settling;

    fn members(inliers: &[usize]) -> Vec<u64> {
        let mut bits = vec![0u64; 2];
        for &i in inliers {
            bits[i / 64] |= 1 << (i % 64);
        }
        bits
    }

    /// A better hypothesis of the same cluster (most inliers shared) is the same answer; another
    /// cluster starts the count again.
    #[test]
    fn settling_counts_the_same_cluster_as_unchanged() {
        let mut settling = Settling::default();
        let first = members(&(0..40).collect::<Vec<_>>());
        let sharper = members(&(2..44).collect::<Vec<_>>());
        let other = members(&(60..100).collect::<Vec<_>>());
        assert!(!settling.unchanged(Some(&first), 2));
        assert!(settling.unchanged(Some(&sharper), 2));
        assert!(!settling.unchanged(Some(&other), 3));
        assert!(!settling.unchanged(Some(&other), 3));
        assert!(settling.unchanged(Some(&other), 3));
        assert!(!settling.unchanged(Some(&other), 0), "0 checks: never");
    }
}
