//! The localizer: one frame in, one [`Localization`] out. Geometry → rejection → PnP →
//! covariance, with per-stage timings; every failure is a value with a reason.

use std::time::Instant;

use nalgebra::Isometry3;

use crate::consistency::ScaleShiftParams;
use crate::frame::{Correspondence, Frame};
use crate::geometry::DepthKind;
use crate::pnp::{solve_pnp_ransac, Guidance, PnpError, PnpParams, PnpSolution, PoseGate, Problem};
use crate::reject::network::{NetworkError, NetworkRejector};
use crate::reject::{FrameGeometry, Rejector, SpectralRejector};
use crate::verify::{PriorVerifier, RenderMap};
use last_choice::Flagged;
use scratch::FrameScratch;
use significance::Significance;
use track::{OnTrack, Prediction, Published, Tracker};

mod arbiter;
mod cascade;
mod gate;
mod last_choice;
mod localization;
mod params;
mod refine;
mod scratch;
mod significance;
mod track;
mod uncertainty;

pub use cascade::{CascadeParams, FastPathCheck, FastPathSettled, PlainSearch};
pub use localization::{Failure, Localization, Method, StageTimings};
pub use params::LocalizerParams;
pub use refine::{FinalRefine, RefineFrame};
pub use track::{PredictionSource, TrackState, TrackingParams};
pub use uncertainty::CovarianceParams;

/// Why a localizer cannot be set up for its method.
#[derive(Debug, Clone, thiserror::Error)]
pub enum SetupError {
    /// The learned rejector's ONNX Runtime or model.
    #[error(transparent)]
    Network(#[from] NetworkError),
}

/// How a frame's geometry is built: the prior's depth kind and alignment for the method, and
/// whether a rejector needs it at all.
struct GeometryStep<'a> {
    depth_kind: DepthKind,
    align: Option<&'a ScaleShiftParams>,
    needed: bool,
}

impl<'a> GeometryStep<'a> {
    fn of(params: &'a LocalizerParams, has_rejector: bool) -> Self {
        let align = match params.method {
            Method::AngleI2p => params.network.alignment(&params.align),
            _ => Some(&params.align),
        };
        Self { depth_kind: params.depth_kind, align, needed: has_rejector }
    }

    /// Into `scratch.geometry` (empty when no rejector needs it).
    fn build(&self, frame: &Frame, scratch: &mut FrameScratch) {
        if self.needed {
            scratch.geometry.rebuild(frame, self.depth_kind, self.align, &mut scratch.geometry_work);
        } else {
            scratch.geometry = FrameGeometry::default();
        }
    }
}

/// Localizes frames; holds the reusable per-frame buffers.
pub struct Localizer {
    params: LocalizerParams,
    rejector: Option<Box<dyn Rejector>>,
    /// The map subsample that PnP's hypotheses are rendered from for verification.
    render_map: RenderMap,
    /// Per-frame buffers, refilled every frame (the rejector keeps its own).
    scratch: FrameScratch,
    /// Poses outside this gate are not considered (e.g. an `/initialpose` prior).
    pose_gate: Option<PoseGate>,
    /// Whether the next frame builds its geometry beside the fast path (the last frame was not
    /// settled by it).
    overlap_fast_path: bool,
    /// The stream's memory: the poses published before, which predict the next frame's.
    tracker: Tracker,
}

impl Localizer {
    /// A localizer for `params.method`; an error when its rejector cannot run (e.g. ONNX Runtime
    /// or the model is missing).
    pub fn new(mut params: LocalizerParams) -> Result<Self, SetupError> {
        let rejector: Option<Box<dyn Rejector>> = match params.method {
            Method::Ransac => None,
            Method::Consistency => Some(Box::new(SpectralRejector::new(params.spectral.clone()))),
            Method::AngleI2p => {
                let network = NetworkRejector::new(params.network.clone(), params.spectral.clone())?;
                // The model's constants (its prior alignment too, which the geometry step reads).
                params.network = network.params().clone();
                Some(Box::new(network))
            }
        };
        Ok(Self {
            params,
            rejector,
            render_map: RenderMap::default(),
            scratch: FrameScratch::default(),
            pose_gate: None,
            overlap_fast_path: false,
            tracker: Tracker::default(),
        })
    }

