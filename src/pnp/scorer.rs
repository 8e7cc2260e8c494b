//! Scoring a pose against the correspondences: MSAC (truncated squared error) or coverage (see
//! [`super::coverage`]), each with SPRT (Matas & Chum) and a bound for the early exit. Every
//! scored pose becomes a [`Hypothesis`].

use super::coverage::Coverage;
use super::hypothesis::{Bound, Hypothesis, Sprt};
use super::ops::Positions;
use super::MapToCamera;

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
