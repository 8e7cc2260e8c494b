//! The core's parameters: everything [`super::Localizer`] is configured with, and nothing of
//! the edges (topics, the node, input limits: [`crate::params::AppParams`] holds those beside
//! it), so the core depends on no edge.

use serde::{Deserialize, Serialize};

use super::{CascadeParams, CovarianceParams, FinalRefine, Method, TrackingParams};
use crate::consistency::ScaleShiftParams;
use crate::geometry::DepthKind;
use crate::pnp::PnpParams;
use crate::reject::network::NetworkParams;
use crate::reject::SpectralParams;
use crate::verify::VerifyParams;

/// What the localizer (the pure core) is configured with.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LocalizerParams {
    /// Outlier rejection before PnP.
    pub method: Method,
    /// The fast path: a budgeted LO-RANSAC that settles easy frames before any rejection.
    pub cascade: CascadeParams,
    /// What the prior's values mean: depth, inverse depth or affine-invariant disparity.
    pub depth_kind: DepthKind,
    /// Scale-and-shift alignment of the prior.
    pub align: ScaleShiftParams,
    /// The training-free spectral rejector.
    pub spectral: SpectralParams,
    /// The learned rejector (method `angle-i2p`).
    pub network: NetworkParams,
    /// Robust PnP.
    pub pnp: PnpParams,
    /// Verification of PnP's best hypotheses against the dense depth prior.
    pub verify: VerifyParams,
    /// Last refinement on every correspondence agreeing with the pose.
    pub final_refine: FinalRefine,
    /// What the published covariance counts beside the inliers' pixel noise: the map's own error.
    pub covariance: CovarianceParams,
    /// Frames as a stream: the poses published before predict the next ([`super::track`]).
    pub tracking: TrackingParams,
    /// Seed of every random choice (results are reproducible).
    pub seed: u64,
}
