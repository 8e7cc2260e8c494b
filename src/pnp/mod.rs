//! Robust perspective-n-point: camera pose from putative 2D–3D correspondences, most of them
//! wrong. Built like PoseLib: minimal solver ([`p3p`], Lambda Twist), non-minimal solver
//! ([`epnp`] + [`refine_pose`], Levenberg–Marquardt on pixel reprojection error over SE(3)) and a
//! robust estimator ([`solve_pnp_ransac`]: PROSAC/uniform sampling, SPRT + MSAC scoring,
//! LO-RANSAC, adaptive termination, final refinement and covariance), each usable on its own.
//!
//! Crate decision: written here. `kornia-pnp` is f32/glam, pulls nalgebra 0.32 and
//! kornia-imgproc, and only has EPnP inside uniform RANSAC (no P3P, PROSAC or LO); `sqpnp` is
//! good but pins nalgebra 0.34 + glam; `lambda-twist`/`arrsac` (rust-cv) sit on cv-core with an
//! old nalgebra and rand_core 0.9, are unmaintained since ~2021 and have no score-ordered sampling.
//!
//! # Conventions
//! * Pixels are in the image of [`Intrinsics`] (pinhole, no distortion): `u = fx·x/z + cx`.
//! * [`PnpSolution::pose`] and every `Isometry3` in this module's public API is the
//!   **camera-to-map** pose `T_map_cam`: `x_map = pose * x_cam`. The camera frame is the optical
//!   frame (x right, y down, z forward). [`MapToCamera`] is its inverse (`x_cam = R·x_map + t`),
//!   the form the solvers work in.
//! * A point is visible only with `z_cam > 0`; points behind the camera are never inliers.
//! * Covariances are 6×6 over `(x, y, z, rot x, rot y, rot z)` (ROS `PoseWithCovariance`
//!   order) of the camera-to-map pose, with the perturbation applied in the map frame:
//!   `p' = p + δp`, `R' = exp([δθ]×)·R`, in metres² and radians².
//! * Non-finite correspondences are ignored (never inliers); a non-finite score ranks last.

// `!(x > y)` is deliberate throughout: it is true for NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod covariance;
mod coverage;
mod epnp;
mod evaluator;
mod gate;
mod hypothesis;
mod lm;
mod nonminimal;
mod ops;
mod p3p;
mod pool;
mod ransac;
mod sampler;
mod scorer;
mod termination;

use nalgebra::{Isometry3, Matrix3, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::geometry::{Intrinsics, PriorSpace};

pub use covariance::{map_error_covariance, pose_covariance, MapError};
pub use epnp::epnp;
pub use gate::{GateMiss, PoseGate};
pub use lm::{refine_pose, RefineOptions, RefineResult};
pub use nonminimal::solve_pnp_nonminimal;
pub use p3p::{p3p, P3pSolutions};
pub use ransac::{solve_pnp_ransac, RansacSearch};

/// Why a PnP solve produced no pose.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PnpError {
    #[error("invalid camera intrinsics")]
    InvalidIntrinsics,
    #[error("length mismatch: {pixels} pixels, {points} points, {scores:?} scores")]
    LengthMismatch { pixels: usize, points: usize, scores: Option<usize> },
    #[error("invalid parameter: {0}")]
    InvalidParams(&'static str),
    #[error("too few usable correspondences: {usable} < {required}")]
    TooFewPoints { usable: usize, required: usize },
    #[error("degenerate configuration: {0}")]
    Degenerate(&'static str),
    #[error("no consensus: best pose has {inliers} inliers, {required} required")]
    NoConsensus { inliers: usize, required: usize },
}

/// Robust loss on the pixel reprojection error used by the refinements.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RobustLoss {
    /// Plain least squares.
    Trivial,
    /// Quadratic up to the scale, linear beyond.
    #[default]
    Huber,
    /// `s²·ln(1 + r²/s²)`.
    Cauchy,
}

/// Parameters of [`solve_pnp_ransac`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PnpParams {
    /// Inlier threshold on the reprojection error, pixels.
    pub threshold_px: f64,
    /// Probability of having drawn at least one all-inlier sample when stopping.
    pub confidence: f64,
    pub min_iterations: usize,
    pub max_iterations: usize,
    /// Local optimisation (LO-RANSAC) whenever a new best pose is found.
    pub local_optimization: bool,
    /// Fewer inliers than this is a failure.
    pub min_inliers: usize,
    /// Final LM refinement on all inliers.
    pub refine: bool,
    /// Robust loss of the final refinement.
    pub loss: RobustLoss,
    /// Scale of the robust loss, pixels.
    pub loss_scale_px: f64,
    /// Side of the image cells of coverage scoring, pixels; 0 turns it off. When on, a
    /// hypothesis is ranked by the number of distinct cells its inliers occupy (ties: inlier
    /// count, then MSAC), not by its inlier count: a wrong pose that explains one rigidly
    /// displaced patch of matches gathers its support in a few cells, the true pose's spreads
    /// over the image.
    pub coverage_cell_px: f64,
    /// With coverage scoring and prior depths ([`Guidance::prior_depths`]): an inlier
    /// counts only if its depth is within this share of the prior's (affinely mapped); 0: off.
    pub prior_tolerance: f64,
    /// The focal length (px) that the pixel sizes above are meant for: [`PnpParams::for_camera`]
    /// scales `threshold_px`, `loss_scale_px` and `coverage_cell_px` by fx / this when fx is
    /// longer, so that they keep their angle (8 px at 525 px ≈ 0.87°): a map's metric error
    /// projects to more pixels at a longer focal length. They are never scaled down: the
    /// matcher's own pixel error does not shrink with a shorter one. 0: as they are.
    pub reference_focal_px: f64,
    /// Seed of the random sampling: a solve is deterministic for a given seed. Not a
    /// parameter of the file: the localizer sets it from its own `seed`.
    #[serde(skip)]
    pub seed: u64,
}