    /// A localizer whose rejection is `rejector` (a user's own scorer, or a test's), everything
    /// else as `params` says.
    pub fn with_rejector(params: LocalizerParams, rejector: Box<dyn Rejector>) -> Self {
        Self {
            params,
            rejector: Some(rejector),
            render_map: RenderMap::default(),
            scratch: FrameScratch::default(),
            pose_gate: None,
            overlap_fast_path: false,
            tracker: Tracker::default(),
        }
    }

    /// The map frames are localized against, indexed here whole before the next frame: a
    /// building-scale map's per-voxel trees and planar cells too (which a node builds beside or
    /// in its first frames, [`crate::map_index::swap`]). See [`Localizer::set_map_index`].
    pub fn set_map(&mut self, map: &crate::frame::MapCloud) {
        let settings = self.params.verify.index_settings();
        let index = crate::map_index::MapIndex::build(map.points.clone(), &settings);
        index.prepare_searches();
        self.set_map_index(std::sync::Arc::new(index));
    }

    /// The map, already indexed (an index may be shared by several localizers, and built on
    /// another thread): rejectors that use its geometry keep it, the verifier renders from it.
    /// A new map starts the track again (poses in the old map do not predict poses in it).
    pub fn set_map_index(&mut self, index: std::sync::Arc<crate::map_index::MapIndex>) {
        self.tracker.reset();
        if let Some(r) = self.rejector.as_mut() {
            r.set_map_index(&index);
        }
        self.render_map = if self.params.verify.enabled {
            RenderMap::of_index(&index, &self.params.verify)
        } else {
            RenderMap::default()
        };
    }

    /// A prior on the pose (e.g. `/initialpose`): PnP considers only poses inside `gate`, on
    /// every path of the cascade, until it is set to `None`.
    pub fn set_pose_gate(&mut self, gate: Option<PoseGate>) {
        self.pose_gate = gate;
    }

    pub fn params(&self) -> &LocalizerParams {
        &self.params
    }

    /// One frame through at most two robust passes: the plain search over every match (the
    /// fast path's stages; a frame they settle ends there) and the search guided by the
    /// rejector on the kept matches, whose pose, when it is not sure, the plain search goes on
    /// to confirm or replace (and rescues a frame the guided search leaves without a pose).
    pub fn process(&mut self, frame: &Frame) -> Localization {
        let start = Instant::now();
        let mut out = Localization::nothing_yet(frame, self.params.method);
        let tracking = self.params.tracking.enabled;
        let prediction = if tracking { self.tracker.predict(frame.stamp, frame.odometry.as_ref()) } else { None };
        out.prediction = prediction.map(|p| p.source);
        match self.validate(frame) {
            Ok(()) => self.localize(frame, prediction.as_ref(), &mut out),
            Err(failure) => out.failure = Some(failure),
        }
        // A frame the fast path did not settle predicts the next one: it builds its geometry
        // while the fast path runs.
        self.overlap_fast_path = self.fast_path_applies() && !out.fast_path && out.failure.is_none();
        self.weigh_gate(&mut out);
        let published = self.withhold_unsure(frame, prediction.as_ref(), &mut out);
        if tracking {
            let odometry = frame.odometry.as_ref();
            out.track = Some(self.tracker.update(frame.stamp, published, prediction.as_ref(), odometry));
        }
        out.timings.total_ms = ms_since(start);
        out
    }

    /// The fast path (beside the geometry when the last frame predicts this one needs it), then,
    /// unless it settled the frame, rejection and the guided search. The track's `prediction`
    /// may confirm the fast path's pose.
    fn localize(&mut self, frame: &Frame, prediction: Option<&Prediction>, out: &mut Localization) {
        let (plain, geometry_built) = if self.overlap_fast_path {
            (self.fast_path_beside_geometry(frame, prediction, out), true)
        } else if self.fast_path_applies() {
            (self.fast_path(frame, prediction, out), false)
        } else {
            (None, false)
        };
        if out.fast_path {
            return;
        }
        if !geometry_built {
            self.build_geometry(frame, out);
        }
        self.reject_and_solve(frame, plain, out);
    }

    /// Whether frames try the cascade's fast path first.
    fn fast_path_applies(&self) -> bool {
        self.params.cascade.enabled && self.params.method != Method::Ransac
    }

