//! Scoring a pose against the correspondences: MSAC (truncated squared error) or coverage (see
//! [`super::coverage`]), each with SPRT (Matas & Chum) and a bound for the early exit. Every
//! scored pose becomes a [`Hypothesis`].

use super::coverage::Coverage;
use super::ops::Positions;
use super::MapToCamera;

/// Assumed probability that a correspondence agrees with a wrong model (SPRT δ).
const SPRT_DELTA: f64 = 0.02;
/// SPRT assumes at least this inlier ratio for a good model, so that it also prunes before a
/// good model is found (a good model with fewer inliers is rarely drawn within the budget).
const SPRT_MIN_EPS: f64 = 0.05;
/// SPRT decision threshold A: a good model is wrongly rejected with probability ≲ 1/A.
pub(crate) const SPRT_A: f64 = 300.0;

/// A scored pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Hypothesis {
    pub pose: MapToCamera,
    /// Ranking cost, lower is better (MSAC score, or the coverage cost).
    pub cost: f64,
    /// Correspondences within the threshold (with a prior check: that agree with it).
    pub inliers: usize,
    /// What SPRT and the stopping rule count: covered cells with coverage scoring (never more
    /// than the inliers, so both stay conservative), else the inliers.
    pub support: usize,
}

/// What a hypothesis must beat.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Bound {
    pub cost: f64,
    /// The support below which coverage scoring stops early.
    pub support: usize,
}

impl Bound {
    pub(crate) const NONE: Bound = Bound { cost: f64::INFINITY, support: 0 };

    pub(crate) fn of(h: &Hypothesis) -> Bound {
        Bound { cost: h.cost, support: h.support }
    }
}

/// SPRT log-likelihood increments, active once the best model's inlier ratio clearly exceeds δ.
#[derive(Clone, Copy)]
pub(crate) struct Sprt {
    pub log_in: f64,
    pub log_out: f64,
    pub log_a: f64,
}

impl Sprt {
    /// SPRT for a best model with support ratio `eps` (`None` where it would not help).
    pub(crate) fn new(eps: f64) -> Option<Self> {
        let eps = eps.max(SPRT_MIN_EPS);
        (eps > 1.5 * SPRT_DELTA && eps < 1.0).then(|| Self {
            log_in: (SPRT_DELTA / eps).ln(),
            log_out: ((1.0 - SPRT_DELTA) / (1.0 - eps)).ln(),
            log_a: SPRT_A.ln(),
        })
    }

    /// Probability that SPRT keeps a good model.
    pub(crate) fn keep_probability() -> f64 {
        1.0 - 1.0 / SPRT_A
    }
}

/// How hypotheses are ranked.
pub(crate) enum Scorer {
    Msac,
    Coverage(Coverage),
}

impl Scorer {
    pub(crate) fn coverage(&mut self) -> Option<&mut Coverage> {
        match self {
            Self::Msac => None,
            Self::Coverage(c) => Some(c),
        }
    }

    /// A refined pose's hypothesis (local optimisation): coverage bounded by `bound` without
    /// SPRT, or the full MSAC score. `None`: it cannot beat `bound`.
    pub(crate) fn rescore(&mut self, data: &Positions, pose: &MapToCamera, bound: Bound) -> Option<Hypothesis> {
        match self {
            Self::Coverage(cov) => cov.cost(data, pose, bound, None, 0),
            Self::Msac => Some(msac_full(data, pose)),
        }
    }
}

/// Running sums of one MSAC pass.
struct Acc {
    score: f64,
    inliers: usize,
    lambda: f64,
}

/// MSAC score with early exit once it reaches `best` or SPRT rejects (`None`). Evaluation
/// starts at position `start` and wraps around, so no fixed prefix decides every SPRT.
#[inline(always)]
pub(crate) fn msac_bounded(
    data: &Positions,
    pose: &MapToCamera,
    best: f64,
    sprt: Option<Sprt>,
    start: usize,
) -> Option<Hypothesis> {
    let mut acc = Acc { score: 0.0, inliers: 0, lambda: 0.0 };
    let n = data.len();
    if !msac_range(data, pose, start..n, best, &sprt, &mut acc)
        || !msac_range(data, pose, 0..start, best, &sprt, &mut acc)
    {
        return None;
    }
    Some(Hypothesis { pose: *pose, cost: acc.score, inliers: acc.inliers, support: acc.inliers })
}

/// Accumulates over one contiguous range of positions; `false` once rejected.
#[inline(always)]
fn msac_range(
    data: &Positions,
    pose: &MapToCamera,
    range: std::ops::Range<usize>,
    best: f64,
    sprt: &Option<Sprt>,
    acc: &mut Acc,
) -> bool {
    let th2 = data.th2;
    let (pw, px) = (&data.pw[range.clone()], &data.px[range]);
    for (p, q) in pw.iter().zip(px) {
        let e2 = super::ops::reproj_err2(&data.cam, pose, p, q);
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
pub(crate) fn msac_full(data: &Positions, pose: &MapToCamera) -> Hypothesis {
    let mut score = 0.0;
    let mut inliers = 0;
    for pos in 0..data.len() {
        let e2 = data.err2(pose, pos);
        if e2 < data.th2 {
            score += e2;
            inliers += 1;
        } else {
            score += data.th2;
        }
    }
    Hypothesis { pose: *pose, cost: score, inliers, support: inliers }
}
