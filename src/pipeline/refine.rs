//! The last refinement of a pose over every correspondence of the frame that agrees with it:
//! rejection (or a budgeted RANSAC) found the pose on a subset; the correspondences it left out
//! but that fit sharpen it. Every correspondence within PnP's inlier threshold joins, as in
//! PoseLib's last bundle adjustment over its LO-RANSAC's inliers, weighed by a robust loss whose
//! scale follows the frame's own pixel noise: a tolerance cut at the noise instead keeps the
//! matches that happen to agree with a pose slightly off and settles next to it.

use serde::{Deserialize, Serialize};

use crate::frame::Correspondence;
use crate::geometry::Intrinsics;
use crate::pnp::{pose_covariance, refine_pose, PnpSolution, RefineOptions, RobustLoss};

/// The last refinement over every correspondence that agrees with the pose.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FinalRefine {
    pub enabled: bool,
    /// The loss over the correspondences within PnP's inlier threshold of the pose.
    pub loss: RobustLoss,
    /// The loss's scale, in σ̂: the pixel noise estimated from those correspondences (median
    /// residual / 1.1774, the Rayleigh median). In pixels of the frame's own noise, so it holds
    /// at any depth range and follows the matcher's accuracy.
    pub loss_sigmas: f64,
    /// The loss's scale at least, pixels at PnP's reference focal length (scaled with it): a
    /// pose that fits a handful of matches exactly measures no noise.
    pub min_loss_scale_px: f64,
    pub max_iterations: usize,
    /// Gather-and-refine rounds: each refined pose gathers the agreeing correspondences again,
    /// while their number grows (a pose found on a subset that misses part of the true matches
    /// recruits them as it sharpens); 1: one gathering.
    pub rounds: usize,
    /// After the rejection-guided PnP, its verifier's first this many other candidates, and the
    /// cascade's unsettled fast-path pose, are refined on every correspondence too, and the
    /// best supported of them there (most image cells, then inliers) replaces the chosen pose
    /// when it covers more than `switch_margin` times its cells (the matches rejection left out
    /// settle what the kept ones could not), or, keeping nine in ten of its inliers, explains
    /// as many and fits every match better (the same answer out of a wrong basin next to it);
    /// 0: off.
    pub alternatives: usize,
    pub switch_margin: f64,
    /// The chosen pose is refined once more from the matches within this many inlier
    /// thresholds of it ([`FinalRefine::out_of_basin`]), and that candidate weighed against it
    /// as the alternatives are; 1: off. Three thresholds reach a basin of the reprojection
    /// error a few degrees from the pose on a frame whose matches barely constrain it, and the
    /// robust loss at the frame's noise keeps what lies between the basins from pulling.
    pub widen_threshold: f64,
}

impl Default for FinalRefine {
    fn default() -> Self {
        Self {
            enabled: true,
            loss: RobustLoss::Cauchy,
            loss_sigmas: 2.0,
            min_loss_scale_px: 0.5,
            max_iterations: 20,
            rounds: 4,
            alternatives: 4,
            switch_margin: 1.25,
            widen_threshold: 3.0,
        }
    }
}

/// A frame's correspondences as the last refinement weighs them.
#[derive(Clone, Copy, Debug)]
pub struct RefineFrame<'a> {
    pub k: &'a Intrinsics,
    pub correspondences: &'a [Correspondence],
    /// PnP's inlier threshold for the camera, pixels.
    pub inlier_threshold_px: f64,
    /// How PnP's pixels scale for the camera ([`crate::pnp::PnpParams::for_camera`]): the
    /// loss's pixel floor scales with it.
    pub pixel_scale: f64,
    /// Correspondences that must agree with a pose for it to be refined.
    pub min_count: usize,
}

/// The Rayleigh distribution's median over its σ: √(2 ln 2).
const RAYLEIGH_MEDIAN: f64 = 1.177_410_022_515_474_7;

