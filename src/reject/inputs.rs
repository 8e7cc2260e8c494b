//! Everything the learned rejector consumes for one frame, built in Rust (never inside the
//! network graph): eq. (9) features, the local and global graphs with their θ, and — for
//! training — the ground-truth labels. The same code builds training samples (`angle-i2p
//! export`) and inference inputs, so both sides see identical numbers.

use nalgebra::Point3;

use super::features::{features, map_normals, FEATURE_DIM};
use super::graph::{build_graphs, GraphParams, Graphs};
use super::{FrameGeometry, Rejector, SpectralRejector};
use crate::geometry::PointIndex;

/// The map, indexed once for normals.
pub struct IndexedMap {
    pub points: Vec<Point3<f32>>,
    pub index: PointIndex,
}

impl IndexedMap {
    pub fn new(points: Vec<Point3<f32>>) -> Self {
        let index = PointIndex::new(&points);
        Self { points, index }
    }
}

/// One frame's network inputs.
#[derive(Clone, Debug, Default)]
pub struct NetworkInputs {
    /// N × 24, row-major.
    pub features: Vec<[f32; FEATURE_DIM]>,
    pub graphs: Graphs,
    /// Spectral consistency score per correspondence (also ranks the global keypoints).
    pub spectral_scores: Vec<f32>,
}

/// Builds the inputs. Correspondences without prior depth get their map point as image point
/// in the graphs (their θ rows then carry no information rather than a wrong one).
pub fn build_inputs(
    geometry: &FrameGeometry,
    map: Option<&IndexedMap>,
    spectral: &mut SpectralRejector,
    graph: &GraphParams,
) -> NetworkInputs {
    let spectral_scores = spectral.reject(geometry).map(|r| r.scores).unwrap_or_else(|_| vec![0.0; geometry.len()]);
    let n_map = match map {
        Some(m) => map_normals(&m.index, &m.points, geometry),
        None => vec![nalgebra::Vector3::zeros(); geometry.len()],
    };
    let image: Vec<Point3<f64>> = (0..geometry.len())
        .map(|i| match geometry.image_points.get(i) {
            Some(p) if p.coords.iter().all(|v| v.is_finite()) => *p,
            _ => geometry.map_points[i],
        })
        .collect();
    NetworkInputs {
        features: features(geometry, &geometry.image_normals, &n_map),
        graphs: build_graphs(&image, &geometry.map_points, &spectral_scores, graph),
        spectral_scores,
    }
}