    /// The cascade's first step: the first stages of the plain search on the raw
    /// correspondences, which settle the frame when its support is unambiguous (then `out`
    /// holds the pose and its inliers as the kept set). The search, to go on with.
    fn fast_path(&self, frame: &Frame, prediction: Option<&Prediction>, out: &mut Localization) -> Option<PlainSearch> {
        let gate = self.pose_gate.as_ref();
        let (track, refined) = (self.on_track_closely(prediction), self.params.final_refine.enabled);
        let (settled, plain, ms) =
            fast_path_timed(&self.params.cascade, frame, &self.pnp_params(frame), gate, track.as_ref(), refined);
        out.timings.fast_path_ms = ms;
        out.robust_passes += usize::from(plain.is_some());
        self.take_fast_path(frame, settled, out);
        plain
    }

    /// The fast path on this thread and the frame's geometry on another, side by side (the
    /// fast path is serial; the geometry's serial steps leave the other core idle): for a frame
    /// after one the fast path did not settle. The outputs are those of the fast path first and
    /// the geometry after; when the fast path settles the frame after all, its geometry was
    /// built for nothing.
    fn fast_path_beside_geometry(
        &mut self,
        frame: &Frame,
        prediction: Option<&Prediction>,
        out: &mut Localization,
    ) -> Option<PlainSearch> {
        let pnp = self.pnp_params(frame);
        let (cascade, gate, track) = (&self.params.cascade, self.pose_gate.as_ref(), self.on_track_closely(prediction));
        let refined = self.params.final_refine.enabled;
        let geometry = GeometryStep::of(&self.params, self.rejector.is_some());
        let scratch = &mut self.scratch;
        let ((settled, plain, fast_path_ms), geometry_ms) = rayon::join(
            || fast_path_timed(cascade, frame, &pnp, gate, track.as_ref(), refined),
            || {
                let t = Instant::now();
                geometry.build(frame, scratch);
                ms_since(t)
            },
        );
        out.timings.fast_path_ms = fast_path_ms;
        out.robust_passes += usize::from(plain.is_some());
        if !self.take_fast_path(frame, settled, out) {
            out.timings.geometry_ms = geometry_ms;
        }
        plain
    }

    /// The fast path's outcome into `out`: its pose when it `settled` the frame (true), else
    /// what it measured (false).
    fn take_fast_path(
        &self,
        frame: &Frame,
        settled: Result<FastPathSettled, FastPathCheck>,
        out: &mut Localization,
    ) -> bool {
        let solution = match settled {
            Ok(FastPathSettled { solution, on_track }) => {
                out.fast_path_on_track = on_track;
                solution
            }
            Err(check) => {
                if check.pose.is_some_and(|pose| !gate::admits(self.pose_gate.as_ref(), &pose)) {
                    gate::note_outside(out, check.log10_nfa);
                }
                out.fast_path_check = Some(check);
                return false;
            }
        };
        out.fast_path = true;
        self.accept_plain(frame, solution, out);
        out.timings.pnp_ms = out.timings.fast_path_ms;
        true
    }

    /// Geometry: rays, prior depths and the aligned image cloud (only a rejector needs them).
    fn build_geometry(&mut self, frame: &Frame, out: &mut Localization) {
        let t = Instant::now();
        GeometryStep::of(&self.params, self.rejector.is_some()).build(frame, &mut self.scratch);
        out.timings.geometry_ms = ms_since(t);
    }

    /// Rejection on the frame's geometry (built), then PnP on the kept correspondences (sampled
    /// in score order), verified against the prior.
    fn reject_and_solve(&mut self, frame: &Frame, plain: Option<PlainSearch>, out: &mut Localization) {
        let scratch = &mut self.scratch;
        out.scale_shift = scratch.geometry.scale_shift;
        // Rejection: scores and the kept subset, best first.
        let t = Instant::now();
        let rejection = match self.rejector.as_mut().map(|r| r.reject(&scratch.geometry)) {
            None => None,
            Some(Ok(r)) => Some(r),
            Some(Err(e)) => {
                out.failure = Some(Failure::Rejection(e));
                out.timings.reject_ms = ms_since(t);
                return;
            }
        };
        out.timings.reject_ms = ms_since(t);

        let t = Instant::now();
        scratch.fill_pnp_inputs(frame, rejection.as_ref());
        self.solve(frame, rejection.as_ref(), plain, out);
        out.timings.pnp_ms = ms_since(t);
    }