impl FinalRefine {
    /// Refines `solution` in place on the frame's correspondences within PnP's inlier threshold
    /// of its pose. Leaves it unchanged when fewer than `min_count` agree or the refinement
    /// fails; whether it refined it.
    pub fn apply(&self, frame: &RefineFrame, solution: &mut PnpSolution) -> bool {
        let RefineFrame { k, correspondences, inlier_threshold_px, pixel_scale, min_count } = *frame;
        let (mut gathered, mut refined) = (0, false);
        for _ in 0..self.rounds.max(1) {
            let agreeing = Agreeing::gather(k, correspondences, inlier_threshold_px, &solution.pose);
            if agreeing.correspondences.len() < min_count.max(3) || agreeing.correspondences.len() <= gathered {
                break;
            }
            gathered = agreeing.correspondences.len();
            if !self.refine_on(k, &agreeing.correspondences, self.loss_scale_px(&agreeing, pixel_scale), solution) {
                break;
            }
            refined = true;
        }
        if refined {
            measure_covariance(k, correspondences, inlier_threshold_px, solution);
        }
        refined
    }

    /// LO-RANSAC's least squares from a wide threshold (Chum, Matas & Kittler 2003; Lebeda,
    /// Matas & Chum 2012), on a refined `solution`: a pose that settled in a wrong basin of the
    /// reprojection error next to the true one (a degree or more off, on a frame whose matches
    /// barely constrain it) gathers within the inlier threshold only the matches that agree with
    /// it there. Gathered within [`FinalRefine::widen_threshold`] thresholds and weighed by the
    /// robust loss at the noise of those within one, the true matches pull it out; then the
    /// rounds of [`FinalRefine::apply`] settle it. A candidate for the caller to weigh against
    /// the pose (a wider gathering can also take a biased group in); `None` when off, or when
    /// too few agree or the refinement fails.
    pub fn out_of_basin(&self, frame: &RefineFrame, solution: &PnpSolution) -> Option<PnpSolution> {
        let RefineFrame { k, correspondences, inlier_threshold_px, pixel_scale, min_count } = *frame;
        if self.widen_threshold.is_nan() || self.widen_threshold <= 1.0 {
            return None;
        }
        let near = Agreeing::gather(k, correspondences, inlier_threshold_px, &solution.pose);
        let wide = Agreeing::gather(k, correspondences, self.widen_threshold * inlier_threshold_px, &solution.pose);
        if near.correspondences.len() < min_count.max(3) {
            return None;
        }
        let mut candidate = solution.clone();
        if !self.refine_on(k, &wide.correspondences, self.loss_scale_px(&near, pixel_scale), &mut candidate) {
            return None;
        }
        if !self.apply(frame, &mut candidate) {
            measure_covariance(k, correspondences, inlier_threshold_px, &mut candidate);
        }
        Some(candidate)
    }

    /// The loss's scale for `agreeing`: `loss_sigmas` of their noise, at least the floor.
    fn loss_scale_px(&self, agreeing: &Agreeing, pixel_scale: f64) -> f64 {
        (self.loss_sigmas * agreeing.noise_px).max(self.min_loss_scale_px * pixel_scale)
    }

    /// LM on `agreeing` from `solution`'s pose, into it; whether it succeeded.
    fn refine_on(
        &self,
        k: &Intrinsics,
        agreeing: &[&Correspondence],
        loss_scale_px: f64,
        solution: &mut PnpSolution,
    ) -> bool {
        let (pixels, points): (Vec<_>, Vec<_>) = agreeing.iter().map(|c| (c.pixel, c.point)).unzip();
        let options = RefineOptions { max_iterations: self.max_iterations, loss: self.loss, loss_scale_px };
        let Ok(refined) = refine_pose(k, &pixels, &points, &solution.pose, &options) else { return false };
        solution.pose = refined.pose;
        solution.rmse_px = refined.rmse_px;
        true
    }
}

/// The covariance of the refined pose is measured on the matches within this many σ̂ of it
/// (98.9 % of Gaussian pixel noise): the robust loss weighed the others near zero, and their
/// residuals would inflate the noise the covariance scales with.
const COVARIANCE_SIGMAS: f64 = 3.0;

