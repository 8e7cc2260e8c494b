//! What a scored pose is ([`Hypothesis`]), what it must beat ([`Bound`]) and the sequential
//! probability ratio test that drops a hopeless one early ([`Sprt`], Matas & Chum): shared by
//! both scorers ([`super::scorer`] and [`super::coverage`]), the pool and the stopping rule.

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
