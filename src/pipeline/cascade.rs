//! The fast path of the cascade: a budgeted plain LO-RANSAC on the raw correspondences, whose
//! pose is taken when its support is unambiguous, so that easy frames never pay for the prior's
//! alignment, the network and verification.

use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use super::arbiter::CellGrid;
use super::significance::Significance;
use super::track::OnTrack;
use crate::frame::Frame;
use crate::pnp::{Guidance, PnpParams, PnpSolution, PoseGate, Problem, RansacSearch};

/// When the budgeted LO-RANSAC settles a frame on its own.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CascadeParams {
    pub enabled: bool,
    /// Hypotheses drawn at most (adaptive stopping ends earlier on easy frames). 400 draws reach
    /// 99.99 % confidence down to an inlier ratio of ~0.29, the lowest one `min_inlier_ratio`
    /// accepts; a frame the track settles on weaker support has drawn them all.
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
    /// … and cover at least this share of the image cells the map covers under the pose (those
    /// its matched map points project into), so that it is spread over what the map shows of the
    /// view, whatever share of the image that is; cells are a `grid_columns`-wide grid over the
    /// image (their size follows the resolution).
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
    /// A pose is published when its support among every match is significant (number of false
    /// alarms at most this) or the dense prior confirms it (`verify.min_trust`); else the frame
    /// reports it unsure and publishes none: a likely-wrong pose is worse than none. The NFA
    /// bounds the poses that wrong matches alone are expected to support so well on a frame,
    /// so this level is the share of frames without a true pose that may still publish one on
    /// geometry alone: 0.01, one in a hundred, under the 5 % of wrong poses a user can live
    /// with (a-contrario's own level of 1, one a frame, let 9.4 % of the poses published on
    /// the shared extreme-harsh bag be wrong; here 2.2 %). 0: publish every pose.
    pub publish_nfa: f64,
    /// The prior confirms a pose only while its support among every match is at least this
    /// meaningful (NFA at most this): support that wrong matches alone give many poses a frame
    /// (log₁₀ NFA of +3 and more) is no support, and no prior makes it one — a map seen over a
    /// plane or a small part of the view renders depths that an affine prior matches at wrong
    /// poses too. The prior is a second, independent test: if it confirms a wrong pose at most
    /// one time in a hundred, the two together false-alarm at most once a frame (a-contrario's
    /// own level) at NFA 100. On 62 bags (the shared, synthetic and partial-map ones, tracked
    /// and frames alone) every right pose the prior confirmed had log₁₀ NFA ≤ 1.5, and the
    /// published poses above 2 (13) were all wrong. 0: the prior confirms any support.
    pub prior_nfa: f64,
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
            publish_nfa: 0.01,
            prior_nfa: 100.0,
        }
    }
}

/// What the fast path measured on a frame it did not settle (for diagnostics), and the pose it
/// had found (a candidate for the last choice on every match).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FastPathCheck {
    pub inlier_ratio: f64,
    /// Image cells holding an inlier, of those the map covers under the pose (`Spread`).
    pub cell_share: f64,
    /// How sure its best hypothesis is among every match ([`super::significance`]).
    pub log10_nfa: f64,
    /// Camera-to-map pose of its best hypothesis, when it had one.
    pub pose: Option<nalgebra::Isometry3<f64>>,
}

impl FastPathCheck {
    /// What a fast path that found no pose (or could not search the frame) measured.
    const NO_POSE: Self = Self { inlier_ratio: 0.0, cell_share: 0.0, log10_nfa: f64::INFINITY, pose: None };
}

impl CascadeParams {
    /// The plain search of `frame` (its first robust pass, not yet started): LO-RANSAC over
    /// every correspondence, PROSAC by the matcher's scores, inlier count, no coverage or
    /// verification; `pnp` as for the frame's camera and with the seed. It searches every pose,
    /// a pose gate or not: its poses outside the gate are evidence against it
    /// ([`super::gate`]). The fast path runs its first stages; confirming or rescuing a guided
    /// pose goes on with it ([`CascadeParams::search_on`]). `None` when the frame cannot be
    /// searched at all (too few usable matches, degenerate map points). `refined_after`: the
    /// caller refines a settled pose on every match itself, so the fast path takes the search's
    /// best as drawn (PnP's own final refinement would be done twice).
    pub fn plain_search(&self, frame: &Frame, pnp: &PnpParams, refined_after: bool) -> Option<PlainSearch> {
        let matches = Matches::of(frame);
        // One PROSAC schedule over the matcher's order spans every stage: the fast path draws
        // from the best ranked matches, confirming and the last resort go on growing the pool.
        let budget = self.max_iterations.max(self.last_resort_iterations).max(1);
        let params = PnpParams { max_iterations: budget, coverage_cell_px: 0.0, ..pnp.clone() };
        let guidance = Guidance { scores: Some(&matches.scores), ..Guidance::default() };
        let problem = Problem { intrinsics: &frame.intrinsics, pixels: &matches.pixels, points: &matches.points };
        let search = RansacSearch::new(&problem, &guidance, &params).ok()?;
        Some(PlainSearch { search, min_iterations: pnp.min_iterations, refined_after })
    }

