//! The fast path of the cascade: a budgeted plain LO-RANSAC on the raw correspondences, whose
//! pose is taken when its support is unambiguous, so that easy frames never pay for the prior's
//! alignment, the network and verification.

use serde::{Deserialize, Serialize};

use super::arbiter::CellGrid;
use super::significance::Significance;
use crate::frame::Frame;
use crate::pnp::{solve_pnp_ransac, Guidance, PnpParams, PnpSolution, PoseGate, Problem};

/// When the budgeted LO-RANSAC settles a frame on its own.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CascadeParams {
    pub enabled: bool,
    /// Hypotheses drawn at most (adaptive stopping ends earlier on easy frames). 400 draws reach
    /// 99.99 % confidence down to an inlier ratio of ~0.29, the lowest one `min_inlier_ratio`
    /// accepts.
    pub max_iterations: usize,
    /// Hypotheses drawn at least before adaptive stopping may end an attempt (PoseLib's and the
    /// guided PnP's floor is 100): an easy frame whose best pose already explains most matches
    /// is certain after ~10 draws at 99.99 %, and whatever it draws beyond is the fast path's
    /// whole cost; the settling bar (`min_inlier_ratio`, `min_cell_share`) is unchanged.
    pub min_iterations: usize,
    /// Hypotheses of the first, short attempt; a frame whose support then is under half
    /// `min_inlier_ratio` skips the rest of the budget.
    pub probe_iterations: usize,
    /// The pose's inliers must be at least this share of the correspondences: a majority-like
    /// support that no wrong pose explaining a displaced patch of matches reaches …
    pub min_inlier_ratio: f64,
    /// … and cover at least this share of the image cells that hold any correspondence, so that
    /// it is spread over the view; cells are a `grid_columns`-wide grid over the image (their
    /// size follows the resolution).
    pub min_cell_share: f64,
    pub grid_columns: usize,
    /// The cascade's last step: a frame whose rejection-guided PnP finds no consensus gets a
    /// plain LO-RANSAC over every correspondence with this many hypotheses at most (PoseLib's
    /// budget), its pose chosen on geometry alone, so the method never returns less than plain
    /// LO-RANSAC would. 0: off.
    pub last_resort_iterations: usize,
    /// How sure a pose must be: a pose found in the rejector's order whose support among every
    /// match could come from wrong matches more often than this (its number of false alarms,
    /// [`super::significance`]) is checked by the same plain LO-RANSAC over every match, whose
    /// pose replaces it when that one is this sure: the rejector's scores order the search,
    /// they never keep the geometry from a pose that every match supports. A-contrario's own
    /// level is 1; 10⁻³ asks a thousand times more of a pose before it overrules the network
    /// (the shared extreme frames' wrong plain poses reach 10^−1.6). 0: never checked.
    pub confirm_nfa: f64,
    /// A pose is published when its support among every match is meaningful (number of false
    /// alarms at most this) or the dense prior confirms it (`verify.min_trust`); else the frame
    /// reports it unsure and publishes none: a likely-wrong pose is worse than none. 1 is
    /// a-contrario's own level; 0: publish every pose.
    pub publish_nfa: f64,
}

impl Default for CascadeParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_iterations: 400,
            min_iterations: 20,
            probe_iterations: 100,
            min_inlier_ratio: 0.3,
            min_cell_share: 0.5,
            grid_columns: 16,
            last_resort_iterations: 10_000,
            confirm_nfa: 0.001,
            publish_nfa: 1.0,
        }
    }
}

/// What the fast path measured on a frame it did not settle (for diagnostics), and the pose it
/// had found (a candidate for the last choice on every match).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FastPathCheck {
    pub inlier_ratio: f64,
    pub cell_share: f64,
    /// How sure its best hypothesis is among every match ([`super::significance`]).
    pub log10_nfa: f64,
    /// Camera-to-map pose of its best hypothesis, when it had one.
    pub pose: Option<nalgebra::Isometry3<f64>>,
}

impl CascadeParams {
    /// The budgeted RANSAC's solution when it settles the frame, else what it measured; `pnp`
    /// as for the frame's camera and with the seed, poses only inside `gate` when there is one.
    pub fn settle(
        &self,
        frame: &Frame,
        pnp: &PnpParams,
        gate: Option<&PoseGate>,
    ) -> Result<PnpSolution, FastPathCheck> {
        let matches = Matches::of(frame);
        let pnp = &PnpParams { min_iterations: self.min_iterations, ..pnp.clone() };
        let budget = self.max_iterations.max(1);
        // A short probe first: a frame whose best support after it is under half the bar is
        // hard (a true ratio at the bar is all but certain to show more by then) and goes on
        // at once; only frames near the bar get the whole budget.
        let probe = self.probe_iterations.clamp(1, budget);
        let check = match self.attempt(frame, &matches, pnp, probe, gate)? {
            Ok(solution) => return Ok(solution),
            Err(check) => check,
        };
        if probe == budget || check.inlier_ratio < 0.5 * self.min_inlier_ratio {
            return Err(check);
        }
        self.attempt(frame, &matches, pnp, budget, gate)?
    }

