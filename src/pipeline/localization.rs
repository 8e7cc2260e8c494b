//! What the localizer returns for one frame: the pose and what it is made of, per-stage
//! timings, and why a frame has no pose.

use nalgebra::{Isometry3, Matrix6};
use serde::{Deserialize, Serialize};

use super::cascade::FastPathCheck;
use super::track::{PredictionSource, TrackState};
use crate::consistency::ScaleShift;
use crate::frame::{Correspondence, Frame, Stamp};
use crate::pnp::PnpError;
use crate::reject::RejectError;

/// How outliers are rejected before PnP.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// No rejection: LO-RANSAC on the raw correspondences (the baseline row).
    Ransac,
    /// Spectral scoring of the pairwise consistency matrix, then score-ordered LO-RANSAC.
    Consistency,
    /// The learned Angle-I2P network (ONNX Runtime), then score-ordered LO-RANSAC.
    #[default]
    #[value(name = "angle-i2p")]
    #[serde(rename = "angle-i2p")]
    AngleI2p,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Ransac => "ransac",
            Method::Consistency => "consistency",
            Method::AngleI2p => "angle-i2p",
        }
    }
}

/// Wall-clock time of each stage, milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StageTimings {
    /// The cascade's budgeted LO-RANSAC (the whole PnP when it settles the frame).
    pub fast_path_ms: f64,
    pub geometry_ms: f64,
    pub reject_ms: f64,
    pub pnp_ms: f64,
    pub total_ms: f64,
}

/// Why a frame got no pose.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Failure {
    #[error("the frame has no correspondences")]
    NoCorrespondences,
    #[error("too few correspondences: {have} < {need}")]
    TooFewCorrespondences { have: usize, need: usize },
    #[error("invalid camera intrinsics")]
    InvalidIntrinsics,
    #[error("correspondence {index} is not finite")]
    NonFinite { index: usize },
    #[error("rejection failed: {0}")]
    Rejection(RejectError),
    #[error("PnP failed: {0}")]
    Pnp(PnpError),
    /// A pose was found but is not published: neither its support among every match is
    /// meaningful (log₁₀ NFA above the publishing level) nor does the dense prior confirm it
    /// (its agreement is under `verify.min_trust`, or the support is too weak for any prior to
    /// confirm: log₁₀ NFA above `cascade.prior_nfa`'s, `prior_level`).
    #[error("pose not sure enough to publish: log10 NFA {log10_nfa:.1} among every match, prior agreement {}{}",
        prior_quality.map_or_else(|| "unknown".to_string(), |q| format!("{q:.2}")),
        prior_level.map_or_else(String::new, |l| format!(", too weak a support for the prior to confirm (above {l:.1})")))]
    Unsure { log10_nfa: f64, prior_quality: Option<f64>, prior_level: Option<f64> },
    /// A pose was found whose support is not meaningful among every match and which the prior
    /// confirms, but the track's prediction, which has proved itself, puts the camera elsewhere
    /// ([`super::track`]).
    #[error(
        "pose not sure enough to publish: log10 NFA {log10_nfa:.1} among every match, and {angle_deg:.1}° from \
        the track's prediction (agreement within {gate_deg:.1}°)"
    )]
    OffTrack { log10_nfa: f64, angle_deg: f64, gate_deg: f64 },
    /// The pose gate (`/initialpose`) is contradicted: a pose outside it is sure among every
    /// match and surer than the best inside it (if any), which is not published ([`super::gate`]).
    #[error("the pose gate is contradicted: a pose outside it has log10 NFA {outside_log10_nfa:.1} among every match, \
        the best inside {}", inside_log10_nfa.map_or_else(|| "none".to_string(), |n| format!("{n:.1}")))]
    GateContradicted { outside_log10_nfa: f64, inside_log10_nfa: Option<f64> },
}