    /// The fast path: the first stages of `plain` (see [`CascadeParams::plain_search`]), whose
    /// solution is taken when it settles the frame (and lies inside `gate`, when there is one),
    /// else what it measured. With a prediction that is evidence (`track`), a pose the search
    /// is confident of that is sure among every match and agrees with the prediction settles
    /// the frame too, whatever share of the matches and the view it explains — judged once the
    /// search has drawn its whole budget.
    pub fn settle(
        &self,
        frame: &Frame,
        plain: Option<&mut PlainSearch>,
        pnp: &PnpParams,
        gate: Option<&PoseGate>,
        track: Option<&OnTrack>,
    ) -> Result<FastPathSettled, FastPathCheck> {
        let plain = plain.ok_or(FastPathCheck::NO_POSE)?;
        let budget = self.max_iterations.max(1);
        // A short probe first: a frame whose best support after it is under half the bar is
        // hard (a true ratio at the bar is all but certain to show more by then) and goes on
        // at once; only frames near the bar get the whole budget.
        let probe = self.probe_iterations.clamp(1, budget);
        let check = match self.stage(frame, plain, pnp, probe, gate, track)? {
            Ok(solution) => return Ok(solution),
            Err(check) => check,
        };
        // A sure pose a prediction is there to confirm goes on too, until the search is
        // confident of it.
        let may_confirm = track.is_some() && self.sure(check.log10_nfa);
        if probe == budget || (check.inlier_ratio < 0.5 * self.min_inlier_ratio && !may_confirm) {
            return Err(check);
        }
        self.stage(frame, plain, pnp, budget, gate, track)?
    }

    /// Whether a pose of this log₁₀ NFA among every match has support enough for the prior to
    /// confirm it ([`CascadeParams::prior_nfa`]).
    pub fn prior_may_confirm(&self, log10_nfa: f64) -> bool {
        if self.prior_nfa > 0.0 {
            log10_nfa <= self.prior_nfa.log10()
        } else {
            true
        }
    }

    /// Whether a pose of this log₁₀ NFA among every match is sure enough to overrule the
    /// network ([`CascadeParams::confirm_nfa`]).
    fn sure(&self, log10_nfa: f64) -> bool {
        self.confirm_nfa > 0.0 && log10_nfa <= self.confirm_nfa.log10()
    }

    /// `plain` on from where it stopped to the last resort's budget
    /// ([`CascadeParams::last_resort_iterations`]): its solution, `None` when it finds no
    /// consensus. For a frame whose guided pose is not sure, or that the guided search left
    /// without one.
    pub fn search_on(&self, plain: &mut PlainSearch) -> Option<PnpSolution> {
        plain.search.run_until(self.last_resort_iterations, plain.min_iterations);
        plain.search.solution().ok()
    }

    /// One stage of the fast path: the plain search on to `iterations` in all (to the whole
    /// budget before the track settles the frame); `Ok(Ok(pose))` when its solution settles the
    /// frame, `Ok(Err(check))` with what it measured when not (a pose outside `gate` never
    /// settles it).
    fn stage(
        &self,
        frame: &Frame,
        plain: &mut PlainSearch,
        pnp: &PnpParams,
        iterations: usize,
        gate: Option<&PoseGate>,
        track: Option<&OnTrack>,
    ) -> Result<Result<FastPathSettled, FastPathCheck>, FastPathCheck> {
        plain.search.run_until(iterations, self.min_iterations.min(iterations));
        let verdict = self.judge(frame, plain, pnp, gate, track)?;
        let budget = self.max_iterations.max(1);
        if matches!(verdict, Ok(FastPathSettled { on_track: true, .. })) && plain.search.iterations() < budget {
            // PROSAC's rule is met on the matcher's best-ranked matches; below the support bar a
            // larger consensus can still lie among the rest (a pose 5° off explaining 56
            // matches where the true one explains 63), so the search draws its whole budget
            // before the track settles the frame, and the frame is judged on what it found.
            plain.search.run_until(budget, budget);
            return self.judge(frame, plain, pnp, gate, track);
        }
        Ok(verdict)
    }

