//! The last choice on a found pose, over every correspondence of the frame: the final
//! refinement ([`FinalRefine`](super::refine::FinalRefine)), the arbitration between the pose
//! and the search's other candidates ([`arbiter`]), the plain search confirming an unsure guided
//! pose, and the step out of a wrong basin next to it. Each weighs a candidate by the same rule
//! ([`arbiter::Challenge::beats`]) and re-flags the inliers of the pose it keeps.

use nalgebra::Isometry3;

use super::arbiter;
use super::cascade::PlainSearch;
use super::gate;
use super::localization::Localization;
use super::refine::RefineFrame;
use super::Localizer;
use crate::frame::Frame;
use crate::pnp::PnpSolution;

/// Which correspondences a solution's inlier flags are over.
#[derive(Clone, Copy, Debug)]
pub(super) enum Flagged {
    /// Those PnP saw (the kept set, in the scratch).
    Kept,
    /// Every correspondence of the frame (the plain search's).
    All,
}

impl Localizer {
    /// A pose the rejector's order found whose support among every match is not sure (its
    /// number of false alarms above [`CascadeParams::confirm_nfa`]): the plain pass over every
    /// match goes on, and its pose replaces the found one when it is sure itself, surer, and
    /// covers more cells once refined ([`arbiter`]). An unsure pose is replaced by a sure one,
    /// never by another unsure one: on the shared extreme frames, wrong matches moved patch-wise
    /// give plain LO-RANSAC wrong poses with more inliers than the true pose (up to 22 against
    /// 9), but none of them sure (log₁₀ NFA ≥ −1.6 in cells); a rejector that lost the true
    /// matches leaves a pose that a sure one over every match replaces (log₁₀ NFA −5 to −10).
    pub(super) fn confirm_on_all(
        &self,
        frame: &Frame,
        solution: &mut PnpSolution,
        plain: &mut Option<PlainSearch>,
        out: &mut Localization,
    ) {
        let cascade = &self.params.cascade;
        let found = self.significance(frame, &solution.pose);
        if !(cascade.confirm_nfa > 0.0) || found.below(cascade.confirm_nfa) {
            return;
        }
        let Some(confirming) = self.search_on(frame, plain, out) else { return };
        out.confirm_search = true;
        out.pnp_iterations += confirming.iterations;
        let sure = self.significance(frame, &confirming.pose);
        if !gate::admits(self.pose_gate.as_ref(), &confirming.pose) {
            gate::note_outside(out, sure.log10_nfa);
            return;
        }
        if sure.below(cascade.confirm_nfa) && sure.log10_nfa < found.log10_nfa {
            self.arbitrate_on_all(frame, &[confirming.pose], 1.0, solution);
        }
    }

    /// Rejection keeps a subset; once the pose is known, every correspondence that agrees with
    /// it within the frame's own noise sharpens it in a last LM ([`FinalRefine`](super::refine::FinalRefine)).
    pub(super) fn refine_on_all(&self, frame: &Frame, solution: &mut PnpSolution) {
        self.params.final_refine.apply(&self.refine_frame(frame), solution);
    }

    /// `frame`'s correspondences as the last refinement weighs them: at PnP's threshold for its
    /// camera.
    pub(super) fn refine_frame<'a>(&self, frame: &'a Frame) -> RefineFrame<'a> {
        let pnp = self.pnp_params(frame);
        RefineFrame {
            k: &frame.intrinsics,
            correspondences: &frame.correspondences,
            inlier_threshold_px: pnp.threshold_px,
            pixel_scale: pnp.threshold_px / self.params.pnp.threshold_px,
            min_count: pnp.min_inliers.max(4),
        }
    }

    /// The pool's first `final_refine.alternatives` other candidates and `poses` (the fast
    /// path's unsettled pose, or the plain search's confirming one), each refined on every
    /// correspondence as the chosen pose was ([`arbiter`]): the best supported of them replaces
    /// the chosen pose when it covers more than `margin` times its cells.
    pub(super) fn arbitrate_on_all(
        &self,
        frame: &Frame,
        poses: &[Isometry3<f64>],
        margin: f64,
        solution: &mut PnpSolution,
    ) {
        let pool = std::mem::take(&mut solution.alternatives).into_iter().take(self.params.final_refine.alternatives);
        let candidates: Vec<PnpSolution> = pool
            .chain(poses.iter().copied())
            .map(|start| {
                let mut candidate = PnpSolution { pose: start, ..solution.clone() };
                self.refine_on_all(frame, &mut candidate);
                candidate
            })
            .collect();
        self.weigh(frame, solution, candidates, margin, Flagged::Kept);
    }

    /// The chosen pose out of a wrong basin next to it ([`FinalRefine::out_of_basin`](super::refine::FinalRefine::out_of_basin)): the
    /// candidate replaces it by the last choice's rule ([`arbiter::Challenge::beats`]: the same
    /// answer fitting every match better, or clearly more cells). On the synthetic hard bags a
    /// pose 2.8° off with 43 inliers leaves its basin for one 0.8° off with 48; on the extreme
    /// ones, poses 2–4° off come within 1–2°.
    pub(super) fn out_of_basin(&self, frame: &Frame, solution: &mut PnpSolution, flagged: Flagged) {
        let refine = &self.params.final_refine;
        let Some(candidate) = refine.out_of_basin(&self.refine_frame(frame), solution) else { return };
        self.weigh(frame, solution, [candidate], refine.switch_margin, flagged);
    }

    /// `candidates` (refined on every correspondence) against `solution` by the last choice's
    /// rule ([`arbiter::challenger`]: support among every match, inliers shared with it, cells
    /// over `margin`); the winner replaces it, its inliers re-flagged over `flagged`.
    fn weigh(
        &self,
        frame: &Frame,
        solution: &mut PnpSolution,
        candidates: impl IntoIterator<Item = PnpSolution>,
        margin: f64,
        flagged: Flagged,
    ) {
        let pnp = self.pnp_params(frame);
        let support = |pose: &Isometry3<f64>| {
            arbiter::support(&frame.intrinsics, &frame.correspondences, pose, pnp.threshold_px, pnp.coverage_cell_px)
        };
        let (incumbent, incumbent_inliers) = support(&solution.pose);
        let challenges = candidates.into_iter().map(|candidate| {
            let (support, inliers) = support(&candidate.pose);
            let shared = arbiter::shared_inliers(&inliers, &incumbent_inliers);
            (arbiter::Challenge { support, shared }, candidate)
        });
        if let Some(better) = arbiter::challenger(incumbent, challenges, margin) {
            *solution = better;
            self.reflag(frame, solution, flagged);
        }
    }

    /// `solution`'s inlier flags and count at its pose again, over the correspondences they flag.
    pub(super) fn reflag(&self, frame: &Frame, solution: &mut PnpSolution, flagged: Flagged) {
        let (k, threshold) = (&frame.intrinsics, self.pnp_params(frame).threshold_px);
        let to_cam = solution.pose.inverse();
        let agrees = |pixel: &nalgebra::Point2<f64>, point: &nalgebra::Point3<f64>| {
            k.reprojection_error(&to_cam.transform_point(point), pixel) < threshold
        };
        solution.inliers = match flagged {
            Flagged::Kept => self.scratch.pixels.iter().zip(&self.scratch.points).map(|(p, q)| agrees(p, q)).collect(),
            Flagged::All => frame.correspondences.iter().map(|c| agrees(&c.pixel, &c.point)).collect(),
        };
        solution.num_inliers = solution.inliers.iter().filter(|&&f| f).count();
    }
}
