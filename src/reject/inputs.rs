//! Everything the learned rejector consumes for one frame, built in Rust (never inside the
//! network graph): eq. (9) features, the local and global graphs with their θ, and — for
//! training — the ground-truth labels. The same code builds training samples (`angle-i2p
//! export`) and inference inputs, so both sides see identical numbers.

use nalgebra::Point3;

use super::features::{features, map_normals, FEATURE_DIM, MAP_NORMAL_NEIGHBOURS};
use super::graph::{build_graphs, Graphs};
use super::network::{KeypointRanking, NetworkParams};
use super::{FrameGeometry, Rejector, SpectralRejector};

/// The map, indexed once, with the normal of each map point a frame uses (PCA over its
/// [`MAP_NORMAL_NEIGHBOURS`] nearest, sign left to each frame) computed on first use and cached.
pub type IndexedMap = crate::map_index::MapIndex;
const _: () = assert!(MAP_NORMAL_NEIGHBOURS == crate::map_index::NORMAL_NEIGHBOURS);

/// One frame's network inputs.
#[derive(Clone, Debug, Default)]
pub struct NetworkInputs {
    /// N × 24, row-major.
    pub features: Vec<[f32; FEATURE_DIM]>,
    pub graphs: Graphs,
    /// Spectral consistency score per correspondence (also ranks the global keypoints).
    pub spectral_scores: Vec<f32>,
    /// The matcher's confidence per correspondence (an input of models trained with it).
    pub matcher_scores: Vec<f32>,
}

/// Builds the inputs. Correspondences without prior depth get their map point as image point
/// in the graphs (their θ rows then carry no information rather than a wrong one).
pub fn build_inputs(
    geometry: &FrameGeometry,
    map: Option<&IndexedMap>,
    spectral: &mut SpectralRejector,
    params: &NetworkParams,
) -> NetworkInputs {
    let spectral_scores = spectral.reject(geometry).map(|r| r.scores).unwrap_or_else(|_| vec![0.0; geometry.len()]);
    let n_map = match map {
        Some(m) => map_normals(m, geometry),
        None => vec![nalgebra::Vector3::zeros(); geometry.len()],
    };
    let image: Vec<Point3<f64>> = (0..geometry.len())
        .map(|i| match geometry.image_points.get(i) {
            Some(p) if p.coords.iter().all(|v| v.is_finite()) => *p,
            _ => geometry.map_points[i],
        })
        .collect();
    NetworkInputs {
        features: features(geometry, &geometry.image_normals, &n_map, params.align_prior),
        graphs: build_graphs(
            &image,
            &geometry.map_points,
            &keypoint_ranks(&spectral_scores, geometry, params),
            &params.graph(),
        ),
        spectral_scores,
        matcher_scores: geometry.matcher_scores.clone(),
    }
}

/// The scores that pick the keypoints ([`KeypointRanking`]). A matcher that publishes no
/// confidence (all zero) leaves the spectral order.
fn keypoint_ranks(spectral: &[f32], geometry: &FrameGeometry, params: &NetworkParams) -> Vec<f32> {
    match params.keypoint_ranking {
        KeypointRanking::Spectral => spectral.to_vec(),
        KeypointRanking::SpectralMatcher => spectral
            .iter()
            .zip(&geometry.matcher_scores)
            .map(|(&s, &m)| s * (if m.is_finite() { m.clamp(0.0, 1.0) } else { 0.0 } + 1e-3))
            .collect(),
    }
}