    /// Whether the plain search's best pose so far settles the frame: on its support alone, or
    /// on the track's prediction (see [`CascadeParams::settle`]); else what it measured.
    fn judge(
        &self,
        frame: &Frame,
        plain: &mut PlainSearch,
        pnp: &PnpParams,
        gate: Option<&PoseGate>,
        track: Option<&OnTrack>,
    ) -> Result<Result<FastPathSettled, FastPathCheck>, FastPathCheck> {
        let solution = plain.solution()?;
        let grid = CellGrid::new(&frame.intrinsics, frame.intrinsics.width as f64 / self.grid_columns.max(1) as f64);
        let spread = Spread::of(&grid, frame, &solution);
        let inlier_ratio = solution.num_inliers as f64 / frame.correspondences.len().max(1) as f64;
        let cell_share = spread.share();
        let inside = gate.is_none_or(|g| g.check(&solution.pose).is_ok());
        if inlier_ratio >= self.min_inlier_ratio && cell_share >= self.min_cell_share && inside {
            return Ok(Ok(FastPathSettled { solution, on_track: false }));
        }
        // Only an unsettled frame reports how sure its best pose is (a settled one is measured
        // once, as every published pose is).
        let (k, th, cell) = (&frame.intrinsics, pnp.threshold_px, pnp.coverage_cell_px);
        let log10_nfa = Significance::of(k, &frame.correspondences, &solution.pose, th, cell).log10_nfa;
        if inside
            && self.sure(log10_nfa)
            && plain.search.confident()
            && track.is_some_and(|t| t.agrees(k, &frame.correspondences, &solution.pose, th))
        {
            return Ok(Ok(FastPathSettled { solution, on_track: true }));
        }
        Ok(Err(FastPathCheck { inlier_ratio, cell_share, log10_nfa, pose: Some(solution.pose) }))
    }
}

/// A frame the fast path settled: its pose, and whether the track's prediction confirmed it
/// (else its support alone settled it).
#[derive(Clone, Debug)]
pub struct FastPathSettled {
    pub solution: PnpSolution,
    pub on_track: bool,
}

/// A frame's plain search (its first robust pass), run in stages: the fast path's probe and
/// budget, then, for a frame whose guided pose is not sure, on to the last resort's budget.
pub struct PlainSearch {
    search: RansacSearch,
    /// At least this many hypotheses before adaptive stopping, past the fast path (PnP's floor).
    min_iterations: usize,
    /// Whether the caller refines the fast path's pose on every match (see
    /// [`CascadeParams::plain_search`]).
    refined_after: bool,
}

impl PlainSearch {
    /// Its best pose so far: as drawn where the caller refines it, else refined.
    fn solution(&mut self) -> Result<PnpSolution, FastPathCheck> {
        let solution = match self.refined_after {
            true => self.search.best_as_drawn(),
            false => self.search.solution(),
        };
        solution.map_err(|_| FastPathCheck::NO_POSE)
    }
}

/// How a pose's inliers spread over the part of the view the map covers under it: the image
/// cells holding an inlier, of the cells the correspondences' map points project into (in front
/// of the camera, inside the image) or an inlier holds. Where the map covers a part of the view
/// only, a matcher's wrong matches on the rest still pair its pixels with map points — points of
/// the mapped part, which the right pose projects there — so the share stays that of the mapped
/// part, whatever share of the image it is; a wrong pose explaining a displaced patch of matches
/// projects the other map points all over the view, its patch a few cells of them.
struct Spread {
    supported: usize,
    covered: usize,
}

impl Spread {
    fn of(grid: &CellGrid, frame: &Frame, solution: &PnpSolution) -> Self {
        let k = &frame.intrinsics;
        let to_camera = solution.pose.inverse();
        let (width, height) = (k.width as f64, k.height as f64);
        let inliers: Vec<&Point2<f64>> =
            frame.correspondences.iter().zip(&solution.inliers).filter(|(_, &i)| i).map(|(c, _)| &c.pixel).collect();
        let projected: Vec<Point2<f64>> = frame
            .correspondences
            .iter()
            .filter_map(|c| k.project(&to_camera.transform_point(&c.point)))
            .filter(|px| (0.0..width).contains(&px.x) && (0.0..height).contains(&px.y))
            .collect();
        let supported = grid.occupied(inliers.iter().copied());
        let covered = grid.occupied(projected.iter().chain(inliers.iter().copied()));
        Self { supported, covered }
    }

    fn share(&self) -> f64 {
        self.supported as f64 / self.covered.max(1) as f64
    }
}

/// A frame's correspondences split as PnP takes them, with the matcher's scores PROSAC ranks
/// them by.
struct Matches {
    pixels: Vec<nalgebra::Point2<f64>>,
    points: Vec<nalgebra::Point3<f64>>,
    scores: Vec<f32>,
}

impl Matches {
    fn of(frame: &Frame) -> Self {
        Self {
            pixels: frame.correspondences.iter().map(|c| c.pixel).collect(),
            points: frame.correspondences.iter().map(|c| c.point).collect(),
            scores: frame.correspondences.iter().map(|c| c.score).collect(),
        }
    }
}