/// `solution`'s covariance from the `correspondences` within [`COVARIANCE_SIGMAS`]·σ̂ of its
/// pose (σ̂ measured on those within `inlier_threshold_px`); left as it was when too few.
fn measure_covariance(
    k: &Intrinsics,
    correspondences: &[Correspondence],
    inlier_threshold_px: f64,
    solution: &mut PnpSolution,
) {
    let agreeing = Agreeing::gather(k, correspondences, inlier_threshold_px, &solution.pose);
    let (pixels, points): (Vec<_>, Vec<_>) =
        agreeing.within(COVARIANCE_SIGMAS * agreeing.noise_px).map(|c| (c.pixel, c.point)).unzip();
    if let Ok(cov) = pose_covariance(k, &pixels, &points, &solution.pose) {
        solution.covariance = cov;
    }
}

/// The correspondences within an inlier threshold of a pose, and the pixel noise they show.
struct Agreeing<'c> {
    correspondences: Vec<&'c Correspondence>,
    /// Their reprojection errors at the pose, in the same order.
    residuals: Vec<f64>,
    /// σ̂: their median reprojection error over the Rayleigh median (0 when none agree).
    noise_px: f64,
}

impl<'c> Agreeing<'c> {
    /// The `correspondences` whose reprojection error at `pose` is below `threshold_px`.
    fn gather(
        k: &Intrinsics,
        correspondences: &'c [Correspondence],
        threshold_px: f64,
        pose: &nalgebra::Isometry3<f64>,
    ) -> Self {
        let to_cam = pose.inverse();
        let (agreeing, residuals): (Vec<_>, Vec<_>) = correspondences
            .iter()
            .map(|c| (c, k.reprojection_error(&to_cam.transform_point(&c.point), &c.pixel)))
            .filter(|&(_, r)| r < threshold_px)
            .unzip();
        let mut sorted = residuals.clone();
        let noise_px = match sorted.len() {
            0 => 0.0,
            n => *sorted.select_nth_unstable_by(n / 2, f64::total_cmp).1 / RAYLEIGH_MEDIAN,
        };
        Self { correspondences: agreeing, residuals, noise_px }
    }

    /// Those of them whose reprojection error is also below `threshold_px`.
    fn within(&self, threshold_px: f64) -> impl Iterator<Item = &'c Correspondence> + '_ {
        self.correspondences.iter().zip(&self.residuals).filter(move |&(_, &r)| r < threshold_px).map(|(c, _)| *c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Matrix6, Point2, Translation3, UnitQuaternion};

    /// A close-range frame (0.4–0.9 m): 1 px noise on 150 matches, and 50 outliers 12–20 px off,
    /// all to the right (a biased group, as near misses on repeated texture are).
    fn frame(seed: u64) -> (Intrinsics, Isometry3<f64>, Vec<Correspondence>) {
        let k = Intrinsics { fx: 615.0, fy: 615.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };
        let pose =
            Isometry3::from_parts(Translation3::new(0.1, -0.2, 0.3), UnitQuaternion::from_euler_angles(0.1, 0.2, -0.1));
        let mut lcg = crate::rng::Lcg64(seed);
        let mut uniform = move || lcg.next_f64();
        let mut corrs = Vec::new();
        for i in 0..200 {
            let pixel = Point2::new(20.0 + 600.0 * uniform(), 20.0 + 440.0 * uniform());
            let point = pose * k.back_project(&pixel, 0.4 + 0.5 * uniform());
            let angle = std::f64::consts::TAU * uniform();
            let offset = if i < 150 {
                nalgebra::Vector2::new(angle.cos(), angle.sin()) * uniform()
            } else {
                nalgebra::Vector2::new(12.0 + 8.0 * uniform(), 0.0)
            };
            corrs.push(Correspondence { pixel: pixel + offset, point, score: 1.0 });
        }
        (k, pose, corrs)
    }

    fn rotation_error_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
        a.rotation.angle_to(&b.rotation).to_degrees()
    }