    /// PnP on the inputs in the scratch, verified against the prior (the guided pass); the
    /// kept set and the pose into `out`. A guided pose that is not sure is confirmed by the
    /// plain pass going on; a frame the guided pass leaves without a pose, rescued by it.
    fn solve(
        &self,
        frame: &Frame,
        rejection: Option<&crate::reject::Rejection>,
        mut plain: Option<PlainSearch>,
        out: &mut Localization,
    ) {
        let scratch = &self.scratch;
        let verifier = self.verifier(frame);
        let guidance = Guidance {
            scores: scratch.scores(rejection),
            prior_depths: scratch.priors(),
            prior_space: scratch.geometry.prior_space,
            verification: verifier.as_ref().map(|v| self.params.verify.verification(v)),
            gate: self.pose_gate.as_ref(),
        };
        let pnp = self.pnp_params(frame);
        let problem = Problem { intrinsics: &frame.intrinsics, pixels: &scratch.pixels, points: &scratch.points };
        let last_choice = rejection.is_some() && self.params.final_refine.enabled;
        let refine_alternatives = self.params.final_refine.alternatives;
        out.robust_passes += 1;
        let solved = solve_pnp_ransac(&problem, &guidance, &pnp);
        let subset = &scratch.subset;
        let with_scores = |r: &crate::reject::Rejection| -> Vec<Correspondence> {
            subset.iter().map(|&i| with_score(frame.correspondences[i], r.scores[i])).collect()
        };
        match solved {
            Ok(mut solution) => {
                if last_choice {
                    self.refine_on_all(frame, &mut solution);
                    let fast_path_pose = out
                        .fast_path_check
                        .and_then(|c| c.pose)
                        .filter(|pose| refine_alternatives > 0 && gate::admits(self.pose_gate.as_ref(), pose));
                    let margin = self.params.final_refine.switch_margin;
                    self.arbitrate_on_all(frame, fast_path_pose.as_slice(), margin, &mut solution);
                    self.confirm_on_all(frame, &mut solution, &mut plain, out);
                    self.out_of_basin(frame, &mut solution, Flagged::Kept);
                }
                out.kept = match rejection {
                    Some(r) => with_scores(r),
                    None => subset
                        .iter()
                        .zip(&solution.inliers)
                        .filter(|(_, &inlier)| inlier)
                        .map(|(&i, _)| with_score(frame.correspondences[i], 1.0))
                        .collect(),
                };
                self.accept(frame, &solution, verifier.as_ref(), out);
            }
            Err(e) => {
                if let Some(r) = rejection {
                    out.kept = with_scores(r);
                }
                let rescued = rejection.is_some()
                    && matches!(e, PnpError::NoConsensus { .. })
                    && self.last_resort(frame, &mut plain, out);
                if !rescued {
                    out.failure = Some(Failure::Pnp(e));
                }
            }
        }
    }

    /// The cascade's last step ([`CascadeParams::last_resort_iterations`]): the plain pass on
    /// to its budget; whether it found the pose, which `out` then holds with its inliers as the
    /// kept set.
    fn last_resort(&self, frame: &Frame, plain: &mut Option<PlainSearch>, out: &mut Localization) -> bool {
        let Some(solution) = self.search_on(frame, plain, out) else { return false };
        if !gate::admits(self.pose_gate.as_ref(), &solution.pose) {
            gate::note_outside(out, self.significance(frame, &solution.pose).log10_nfa);
            return false;
        }
        out.last_resort = true;
        self.accept_plain(frame, solution, out);
        true
    }

    /// The plain pass on to the last resort's budget, from where it stopped: its solution,
    /// `None` when it finds no consensus.
    fn search_on(&self, frame: &Frame, plain: &mut Option<PlainSearch>, out: &mut Localization) -> Option<PnpSolution> {
        let cascade = &self.params.cascade;
        if cascade.last_resort_iterations == 0 {
            return None;
        }
        self.start_plain(frame, plain, out);
        cascade.search_on(plain.as_mut()?)
    }

    /// The frame's plain search, a new one (counted) where no fast path started it.
    fn start_plain(&self, frame: &Frame, plain: &mut Option<PlainSearch>, out: &mut Localization) {
        if plain.is_none() {
            *plain = self.params.cascade.plain_search(frame, &self.pnp_params(frame), self.params.final_refine.enabled);
            out.robust_passes += usize::from(plain.is_some());
        }
    }