impl PnpParams {
    /// These parameters for a camera of focal length `fx` (see `reference_focal_px`).
    pub fn for_camera(&self, fx: f64) -> PnpParams {
        let scale = fx / self.reference_focal_px;
        if !(self.reference_focal_px > 0.0 && scale.is_finite() && scale > 1.0) {
            return self.clone();
        }
        PnpParams {
            threshold_px: self.threshold_px * scale,
            loss_scale_px: self.loss_scale_px * scale,
            coverage_cell_px: self.coverage_cell_px * scale,
            ..self.clone()
        }
    }
}

impl Default for PnpParams {
    fn default() -> Self {
        Self {
            threshold_px: 8.0,
            confidence: 0.9999,
            min_iterations: 100,
            max_iterations: 10_000,
            local_optimization: true,
            min_inliers: 6,
            refine: true,
            loss: RobustLoss::Huber,
            loss_scale_px: 2.0,
            coverage_cell_px: 32.0,
            prior_tolerance: 0.2,
            reference_focal_px: 525.0,
            seed: 0,
        }
    }
}

/// The correspondences of one robust PnP solve: pixel `i` of the image of `intrinsics` is
/// putatively the projection of map point `i`.
#[derive(Clone, Copy, Debug)]
pub struct Problem<'a> {
    pub intrinsics: &'a Intrinsics,
    pub pixels: &'a [Point2<f64>],
    pub points: &'a [Point3<f64>],
}

/// Evidence about a camera-to-map pose beyond the correspondences, e.g. how the map rendered at
/// it agrees with a dense depth prior, counted over image cells.
/// Verifies a pose against evidence beyond the correspondences; `Sync`, since the candidates of
/// one check are verified in parallel.
pub trait PoseVerifier: Sync {
    fn verify(&self, pose: &Isometry3<f64>) -> Agreement;
}

/// How a pose agrees with the evidence of a [`PoseVerifier`], over the image's cells.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Agreement {
    /// Cells where the pose agrees with the evidence.
    pub agreeing: usize,
    /// Cells where the pose can be checked at all (the map is seen there and the prior known).
    pub in_view: usize,
    /// All cells of the image.
    pub cells: usize,
}

impl Agreement {
    /// Share of the whole image that agrees: how candidates of one frame are compared (a pose
    /// that explains more of the image is better).
    pub fn share(&self) -> f64 {
        self.agreeing as f64 / self.cells.max(1) as f64
    }

    /// Share of what can be checked that agrees, counting at least `min_view` of the image as
    /// checkable: how a pose is accepted whatever share of the view the map covers (a small map
    /// or one seen from its edge), without trusting a pose that sees almost nothing of it.
    pub fn in_view_share(&self, min_view: f64) -> f64 {
        let floor = (min_view * self.cells as f64).max(1.0);
        self.agreeing as f64 / (self.in_view as f64).max(floor)
    }
}