    /// `refine` applied from `start` (PnP's threshold 8 px, 6 correspondences at least): the
    /// refined pose.
    fn refined(
        refine: &FinalRefine,
        k: &Intrinsics,
        corrs: &[Correspondence],
        start: Isometry3<f64>,
    ) -> Isometry3<f64> {
        refined_within(refine, k, corrs, start, 8.0)
    }

    /// `corrs` as PnP's threshold `threshold_px` at its reference focal length and 6 matches at
    /// least take them.
    fn at<'a>(k: &'a Intrinsics, corrs: &'a [Correspondence], threshold_px: f64) -> RefineFrame<'a> {
        RefineFrame { k, correspondences: corrs, inlier_threshold_px: threshold_px, pixel_scale: 1.0, min_count: 6 }
    }

    /// A solution at `pose` over `count` correspondences, before the last refinement.
    fn unrefined(pose: Isometry3<f64>, count: usize) -> PnpSolution {
        PnpSolution {
            pose,
            inliers: vec![true; count],
            num_inliers: count,
            iterations: 0,
            rmse_px: 0.0,
            covariance: Matrix6::identity(),
            alternatives: Vec::new(),
        }
    }

    /// `refine` applied from `start` with PnP's threshold at `threshold_px`.
    fn refined_within(
        refine: &FinalRefine,
        k: &Intrinsics,
        corrs: &[Correspondence],
        start: Isometry3<f64>,
        threshold_px: f64,
    ) -> Isometry3<f64> {
        let mut solution = unrefined(start, corrs.len());
        refine.apply(&at(k, corrs, threshold_px), &mut solution);
        solution.pose
    }

    #[test]
    fn the_loss_follows_the_frames_noise_and_leaves_outliers_out_at_close_range() {
        let refine = FinalRefine::default();
        for seed in 1..4 {
            let (k, truth, corrs) = frame(seed);
            let start = truth
                * Isometry3::from_parts(
                    Translation3::new(0.004, 0.0, -0.003),
                    UnitQuaternion::from_euler_angles(0.004, -0.003, 0.002),
                );
            let error = rotation_error_deg(&refined(&refine, &k, &corrs, start), &truth);
            // A metric tolerance (3 cm at 0.5 m is ~37 px here) would take every outlier in.
            let least_squares = FinalRefine { loss: RobustLoss::Trivial, ..FinalRefine::default() };
            let with_outliers = rotation_error_deg(&refined_within(&least_squares, &k, &corrs, start, 40.0), &truth);
            assert!(error < 0.2, "seed {seed}: {error}° off");
            assert!(error < with_outliers, "seed {seed}: {error}° vs {with_outliers}° with the outliers in");
        }
    }

    #[test]
    fn a_pose_found_on_part_of_the_matches_recruits_the_rest_round_by_round() {
        // A pose 1 cm off sideways (as PnP on a kept set that lost part of the true matches can
        // leave it): at 0.4–0.9 m the near matches are 6–14 px off and the far ones 3–6 px, so
        // one gathering takes the far ones only and LM on them leaves a tilt; later rounds, each
        // from the sharper pose, take the near ones in.
        let one = FinalRefine { rounds: 1, ..FinalRefine::default() };
        let rounds = FinalRefine::default();
        for seed in 1..9 {
            let (k, truth, corrs) = frame(seed);
            let start = truth * Translation3::new(0.009, -0.006, 0.0);
            let solve = |refine: &FinalRefine| rotation_error_deg(&refined(refine, &k, &corrs, start), &truth);
            let (after_one, after_rounds) = (solve(&one), solve(&rounds));
            assert!(after_rounds < 0.05, "seed {seed}: {after_rounds}° off after the rounds");
            assert!(after_rounds < 0.5 * after_one, "seed {seed}: {after_rounds}° vs {after_one}° after one gathering");
        }
    }