    /// A pose plain LO-RANSAC found on every correspondence (the fast path, the last resort):
    /// refined on all that agree, its inliers the kept set. The last resort's pose, and a fast
    /// path's the track confirmed, are also taken out of a wrong basin next to it; a fast path's
    /// settled on its support is not: its majority-like support over half the view leaves no
    /// such basin (on the sift bags the step moved MRE by under 0.005° and cost 0.5–0.9 ms a
    /// frame, a third of the frame).
    fn accept_plain(&self, frame: &Frame, mut solution: PnpSolution, out: &mut Localization) {
        if self.params.final_refine.enabled {
            self.refine_on_all(frame, &mut solution);
            if !out.fast_path || out.fast_path_on_track {
                self.out_of_basin(frame, &mut solution, Flagged::All);
            }
        }
        out.kept = inliers_of(frame, &solution);
        self.accept(frame, &solution, self.verifier(frame).as_ref(), out);
    }

    /// PnP's parameters for the frame's camera, with the localizer's seed.
    fn pnp_params(&self, frame: &Frame) -> PnpParams {
        PnpParams { seed: self.params.seed, ..self.params.pnp.for_camera(frame.intrinsics.fx) }
    }

    /// Fills `out` with the solved pose, the prior's quality at it and how sure it is among
    /// every match of `frame`.
    fn accept(&self, frame: &Frame, solution: &PnpSolution, verifier: Option<&PriorVerifier>, out: &mut Localization) {
        out.pose = Some(solution.pose);
        let threshold_px = self.pnp_params(frame).threshold_px;
        out.covariance =
            Some(self.params.covariance.published(frame, &solution.pose, &solution.covariance, threshold_px));
        out.num_inliers = solution.num_inliers;
        out.pnp_iterations += solution.iterations;
        out.prior_quality = verifier.map(|v| v.agreement(&solution.pose).in_view_share(self.params.verify.min_view));
        out.log10_nfa = Some(self.significance(frame, &solution.pose).log10_nfa);
    }

    /// A found pose that neither every match makes significant ([`CascadeParams::publish_nfa`])
    /// nor the prior confirms (`verify.min_trust`, for support not left to chance:
    /// [`CascadeParams::prior_nfa`]) is not published: the frame reports it unsure.
    /// The prior's confirmation stands only where the track's `prediction` (once it has proved
    /// itself) does not put the camera elsewhere ([`track`]). On the three shared extreme bags,
    /// frames alone, this leaves 1.8 / 2.2 / 7.4 % of the published poses wrong (10 / 20 / 15 %
    /// before #34; the wrong ones left agree with the prior in 70–79 % of their view), tracked
    /// 0 / 2.2 / 2.0 % with as many registered; the sift and hard bags publish every pose. The
    /// published pose, as the track learns from it.
    fn withhold_unsure(
        &self,
        frame: &Frame,
        prediction: Option<&Prediction>,
        out: &mut Localization,
    ) -> Option<Published> {
        let (Some(pose), Some(log10_nfa)) = (out.pose, out.log10_nfa) else { return None };
        let level = self.params.cascade.publish_nfa;
        let meaningful = !(level > 0.0) || log10_nfa <= level.log10();
        let threshold_px = self.pnp_params(frame).threshold_px;
        let weighed =
            self.on_track(prediction).map(|t| t.weigh(&frame.intrinsics, &frame.correspondences, &pose, threshold_px));
        let (depth, agreement) = (weighed.and_then(|w| w.depth), weighed.and_then(|w| w.agreement));
        let prior_agrees = out.prior_quality.is_some_and(|q| q >= self.params.verify.min_trust);
        let prior_may_confirm = self.params.cascade.prior_may_confirm(log10_nfa);
        let prior_confirms = prior_agrees && prior_may_confirm;
        let off_track = agreement.filter(|a| !a.agrees());
        if meaningful || (prior_confirms && off_track.is_none()) {
            return Some(Published { pose, sure: meaningful, depth, agreement });
        }
        out.failure = Some(match off_track {
            Some(a) if prior_confirms => {
                Failure::OffTrack { log10_nfa, angle_deg: a.angle.to_degrees(), gate_deg: a.gate.to_degrees() }
            }
            _ => Failure::Unsure {
                log10_nfa,
                prior_quality: out.prior_quality,
                prior_level: (prior_agrees && !prior_may_confirm).then_some(self.params.cascade.prior_nfa.log10()),
            },
        });
        out.pose = None;
        out.covariance = None;
        None
    }

