//! Everything the learned rejector consumes for one frame, built in Rust (never inside the
//! network graph): eq. (9) features, the local and global graphs with their θ, and — for
//! training — the ground-truth labels. The same code builds training samples (`angle-i2p
//! export`) and inference inputs, so both sides see identical numbers.

use nalgebra::Point3;

pub use super::features::IndexedMap;
use super::features::{features, map_normals, FEATURE_DIM};
use super::graph::{build_graphs, Graphs};
use super::network_params::{KeypointRanking, NetworkParams};
use super::{FrameGeometry, Rejector, SpectralRejector};

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

/// The values of one input tensor, in the element type the network declares.
#[derive(Clone, Debug, PartialEq)]
pub enum TensorValues {
    F32(Vec<f32>),
    I64(Vec<i64>),
}

/// One named input of the network: row-major values and their shape.
#[derive(Clone, Debug, PartialEq)]
pub struct InputTensor {
    pub name: &'static str,
    pub shape: Vec<usize>,
    pub values: TensorValues,
}

impl NetworkInputs {
    /// The network's input tensors (N correspondences, V local nodes of K, M keypoints): the one
    /// definition of the layout, which the ONNX run feeds and `export` writes (`NAME.npy`) for
    /// training.
    pub fn tensors(&self) -> Vec<InputTensor> {
        let n = self.features.len();
        let g = &self.graphs;
        let m = g.global_index.len();
        let index = |v: &[u32]| TensorValues::I64(v.iter().map(|&i| i as i64).collect());
        let f32s = |v: &[f32]| TensorValues::F32(v.to_vec());
        let tensor = |name, shape: &[usize], values| InputTensor { name, shape: shape.to_vec(), values };
        vec![
            tensor("features", &[n, FEATURE_DIM], TensorValues::F32(self.features.iter().flatten().copied().collect())),
            tensor("local_index", &[g.nodes, g.neighbours], index(&g.local_index)),
            tensor("local_theta", &[g.nodes, g.neighbours, g.neighbours], f32s(&g.local_theta)),
            tensor("global_index", &[m], index(&g.global_index)),
            tensor("global_theta", &[m, m], f32s(&g.global_theta)),
            tensor("cross_theta", &[n, m], f32s(&g.cross_theta)),
            tensor("matcher_score", &[n], f32s(&self.matcher_scores)),
        ]
    }
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
            &params.graph,
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