    /// The last resort for a frame the rejection-guided path left without a pose: plain
    /// LO-RANSAC on every correspondence (sampled in the matcher's score order), `None` when it
    /// finds no consensus either or the step is off.
    pub fn last_resort(&self, frame: &Frame, pnp: &PnpParams, gate: Option<&PoseGate>) -> Option<PnpSolution> {
        if self.last_resort_iterations == 0 {
            return None;
        }
        Matches::of(frame).lo_ransac(frame, pnp, self.last_resort_iterations, gate).ok()
    }

    /// LO-RANSAC on every correspondence with at most `iterations` hypotheses: `Ok(Ok(pose))`
    /// when it settles the frame, `Ok(Err(check))` with what it measured when it does not.
    fn attempt(
        &self,
        frame: &Frame,
        matches: &Matches,
        pnp: &PnpParams,
        iterations: usize,
        gate: Option<&PoseGate>,
    ) -> Result<Result<PnpSolution, FastPathCheck>, FastPathCheck> {
        let solution = matches
            .lo_ransac(frame, pnp, iterations, gate)
            .map_err(|_| FastPathCheck { log10_nfa: f64::INFINITY, ..FastPathCheck::default() })?;
        let grid = CellGrid::new(&frame.intrinsics, frame.intrinsics.width as f64 / self.grid_columns.max(1) as f64);
        let pixels = &matches.pixels;
        let all = grid.occupied(pixels.iter());
        let supported = grid.occupied(pixels.iter().zip(&solution.inliers).filter(|(_, &i)| i).map(|(p, _)| p));
        let inlier_ratio = solution.num_inliers as f64 / pixels.len().max(1) as f64;
        let cell_share = supported as f64 / all.max(1) as f64;
        if inlier_ratio >= self.min_inlier_ratio && cell_share >= self.min_cell_share {
            return Ok(Ok(solution));
        }
        // Only an unsettled frame reports how sure its best pose is (a settled one is measured
        // once, as every published pose is).
        let (k, th, cell) = (&frame.intrinsics, pnp.threshold_px, pnp.coverage_cell_px);
        let log10_nfa = Significance::of(k, &frame.correspondences, &solution.pose, th, cell).log10_nfa;
        Ok(Err(FastPathCheck { inlier_ratio, cell_share, log10_nfa, pose: Some(solution.pose) }))
    }
}

/// A frame's correspondences split as PnP takes them, with the scores PROSAC ranks them by;
/// built once for both attempts of the fast path.
pub(super) struct Matches {
    pixels: Vec<nalgebra::Point2<f64>>,
    points: Vec<nalgebra::Point3<f64>>,
    scores: Vec<f32>,
}

impl Matches {
    /// Ranked by the matcher's scores.
    fn of(frame: &Frame) -> Self {
        Self::ranked(frame, frame.correspondences.iter().map(|c| c.score).collect())
    }

    /// Ranked by `scores`, one per correspondence (e.g. the rejector's).
    pub(super) fn ranked(frame: &Frame, scores: Vec<f32>) -> Self {
        Self {
            pixels: frame.correspondences.iter().map(|c| c.pixel).collect(),
            points: frame.correspondences.iter().map(|c| c.point).collect(),
            scores,
        }
    }

    /// Plain LO-RANSAC on these matches (PROSAC by the matcher's scores, inlier count, no
    /// coverage or verification) with at most `iterations` hypotheses, inside `gate` if any.
    fn lo_ransac(
        &self,
        frame: &Frame,
        pnp: &PnpParams,
        iterations: usize,
        gate: Option<&PoseGate>,
    ) -> Result<PnpSolution, crate::pnp::PnpError> {
        self.prosac(frame, &PnpParams { coverage_cell_px: 0.0, ..pnp.clone() }, iterations, gate)
    }

    /// PROSAC by these matches' scores with `pnp` (its scoring, no verification) and at most
    /// `iterations` hypotheses, inside `gate` if any.
    pub(super) fn prosac(
        &self,
        frame: &Frame,
        pnp: &PnpParams,
        iterations: usize,
        gate: Option<&PoseGate>,
    ) -> Result<PnpSolution, crate::pnp::PnpError> {
        let params =
            PnpParams { max_iterations: iterations, min_iterations: pnp.min_iterations.min(iterations), ..pnp.clone() };
        let guidance = Guidance { scores: Some(&self.scores), gate, ..Guidance::default() };
        let problem = Problem { intrinsics: &frame.intrinsics, pixels: &self.pixels, points: &self.points };
        solve_pnp_ransac(&problem, &guidance, &params)
    }
}
