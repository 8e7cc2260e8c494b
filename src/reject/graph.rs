//! The learned rejector's graphs (paper section 3.3): a local graph of nodes sampled from the
//! map points, each holding its K nearest correspondences, and a global graph of M keypoint
//! correspondences; the angle consistency θ (eq. 7) of every pair inside each graph and between
//! every correspondence and every keypoint. The attention logits are multiplied by these θ.
//!
//! Keypoints: the paper takes P2-Net's top-M detections; here the M correspondences with the
//! highest spectral consistency score, which need no detector and rank likely inliers first.

use nalgebra::{Point3, Vector3};

use crate::consistency::{angle_consistency, ConsistencyMatrix};
use crate::geometry::{centroid, PointIndex};

/// Graph sizes and the θ sensitivity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GraphParams {
    /// K: correspondences per local node.
    pub neighbours: usize,
    /// M: global keypoints.
    pub keypoints: usize,
    /// σ_d of eq. (7).
    pub sigma_d: f64,
}

impl Default for GraphParams {
    fn default() -> Self {
        Self { neighbours: 32, keypoints: 100, sigma_d: 0.2 }
    }
}

/// Both graphs of one frame, flat row-major arrays ready for the network.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Graphs {
    /// V nodes × K correspondence indices.
    pub local_index: Vec<u32>,
    pub nodes: usize,
    pub neighbours: usize,
    /// V × K × K θ inside each node's group.
    pub local_theta: Vec<f32>,
    /// M keypoint indices.
    pub global_index: Vec<u32>,
    /// M × M θ among the keypoints.
    pub global_theta: Vec<f32>,
    /// N × M θ between every correspondence and every keypoint.
    pub cross_theta: Vec<f32>,
}

/// Builds the graphs over `image` (o_i) and `map` (q_i) points; `scores` rank the keypoints.
/// Image points must be finite (give correspondences without prior depth any point; their θ
/// rows are then uninformative, not wrong-by-construction).
pub fn build_graphs(image: &[Point3<f64>], map: &[Point3<f64>], scores: &[f32], params: &GraphParams) -> Graphs {
    let n = image.len().min(map.len()).min(scores.len());
    if n == 0 {
        return Graphs::default();
    }
    let k = params.neighbours.min(n);
    let m = params.keypoints.min(n);

    // Local graph: nodes by farthest-point sampling of the map points, ~2 nodes per K points.
    let node_count = (2 * n).div_ceil(k).min(n);
    let seeds = farthest_point_sampling(&map[..n], node_count);
    let cloud: Vec<Point3<f32>> = map[..n].iter().map(|p| p.cast()).collect();
    let index = PointIndex::new(&cloud);
    let mut local_index = Vec::with_capacity(node_count * k);
    let mut local_theta = Vec::with_capacity(node_count * k * k);
    let mut theta = ConsistencyMatrix::default();
    let (mut group_image, mut group_map) = (Vec::with_capacity(k), Vec::with_capacity(k));
    for &seed in &seeds {
        let group = index.nearest(&cloud[seed], k);
        group_image.clear();
        group_map.clear();
        group_image.extend(group.iter().map(|&i| image[i]));
        group_map.extend(group.iter().map(|&i| map[i]));
        angle_consistency(&group_image, &group_map, None, params.sigma_d, &mut theta);
        local_index.extend(group.iter().map(|&i| i as u32));
        local_theta.extend_from_slice(&theta.values);
    }

    // Global graph: the M best-scored correspondences.
    let global = crate::reject::top_k(&scores[..n], m);
    let key_image: Vec<_> = global.iter().map(|&i| image[i]).collect();
    let key_map: Vec<_> = global.iter().map(|&i| map[i]).collect();
    angle_consistency(&key_image, &key_map, None, params.sigma_d, &mut theta);
    let global_theta = theta.values.clone();

    // Cross θ: eq. (7) for (correspondence, keypoint) pairs, both clouds centred on the
    // keypoints' centroids.
    let unit = |p: &Point3<f64>, c: &Point3<f64>| -> Vector3<f64> {
        let v = p - c;
        let norm = v.norm();
        if norm > 1e-12 {
            v / norm
        } else {
            Vector3::zeros()
        }
    };
    let (ci, cp) = (centroid(&key_image), centroid(&key_map));
    let key_unit_image: Vec<_> = key_image.iter().map(|p| unit(p, &ci)).collect();
    let key_unit_map: Vec<_> = key_map.iter().map(|p| unit(p, &cp)).collect();
    let inv_sigma2 = 1.0 / (params.sigma_d * params.sigma_d);
    let mut cross_theta = Vec::with_capacity(n * m);
    for i in 0..n {
        let (ui, up) = (unit(&image[i], &ci), unit(&map[i], &cp));
        for j in 0..m {
            let delta = ui.dot(&key_unit_image[j]).abs() - up.dot(&key_unit_map[j]).abs();
            cross_theta.push((1.0 - delta * delta * inv_sigma2).max(0.0) as f32);
        }
    }
    Graphs {
        local_index,
        nodes: seeds.len(),
        neighbours: k,
        local_theta,
        global_index: global.iter().map(|&i| i as u32).collect(),
        global_theta,
        cross_theta,
    }
}

