//! Localization metrics of the paper's section 4, defined exactly as the reference evaluator
//! `shared/tools/baseline_opencv.py` computes them:
//!
//! * IR — inlier ratio of (kept) correspondences: a correspondence is an inlier when its pixel,
//!   lifted with the ground-truth depth (nearest pixel, 0 = unknown) and the ground-truth pose,
//!   lies within 5 cm of its map point; only pixels with ground-truth depth count.
//! * RR — registration recall: the share of frames whose RMSE, over the ground-truth-depth
//!   points of the frame (every 4th pixel) moved by the ground-truth vs the estimated pose, is
//!   below 0.1 m.
//! * MRE / MTE — mean rotation (degrees) and translation (metres) errors over the frames that
//!   have an estimate; medians too.
//!
//! Beside them, what a user of the published poses sees (not in the reference evaluator):
//! * availability — the share of frames that got a pose at all;
//! * false-pose rate — the share of the published poses that are wrong (not registered): a
//!   likely-wrong pose published as a pose is worse than none;
//! * recovery after a jump of the camera (a kidnap, [`recovery`]): frames to a correct pose and
//!   the wrong poses published meanwhile.

use nalgebra::{Isometry3, Matrix3, Matrix6, Vector3};
use serde::Serialize;

use crate::frame::Correspondence;
use crate::geometry::{DepthImage, Intrinsics};

mod recovery;
pub use recovery::{jumps, recovery, Recovery, JUMP_FACTOR};

/// Inlier distance of the IR metric (metres).
pub const INLIER_THRESHOLD: f64 = 0.05;
/// RMSE under which a frame counts as registered (metres).
pub const RECALL_THRESHOLD: f64 = 0.1;
/// Pixel stride of the RMSE's point sample.
const RMSE_STRIDE: usize = 4;

/// Per correspondence: (is an inlier, has ground-truth depth).
pub fn inlier_mask(
    correspondences: &[Correspondence],
    k: &Intrinsics,
    gt_pose: &Isometry3<f64>,
    gt_depth: &DepthImage,
) -> Vec<(bool, bool)> {
    let (w, h) = (gt_depth.width as i64, gt_depth.height as i64);
    correspondences
        .iter()
        .map(|c| {
            if w == 0 || h == 0 {
                // An empty ground-truth image: no pixel has depth.
                return (false, false);
            }
            // numpy's round: half to even, then clipped into the image.
            let u = (c.pixel.x.round_ties_even() as i64).clamp(0, w - 1);
            let v = (c.pixel.y.round_ties_even() as i64).clamp(0, h - 1);
            let z = gt_depth.data.get((v * w + u) as usize).copied().unwrap_or(0.0) as f64;
            if !(z > 0.0) {
                return (false, false);
            }
            let p = nalgebra::Point3::new((c.pixel.x - k.cx) * z / k.fx, (c.pixel.y - k.cy) * z / k.fy, z);
            ((gt_pose.transform_point(&p) - c.point).norm() < INLIER_THRESHOLD, true)
        })
        .collect()
}

/// The inlier ratio over correspondences with ground-truth depth (0 when none has).
pub fn inlier_ratio(mask: &[(bool, bool)]) -> f64 {
    let valid = mask.iter().filter(|m| m.1).count();
    if valid == 0 {
        return 0.0;
    }
    mask.iter().filter(|m| m.0 && m.1).count() as f64 / valid as f64
}

/// Errors of an estimated camera-to-map pose against the ground truth.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PoseErrors {
    pub rotation_deg: f64,
    pub translation_m: f64,
    /// RMSE of the frame's ground-truth-depth points under both poses.
    pub rmse_m: f64,
    /// The error's NEES under the published covariance ([`nees`]), when one was published.
    pub nees: Option<f64>,
}

impl PoseErrors {
    /// Whether these errors register the frame (RMSE below the recall threshold, 0.1 m).
    pub fn registered(&self) -> bool {
        self.rmse_m < RECALL_THRESHOLD
    }
}