    #[test]
    fn a_pose_in_a_basin_degrees_off_leaves_it_from_a_wide_gathering() {
        // Turned 4° about a vertical axis through the point 0.65 m ahead: the true matches at
        // that depth still agree within PnP's 8 px, the nearer and farther ones are 12–27 px
        // off; and 60 wrong matches that this turned pose explains exactly (a matcher's patch of
        // mistakes on a repeated object) hold it there. The rounds within 8 px stay in that
        // basin, 1–4° off; gathered within three thresholds, the 150 true matches pull it out.
        let rounds = FinalRefine::default();
        let turn = UnitQuaternion::from_euler_angles(0.0, 0.07, 0.0);
        let pivot = nalgebra::Vector3::new(0.0, 0.0, 0.65);
        let off = Isometry3::from_parts(Translation3::from(pivot - turn * pivot), turn);
        let mut left_the_basin = 0;
        for seed in 1..6 {
            let (k, truth, mut corrs) = frame(seed);
            corrs.truncate(150);
            let wrong = truth * off;
            let mut lcg = crate::rng::Lcg64(seed + 50);
            for _ in 0..60 {
                let pixel = Point2::new(20.0 + 300.0 * lcg.next_f64(), 20.0 + 200.0 * lcg.next_f64());
                let point = wrong * k.back_project(&pixel, 0.5 + 0.3 * lcg.next_f64());
                corrs.push(Correspondence { pixel, point, score: 1.0 });
            }
            let mut stayed = unrefined(wrong, corrs.len());
            rounds.apply(&at(&k, &corrs, 8.0), &mut stayed);
            let left = rounds.out_of_basin(&at(&k, &corrs, 8.0), &stayed).expect("a candidate");
            let (before, after) = (rotation_error_deg(&stayed.pose, &truth), rotation_error_deg(&left.pose, &truth));
            assert!(before > 0.9, "seed {seed}: the rounds alone reach {before}°: the test shows nothing");
            assert!(after <= before + 1e-3, "seed {seed}: {after}° off after the wide gathering, {before}° before");
            left_the_basin += usize::from(after < 0.05);
        }
        assert!(left_the_basin >= 4, "{left_the_basin} of 5 frames left the basin");
        let off = FinalRefine { widen_threshold: 1.0, ..FinalRefine::default() };
        let (k, truth, corrs) = frame(1);
        assert!(off.out_of_basin(&at(&k, &corrs, 8.0), &unrefined(truth, corrs.len())).is_none());
    }

    #[test]
    fn the_covariance_is_measured_on_the_matches_the_loss_keeps() {
        // 150 matches with ≤ 1 px of noise and 30 near misses 5–7 px off, inside PnP's 8 px:
        // the Cauchy loss weighs the near misses near zero, and so must the covariance's noise.
        for seed in 1..4 {
            let (k, truth, mut corrs) = frame(seed);
            corrs.truncate(150);
            let mut lcg = crate::rng::Lcg64(seed + 100);
            for c in corrs.clone().iter().take(30) {
                let angle = std::f64::consts::TAU * lcg.next_f64();
                let offset = nalgebra::Vector2::new(angle.cos(), angle.sin()) * (5.0 + 2.0 * lcg.next_f64());
                corrs.push(Correspondence { pixel: c.pixel + offset, ..*c });
            }
            let mut solution = unrefined(truth, corrs.len());
            FinalRefine::default().apply(&at(&k, &corrs, 8.0), &mut solution);
            let on = |set: &[Correspondence]| {
                let pixels: Vec<_> = set.iter().map(|c| c.pixel).collect();
                let points: Vec<_> = set.iter().map(|c| c.point).collect();
                pose_covariance(&k, &pixels, &points, &solution.pose).unwrap().trace()
            };
            let (true_ones, all_within) = (on(&corrs[..150]), on(&corrs));
            let measured = solution.covariance.trace();
            assert!((0.7..1.4).contains(&(measured / true_ones)), "seed {seed}: {measured} vs {true_ones}");
            assert!(all_within > 2.0 * measured, "seed {seed}: {all_within} vs {measured}");
        }
    }
}