    /// With a pose gate, a sure pose outside it that outweighs the pose inside ([`gate`]): the
    /// frame publishes none and says why.
    fn weigh_gate(&self, out: &mut Localization) {
        if let Some(failure) = gate::contradiction(out, self.params.cascade.publish_nfa) {
            out.pose = None;
            out.covariance = None;
            out.failure = Some(failure);
        }
    }

    /// How sure the camera-to-map `pose` is among every correspondence of `frame`, at PnP's
    /// inlier threshold and coverage cells for its camera.
    fn significance(&self, frame: &Frame, pose: &Isometry3<f64>) -> Significance {
        let pnp = self.pnp_params(frame);
        Significance::of(&frame.intrinsics, &frame.correspondences, pose, pnp.threshold_px, pnp.coverage_cell_px)
    }

    /// The track's `prediction` as poses are weighed against it (its gate).
    fn on_track<'a>(&self, prediction: Option<&'a Prediction>) -> Option<OnTrack<'a>> {
        prediction.map(|prediction| OnTrack { prediction, gate: self.params.tracking.gate })
    }

    /// The track's `prediction` as the fast path weighs its pose against it
    /// ([`TrackingParams::settle_gate`]).
    fn on_track_closely<'a>(&self, prediction: Option<&'a Prediction>) -> Option<OnTrack<'a>> {
        // A prediction that is not evidence yet confirms nothing: the fast path then searches
        // no further for it.
        let gate = self.params.tracking.settle_gate;
        let evidence = prediction.filter(|p| gate > 0.0 && p.typical_error.is_some());
        evidence.map(|prediction| OnTrack { prediction, gate })
    }

    /// The verifier of PnP's hypotheses against the frame's dense prior, when there is a prior,
    /// a map and verification is on.
    fn verifier(&self, frame: &Frame) -> Option<PriorVerifier<'_>> {
        let verify = &self.params.verify;
        match (&frame.depth_prior, verify.enabled) {
            (Some(prior), true) => {
                PriorVerifier::new(&self.render_map, prior, self.params.depth_kind, &frame.intrinsics, verify)
            }
            _ => None,
        }
    }

    fn validate(&self, frame: &Frame) -> Result<(), Failure> {
        if !frame.intrinsics.is_valid() {
            return Err(Failure::InvalidIntrinsics);
        }
        let n = frame.correspondences.len();
        if n == 0 {
            return Err(Failure::NoCorrespondences);
        }
        let need = self.params.pnp.min_inliers.max(4);
        if n < need {
            return Err(Failure::TooFewCorrespondences { have: n, need });
        }
        if let Some(index) = frame
            .correspondences
            .iter()
            .position(|c| !(c.pixel.iter().chain(c.point.iter()).all(|v| v.is_finite()) && c.score.is_finite()))
        {
            return Err(Failure::NonFinite { index });
        }
        Ok(())
    }
}

/// The frame's correspondences that are inliers of `solution` (found on all of them), scored 1.
fn inliers_of(frame: &Frame, solution: &PnpSolution) -> Vec<Correspondence> {
    frame
        .correspondences
        .iter()
        .zip(&solution.inliers)
        .filter(|(_, &inlier)| inlier)
        .map(|(c, _)| with_score(*c, 1.0))
        .collect()
}

fn with_score(mut c: Correspondence, score: f32) -> Correspondence {
    c.score = score;
    c
}

/// The plain search of `frame` and the fast path's stages of it: its settled solution or what
/// it measured, the search to go on with (`None` for a frame it cannot search), and how long it
/// took (ms).
fn fast_path_timed(
    cascade: &CascadeParams,
    frame: &Frame,
    pnp: &PnpParams,
    gate: Option<&PoseGate>,
    track: Option<&OnTrack>,
    refined_after: bool,
) -> (Result<FastPathSettled, FastPathCheck>, Option<PlainSearch>, f64) {
    let t = Instant::now();
    let mut plain = cascade.plain_search(frame, pnp, refined_after);
    let settled = cascade.settle(frame, plain.as_mut(), pnp, gate, track);
    (settled, plain, ms_since(t))
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