pub fn pose_errors(est: &Isometry3<f64>, gt: &Isometry3<f64>, k: &Intrinsics, gt_depth: &DepthImage) -> PoseErrors {
    let (r_est, r_gt) = (est.rotation.to_rotation_matrix().into_inner(), gt.rotation.to_rotation_matrix().into_inner());
    let d_r: Matrix3<f64> = r_est.transpose() * r_gt;
    let rotation_deg = ((d_r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
    let d_t: Vector3<f64> = gt.translation.vector - est.translation.vector;
    let translation_m = d_t.norm();
    let diff_r = r_gt - r_est;
    let (mut sum, mut count) = (0.0, 0usize);
    let w = gt_depth.width as usize;
    for v in (0..gt_depth.height as usize).step_by(RMSE_STRIDE) {
        for u in (0..w).step_by(RMSE_STRIDE) {
            let z = gt_depth.data.get(v * w + u).copied().unwrap_or(0.0) as f64;
            if z == 0.0 || !z.is_finite() {
                continue;
            }
            let p = Vector3::new((u as f64 - k.cx) * z / k.fx, (v as f64 - k.cy) * z / k.fy, z);
            sum += (diff_r * p + d_t).norm_squared();
            count += 1;
        }
    }
    let rmse_m = if count > 0 { (sum / count as f64).sqrt() } else { f64::NAN };
    PoseErrors { rotation_deg, translation_m, rmse_m, nees: None }
}

/// χ² with 6 degrees of freedom at 0.95: an error inside a covariance's 95 % ellipsoid has a
/// NEES below it.
pub const CHI2_6DOF_95: f64 = 12.5916;

/// The normalized estimation error squared `eᵀ Σ⁻¹ e` of the camera-to-map pose `est` against
/// `gt` under `covariance`, in the pipeline's parameterisation (ROS order `(x, y, z, rot x,
/// rot y, rot z)`, perturbed in the map frame: `p_gt = p + δp`, `R_gt = exp([δθ]×)·R`). A
/// calibrated covariance gives NEES ~ χ²₆ (mean 6, 95 % below [`CHI2_6DOF_95`]). `None` when the
/// covariance is not positive definite.
pub fn nees(est: &Isometry3<f64>, gt: &Isometry3<f64>, covariance: &Matrix6<f64>) -> Option<f64> {
    let dp = gt.translation.vector - est.translation.vector;
    let dtheta = (gt.rotation * est.rotation.inverse()).scaled_axis();
    let e = nalgebra::Vector6::new(dp.x, dp.y, dp.z, dtheta.x, dtheta.y, dtheta.z);
    let cholesky = nalgebra::Cholesky::new(*covariance)?;
    let value = e.dot(&cholesky.solve(&e));
    value.is_finite().then_some(value)
}

/// One evaluated frame.
#[derive(Clone, Debug, Serialize)]
pub struct FrameMetrics {
    pub stamp: i64,
    pub inlier_ratio: f64,
    pub errors: Option<PoseErrors>,
    pub ms: Option<f64>,
}

impl FrameMetrics {
    pub fn registered(&self) -> bool {
        self.errors.is_some_and(|e| e.registered())
    }
}

/// A bag's scores, as the reference evaluator summarises them (percentages for IR and RR).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
#[serde(rename_all = "UPPERCASE")]
pub struct Summary {
    #[serde(rename = "frames")]
    pub frames: usize,
    pub ir: f64,
    pub rr: f64,
    pub mre: Option<f64>,
    pub mte: Option<f64>,
    #[serde(rename = "MedRE")]
    pub med_re: Option<f64>,
    #[serde(rename = "MedTE")]
    pub med_te: Option<f64>,
    /// Frames with a published pose, % of all frames.
    #[serde(rename = "availability")]
    pub availability: f64,
    /// Published poses that are wrong (RMSE ≥ the recall threshold), % of the published poses;
    /// `None` when none was published.
    #[serde(rename = "false_pose_rate")]
    pub false_pose_rate: Option<f64>,
    /// Mean and median time per frame when the run recorded it.
    #[serde(rename = "ms_per_frame")]
    pub ms_per_frame: Option<f64>,
    #[serde(rename = "median_ms")]
    pub median_ms: Option<f64>,
    /// Published poses with a covariance whose true pose lies inside its 95 % ellipsoid, %
    /// (a calibrated covariance: 95); `None` without covariances.
    #[serde(rename = "covariance_95")]
    pub covariance_95: Option<f64>,
    /// Median NEES over those poses (a calibrated covariance: ~5.3, χ²₆'s median).
    #[serde(rename = "median_nees")]
    pub median_nees: Option<f64>,
}

pub fn summarize(rows: &[FrameMetrics]) -> Summary {
    let n = rows.len();
    let with_pose: Vec<&PoseErrors> = rows.iter().filter_map(|r| r.errors.as_ref()).collect();
    let rot: Vec<f64> = with_pose.iter().map(|e| e.rotation_deg).collect();
    let trans: Vec<f64> = with_pose.iter().map(|e| e.translation_m).collect();
    let ms: Vec<f64> = rows.iter().filter_map(|r| r.ms).collect();
    let nees: Vec<f64> = with_pose.iter().filter_map(|e| e.nees).collect();
    Summary {
        frames: n,
        ir: if n > 0 { 100.0 * rows.iter().map(|r| r.inlier_ratio).sum::<f64>() / n as f64 } else { 0.0 },
        rr: 100.0 * rows.iter().filter(|r| r.registered()).count() as f64 / n.max(1) as f64,
        mre: mean(&rot),
        mte: mean(&trans),
        med_re: median(&rot),
        med_te: median(&trans),
        availability: 100.0 * with_pose.len() as f64 / n.max(1) as f64,
        false_pose_rate: (!with_pose.is_empty())
            .then(|| 100.0 * with_pose.iter().filter(|e| !e.registered()).count() as f64 / with_pose.len() as f64),
        ms_per_frame: mean(&ms),
        median_ms: median(&ms),
        covariance_95: (!nees.is_empty())
            .then(|| 100.0 * nees.iter().filter(|&&v| v <= CHI2_6DOF_95).count() as f64 / nees.len() as f64),
        median_nees: median(&nees),
    }
}

pub fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The median as numpy computes it (mean of the two middle values for an even count).
pub fn median(v: &[f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let m = s.len() / 2;
    Some(if s.len() % 2 == 0 { (s[m - 1] + s[m]) / 2.0 } else { s[m] })
}

/// A plain-text table of named summaries.
pub fn format_table(rows: &[(String, Summary)]) -> String {
    let fmt = |v: Option<f64>, p: usize| v.map_or_else(|| "-".to_string(), |x| format!("{x:.p$}"));
    let width = rows.iter().map(|(name, _)| name.len()).max().unwrap_or(6).max(6);
    let mut out = format!(
        "{:<width$}  {:>6}  {:>6}  {:>6}  {:>7}  {:>5}  {:>8}  {:>7}  {:>7}  {:>8}  {:>9}  {:>6}  {:>6}\n",
        "method",
        "frames",
        "IR %",
        "RR %",
        "avail %",
        "FP %",
        "MRE deg",
        "MTE m",
        "MedRE",
        "MedTE m",
        "ms/frame",
        "cov95%",
        "NEES"
    );
    for (name, s) in rows {
        // The raw matches' row has no poses: neither availability nor false poses.
        let (avail, fp) = match s.false_pose_rate {
            Some(fp) => (format!("{:.1}", s.availability), format!("{fp:.1}")),
            None if s.mre.is_none() && s.ms_per_frame.is_none() => ("-".into(), "-".into()),
            None => (format!("{:.1}", s.availability), "-".into()),
        };
        out += &format!(
            "{:<width$}  {:>6}  {:>6.2}  {:>6.2}  {:>7}  {:>5}  {:>8}  {:>7}  {:>7}  {:>8}  {:>9}  {:>6}  {:>6}\n",
            name,
            s.frames,
            s.ir,
            s.rr,
            avail,
            fp,
            fmt(s.mre, 3),
            fmt(s.mte, 3),
            fmt(s.med_re, 3),
            fmt(s.med_te, 3),
            match (s.median_ms, s.ms_per_frame) {
                (Some(med), Some(mean)) => format!("{med:.2} ({mean:.2})"),
                _ => "-".into(),
            },
            fmt(s.covariance_95, 1),
            fmt(s.median_nees, 1),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point2, Point3, Translation3, UnitQuaternion};

    fn k() -> Intrinsics {
        Intrinsics { fx: 100.0, fy: 100.0, cx: 32.0, cy: 24.0, width: 64, height: 48 }
    }

    #[test]
    fn identical_poses_have_zero_error_and_register() {
        let depth = DepthImage::new(64, 48, vec![2.0; 64 * 48]);
        let pose =
            Isometry3::from_parts(Translation3::new(1.0, 2.0, 3.0), UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3));
        let e = pose_errors(&pose, &pose, &k(), &depth);
        assert!(e.rotation_deg < 1e-6 && e.translation_m < 1e-12 && e.rmse_m < 1e-12);
    }

    /// NEES in the pipeline's parameterisation: a 0.1 m offset along x under σ = 0.1 m is 1, a
    /// 0.01 rad turn about z under σ = 0.01 rad is 1; a covariance that is not positive definite
    /// gives none; the summary counts the poses inside the 95 % ellipsoid.
    #[test]
    fn nees_weighs_the_error_by_the_published_covariance() {
        let gt =
            Isometry3::from_parts(Translation3::new(1.0, 2.0, 3.0), UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3));
        let sigma = Matrix6::from_diagonal(&nalgebra::Vector6::new(0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4));
        let shifted = Isometry3::from_parts(Translation3::new(0.9, 2.0, 3.0), gt.rotation);
        assert!((nees(&shifted, &gt, &sigma).unwrap() - 1.0).abs() < 1e-9);
        // R_gt = exp([δθ]×)·R_est with δθ = 0.01 about the map's z.
        let turned =
            Isometry3::from_parts(gt.translation, UnitQuaternion::from_euler_angles(0.0, 0.0, -0.01) * gt.rotation);
        assert!((nees(&turned, &gt, &sigma).unwrap() - 1.0).abs() < 1e-6);
        assert_eq!(nees(&gt, &gt, &Matrix6::zeros()), None);
        let depth = DepthImage::new(64, 48, vec![2.0; 64 * 48]);
        let row = |stamp, est: &Isometry3<f64>, scale: f64| {
            let errors = PoseErrors { nees: nees(est, &gt, &(sigma * scale)), ..pose_errors(est, &gt, &k(), &depth) };
            FrameMetrics { stamp, inlier_ratio: 1.0, errors: Some(errors), ms: None }
        };
        // NEES 1 (inside) and 100 (outside: a covariance 100× too small).
        let s = summarize(&[row(0, &shifted, 1.0), row(1, &shifted, 0.01)]);
        assert_eq!(s.covariance_95, Some(50.0));
        assert!((s.median_nees.unwrap() - 50.5).abs() < 1e-6);
    }

    #[test]
    fn translation_offset_is_the_rmse() {
        let depth = DepthImage::new(64, 48, vec![2.0; 64 * 48]);
        let gt = Isometry3::identity();
        let est = Isometry3::translation(0.0, 0.0, 0.2);
        let e = pose_errors(&est, &gt, &k(), &depth);
        assert!((e.rmse_m - 0.2).abs() < 1e-12 && (e.translation_m - 0.2).abs() < 1e-12);
        let row = FrameMetrics { stamp: 0, inlier_ratio: 0.5, errors: Some(e), ms: Some(1.0) };
        assert!(!row.registered());
    }

    #[test]
    fn inliers_within_five_centimetres() {
        let depth = DepthImage::new(64, 48, vec![2.0; 64 * 48]);
        let pose = Isometry3::identity();
        let px = Point2::new(10.0, 20.0);
        let on = k().back_project(&px, 2.0);
        let c = |p: Point3<f64>| Correspondence { pixel: px, point: p, score: 1.0 };
        let m = inlier_mask(&[c(on), c(on + Vector3::new(0.0, 0.06, 0.0))], &k(), &pose, &depth);
        assert_eq!(m, vec![(true, true), (false, true)]);
        assert_eq!(inlier_ratio(&m), 0.5);
    }

    #[test]
    fn an_empty_ground_truth_depth_gives_no_inliers_and_no_rmse() {
        let empty = DepthImage::new(0, 0, vec![]);
        let c = Correspondence { pixel: Point2::new(3.0, 4.0), point: Point3::new(0.0, 0.0, 1.0), score: 1.0 };
        assert_eq!(inlier_mask(&[c], &k(), &Isometry3::identity(), &empty), vec![(false, false)]);
        let e = pose_errors(&Isometry3::identity(), &Isometry3::identity(), &k(), &empty);
        assert!(e.rmse_m.is_nan());
    }

    #[test]
    fn summary_matches_reference_conventions() {
        let e =
            |r: f64, rmse: f64| Some(PoseErrors { rotation_deg: r, translation_m: r / 10.0, rmse_m: rmse, nees: None });
        let rows = vec![
            FrameMetrics { stamp: 0, inlier_ratio: 0.5, errors: e(1.0, 0.05), ms: Some(2.0) },
            FrameMetrics { stamp: 1, inlier_ratio: 0.0, errors: None, ms: Some(4.0) },
            FrameMetrics { stamp: 2, inlier_ratio: 1.0, errors: e(3.0, 0.5), ms: Some(3.0) },
        ];
        let s = summarize(&rows);
        assert_eq!(s.frames, 3);
        assert!((s.ir - 50.0).abs() < 1e-12);
        assert!((s.rr - 100.0 / 3.0).abs() < 1e-12);
        assert_eq!(s.mre, Some(2.0));
        assert_eq!(s.med_re, Some(2.0));
        assert_eq!(s.median_ms, Some(3.0));
        // Two of three frames got a pose; one of those two is wrong.
        assert!((s.availability - 200.0 / 3.0).abs() < 1e-12);
        assert_eq!(s.false_pose_rate, Some(50.0));
        let none = summarize(&[FrameMetrics { stamp: 0, inlier_ratio: 0.0, errors: None, ms: None }]);
        assert_eq!((none.availability, none.false_pose_rate), (0.0, None));
        let table = format_table(&[("m".into(), s)]);
        assert!(table.contains("avail %") && table.contains("FP %") && table.contains("66.7"), "{table}");
    }
}