impl Failure {
    /// A short stable key for counting failures in diagnostics.
    pub fn key(&self) -> &'static str {
        match self {
            Failure::NoCorrespondences => "no_correspondences",
            Failure::TooFewCorrespondences { .. } => "too_few_correspondences",
            Failure::InvalidIntrinsics => "invalid_intrinsics",
            Failure::NonFinite { .. } => "non_finite",
            Failure::Rejection(_) => "rejection",
            Failure::Pnp(_) => "pnp",
            Failure::Unsure { .. } => "unsure",
            Failure::OffTrack { .. } => "off_track",
            Failure::GateContradicted { .. } => "gate_contradicted",
        }
    }
}

/// The result for one frame.
#[derive(Clone, Debug)]
pub struct Localization {
    pub stamp: Stamp,
    pub camera_frame_id: String,
    pub map_frame_id: String,
    pub method: Method,
    /// Camera-to-map pose of the camera's optical frame.
    pub pose: Option<Isometry3<f64>>,
    /// 6×6 covariance, (x, y, z, rot x, rot y, rot z).
    pub covariance: Option<Matrix6<f64>>,
    /// The correspondences kept, `score` = inlier score. With rejection: the rejector's kept
    /// set, best first; without: the RANSAC inliers.
    pub kept: Vec<Correspondence>,
    /// PnP inliers (among the correspondences PnP saw).
    pub num_inliers: usize,
    /// Hypotheses PnP drew (the fast path's and the full path's).
    pub pnp_iterations: usize,
    pub scale_shift: Option<ScaleShift>,
    /// How far the depth prior can be trusted on this frame: the share of what the map covers
    /// in view at the returned pose where the rendered map agrees with the prior (up to the
    /// prior's unknown affine map), in [0, 1]. `None` without a prior, a map or a pose.
    pub prior_quality: Option<f64>,
    /// Whether the cascade's budgeted LO-RANSAC settled the frame (no rejection ran), and what
    /// it measured when it did not.
    pub fast_path: bool,
    /// Whether the track's prediction confirmed the fast path's pose (which its support alone
    /// did not settle).
    pub fast_path_on_track: bool,
    pub fast_path_check: Option<FastPathCheck>,
    /// Whether the pose came from the cascade's last resort (plain LO-RANSAC on every
    /// correspondence, after the rejection-guided PnP found no consensus).
    pub last_resort: bool,
    /// How sure the pose is: log₁₀ of its number of false alarms among every correspondence of
    /// the frame ([`super::significance`]; ≤ 0: fewer than one pose so well supported is expected
    /// from wrong matches alone). `None` without a pose.
    pub log10_nfa: Option<f64>,
    /// Whether the pose the rejector's order found was not sure enough
    /// ([`super::CascadeParams::confirm_nfa`]) and a plain search over every match checked it.
    pub confirm_search: bool,
    /// With a pose gate: log₁₀ NFA of the surest pose the plain search found outside it (its
    /// poses are never published; a sure one contradicts the gate, [`super::gate`]).
    pub outside_gate_log10_nfa: Option<f64>,
    /// Robust-estimation passes run on the frame (at most two): the plain search over every
    /// match, however many stages it ran (the fast path's, then confirming or rescuing), and
    /// the search guided by the rejector on the kept matches.
    pub robust_passes: usize,
    /// How the frame stands to the track (`None` with tracking off: frames alone).
    pub track: Option<TrackState>,
    /// What predicted the frame's pose (`None`: no prediction, or tracking off).
    pub prediction: Option<PredictionSource>,
    pub timings: StageTimings,
    pub failure: Option<Failure>,
}

impl Localization {
    /// A frame's result before any step ran: no pose, nothing kept, no failure.
    pub fn nothing_yet(frame: &Frame, method: Method) -> Self {
        Self {
            stamp: frame.stamp,
            camera_frame_id: frame.camera_frame_id.clone(),
            map_frame_id: frame.map_frame_id.clone(),
            method,
            pose: None,
            covariance: None,
            kept: Vec::new(),
            num_inliers: 0,
            pnp_iterations: 0,
            scale_shift: None,
            prior_quality: None,
            fast_path: false,
            fast_path_on_track: false,
            fast_path_check: None,
            last_resort: false,
            log10_nfa: None,
            confirm_search: false,
            outside_gate_log10_nfa: None,
            robust_passes: 0,
            track: None,
            prediction: None,
            timings: StageTimings::default(),
            failure: None,
        }
    }
}