/// A verifier and how [`solve_pnp_ransac`] uses it: it keeps the `candidates` best
/// distinct hypotheses by coverage, draws at least `min_iterations`, and returns the one with the
/// most agreement + `coverage_weight`·(cells / the most cells of any candidate) among those
/// covering at least `min_support_share` of the most cells.
#[derive(Clone, Copy)]
pub struct Verification<'a> {
    pub verifier: &'a dyn PoseVerifier,
    pub candidates: usize,
    pub coverage_weight: f64,
    /// A candidate covering fewer cells than this share of the most cells of any candidate is
    /// not chosen by its agreement, nor does it make the evidence trusted: a minimal sample of
    /// wrong matches explains itself and a few more, and a prior agrees with such a pose as
    /// much as with the true one often enough (where it is weak, as at close range).
    pub min_support_share: f64,
    /// Hypotheses drawn at least (the verifier can only choose one that was drawn); the pool is
    /// verified then and every `check_every` samples after, until a candidate's in-view agreement
    /// ([`Agreement::in_view_share`] with `min_view`) reaches `accept`, the choice stays the
    /// same over `settle_checks` verifications in a row, or `max_iterations` (if more than
    /// PnP's own) were drawn.
    pub min_iterations: usize,
    /// After `min_iterations`, the pool is verified again every this many hypotheses.
    pub check_every: usize,
    pub accept: f64,
    pub min_view: f64,
    pub settle_checks: usize,
    pub max_iterations: usize,
    /// Below this in-view agreement of every candidate the evidence is not trusted for the
    /// frame: the pose is chosen on geometry alone (coverage cost), as without a verifier.
    pub min_trust: f64,
    /// When plain RANSAC stops and the best hypothesis is not trusted by the verifier but
    /// explains at least this share of the correspondences, it is taken on geometry alone
    /// (0: off).
    pub settle_support: f64,
}

/// What guides [`solve_pnp_ransac`] beyond the correspondences; each part optional.
#[derive(Clone, Copy, Default)]
pub struct Guidance<'a> {
    /// One per correspondence, higher = more likely correct: PROSAC sampling.
    pub scores: Option<&'a [f32]>,
    /// Prior coordinate per correspondence, affine in `prior_space` (NaN where unknown).
    pub prior_depths: Option<&'a [f64]>,
    pub prior_space: PriorSpace,
    pub verification: Option<Verification<'a>>,
    /// Poses outside this gate are never scored (see [`PoseGate`]).
    pub gate: Option<&'a PoseGate>,
}

/// Result of [`solve_pnp_ransac`].
#[derive(Clone, Debug, PartialEq)]
pub struct PnpSolution {
    /// Camera-to-map pose: `x_map = pose * x_cam`.
    pub pose: Isometry3<f64>,
    /// One flag per input correspondence.
    pub inliers: Vec<bool>,
    pub num_inliers: usize,
    /// Hypothesis samples drawn.
    pub iterations: usize,
    /// Root-mean-square of the 2D reprojection error norm over the inliers, pixels
    /// (`√(Σ|r|²/n)`; ≈ √2·σ for σ px of noise per axis).
    pub rmse_px: f64,
    /// 6×6 covariance of `pose`, order `(x, y, z, rot x, rot y, rot z)`, see the module doc.
    pub covariance: nalgebra::Matrix6<f64>,
    /// With a verifier: the pool's other supported candidates (camera-to-map), best choice
    /// first, which evidence beyond the solved correspondences can still prefer.
    pub alternatives: Vec<Isometry3<f64>>,
}

/// Map-to-camera rigid transform `x_cam = rotation · x_map + translation`, the inverse of the
/// camera-to-map pose. `rotation` is orthonormal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapToCamera {
    pub rotation: Matrix3<f64>,
    pub translation: Vector3<f64>,
}

impl MapToCamera {
    pub fn identity() -> Self {
        Self { rotation: Matrix3::identity(), translation: Vector3::zeros() }
    }

    /// From a camera-to-map pose.
    pub fn from_camera_to_map(pose: &Isometry3<f64>) -> Self {
        let inv = pose.inverse();
        Self { rotation: inv.rotation.to_rotation_matrix().into_inner(), translation: inv.translation.vector }
    }

    /// The camera-to-map pose `x_map = pose * x_cam`.
    pub fn to_camera_to_map(&self) -> Isometry3<f64> {
        // Shepperd's method then normalisation absorbs the rounding LM updates accumulate.
        let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(self.rotation));
        let map_to_cam = Isometry3::from_parts(Translation3::from(self.translation), q);
        map_to_cam.inverse()
    }

    #[inline(always)]
    pub fn transform(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    pub fn transform_point(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.transform(&p.coords))
    }

    pub(crate) fn is_finite(&self) -> bool {
        self.rotation.iter().chain(self.translation.iter()).all(|v| v.is_finite())
    }
}

#[cfg(test)]
mod tests;