/// `count` indices spread over `points`: start from the point farthest from the centroid, then
/// repeatedly take the point farthest from those taken.
pub fn farthest_point_sampling(points: &[Point3<f64>], count: usize) -> Vec<usize> {
    let count = count.min(points.len());
    if count == 0 {
        return Vec::new();
    }
    let c = centroid(points);
    let first =
        (0..points.len()).max_by(|&a, &b| (points[a] - c).norm_squared().total_cmp(&(points[b] - c).norm_squared()));
    let mut chosen = vec![first.unwrap_or(0)];
    let mut distance: Vec<f64> = points.iter().map(|p| (p - points[chosen[0]]).norm_squared()).collect();
    while chosen.len() < count {
        let next = (0..points.len()).max_by(|&a, &b| distance[a].total_cmp(&distance[b])).unwrap_or(0);
        chosen.push(next);
        for (d, p) in distance.iter_mut().zip(points) {
            *d = d.min((p - points[next]).norm_squared());
        }
    }
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: usize) -> Vec<Point3<f64>> {
        (0..n).map(|i| Point3::new((i % 10) as f64 * 0.1, (i / 10) as f64 * 0.1, 1.0 + (i % 7) as f64 * 0.05)).collect()
    }

    #[test]
    fn graph_shapes_and_indices() {
        let map = grid(150);
        let image: Vec<_> = map.iter().map(|p| Point3::new(p.y, -p.x, p.z) * 0.5).collect();
        let scores: Vec<f32> = (0..150).map(|i| i as f32).collect();
        let g = build_graphs(&image, &map, &scores, &GraphParams::default());
        assert_eq!(g.neighbours, 32);
        assert_eq!(g.nodes, 10); // ceil(2·150/32)
        assert_eq!(g.local_index.len(), g.nodes * 32);
        assert_eq!(g.local_theta.len(), g.nodes * 32 * 32);
        assert!(g.local_index.iter().all(|&i| i < 150));
        assert_eq!(g.global_index[0], 149, "best score first");
        assert_eq!(g.global_theta.len(), 100 * 100);
        assert_eq!(g.cross_theta.len(), 150 * 100);
        // A rigid, scaled copy is consistent everywhere (off the diagonal).
        assert!(g.cross_theta.iter().all(|&t| t > 0.999));
    }

    #[test]
    fn small_frames_shrink_the_graphs() {
        let map = grid(5);
        let g = build_graphs(&map, &map, &[1.0; 5], &GraphParams::default());
        assert_eq!((g.neighbours, g.global_index.len()), (5, 5));
        assert!(build_graphs(&[], &[], &[], &GraphParams::default()).local_index.is_empty());
    }

    #[test]
    fn farthest_point_sampling_spreads_out() {
        let pts = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.1, 0.0, 0.0),
            Point3::new(5.0, 0.0, 0.0),
            Point3::new(-5.0, 0.0, 0.0),
        ];
        let chosen = farthest_point_sampling(&pts, 2);
        assert!(chosen.contains(&2) && chosen.contains(&3), "{chosen:?}");
    }
}
