//! The learned rejector's graphs (paper section 3.3): a local graph of nodes sampled from the
//! map points, each holding its K nearest correspondences, and a global graph of M keypoint
//! correspondences; the angle consistency θ (eq. 7) of every pair inside each graph and between
//! every correspondence and every keypoint. The attention logits are multiplied by these θ.
//!
//! Keypoints: the paper takes P2-Net's top-M detections; here the M correspondences ranked
//! first by the caller's scores (see `network::KeypointRanking`: the spectral consistency score
//! times the matcher's confidence by default), which need no detector.

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::consistency::{angle_consistency, distance_consistency, ConsistencyMatrix, PairMetric};
use crate::geometry::{centroid, PointIndex};

/// Graph sizes and the θ sensitivity: the `network.neighbours`, `network.keypoints`,
/// `network.theta` and `network.sigma_d` parameters ([`super::network_params::NetworkParams`]
/// holds this struct flattened, so the keys sit directly under `network`). They must match the
/// training export.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct GraphParams {
    /// K: correspondences per local node.
    pub neighbours: usize,
    /// M: global keypoints.
    pub keypoints: usize,
    /// The graphs' θ: `angle` (eq. 5-7) or `distance` (the ablation).
    pub theta: PairMetric,
    /// σ_d of eq. (7) (angle θ).
    pub sigma_d: f64,
    /// Distance θ tolerance: `sigma_abs + sigma_rel·length` (m). Fixed, not parameters: only the
    /// distance ablation reads them, and its models were exported with these values.
    #[serde(skip)]
    pub sigma_abs: f64,
    #[serde(skip)]
    pub sigma_rel: f64,
}

impl Default for GraphParams {
    fn default() -> Self {
        Self { neighbours: 32, keypoints: 100, theta: PairMetric::Angle, sigma_d: 0.2, sigma_abs: 0.05, sigma_rel: 0.1 }
    }
}

impl GraphParams {
    /// θ among all pairs of `image`/`map`, into `out`.
    fn pair_theta(&self, image: &[Point3<f64>], map: &[Point3<f64>], out: &mut ConsistencyMatrix) {
        match self.theta {
            PairMetric::Angle => angle_consistency(image, map, None, self.sigma_d, out),
            PairMetric::Distance => distance_consistency(image, map, self.sigma_abs, self.sigma_rel, out),
        }
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

impl Graphs {
    /// Empties every array, keeping the allocations for the next frame.
    pub fn clear(&mut self) {
        self.local_index.clear();
        self.local_theta.clear();
        self.global_index.clear();
        self.global_theta.clear();
        self.cross_theta.clear();
        self.nodes = 0;
        self.neighbours = 0;
    }
}

/// What building the graphs works in besides its output, kept between frames so that a frame
/// allocates none of it again: the local graph's and the global one's apart, as they are built
/// side by side.
#[derive(Clone, Debug, Default)]
pub struct GraphScratch {
    local: LocalScratch,
    keys: KeyScratch,
}

#[derive(Clone, Debug, Default)]
struct LocalScratch {
    cloud: Vec<Point3<f32>>,
    seeds: Vec<usize>,
    farthest: Vec<f64>,
    theta: ConsistencyMatrix,
    group_image: Vec<Point3<f64>>,
    group_map: Vec<Point3<f64>>,
}

#[derive(Clone, Debug, Default)]
struct KeyScratch {
    theta: ConsistencyMatrix,
    key_image: Vec<Point3<f64>>,
    key_map: Vec<Point3<f64>>,
    key_unit_image: Vec<Vector3<f64>>,
    key_unit_map: Vec<Vector3<f64>>,
}

/// Builds the graphs over `image` (o_i) and `map` (q_i) points; `scores` rank the keypoints.
/// Image points must be finite (give correspondences without prior depth any point; their θ
/// rows are then uninformative, not wrong-by-construction).
pub fn build_graphs(image: &[Point3<f64>], map: &[Point3<f64>], scores: &[f32], params: &GraphParams) -> Graphs {
    let mut graphs = Graphs::default();
    build_graphs_into(&mut graphs, image, map, scores, params, &mut GraphScratch::default());
    graphs
}

/// [`build_graphs`] into `graphs`, reusing its buffers and `scratch`'s. The local graph and the
/// global one are built side by side (the same values as one after the other).
pub fn build_graphs_into(
    graphs: &mut Graphs,
    image: &[Point3<f64>],
    map: &[Point3<f64>],
    scores: &[f32],
    params: &GraphParams,
    scratch: &mut GraphScratch,
) {
    let n = image.len().min(map.len()).min(scores.len());
    graphs.clear();
    if n == 0 {
        return;
    }
    let (image, map) = (&image[..n], &map[..n]);
    let Graphs { local_index, nodes, neighbours, local_theta, global_index, global_theta, cross_theta } = graphs;
    let ((node_count, k), ()) = rayon::join(
        || local_graph(local_index, local_theta, image, map, params, &mut scratch.local),
        || {
            let global = crate::reject::top_k(&scores[..n], params.keypoints.min(n));
            global_graph(&global, global_theta, cross_theta, image, map, params, &mut scratch.keys);
            global_index.extend(global.iter().map(|&i| i as u32));
        },
    );
    *nodes = node_count;
    *neighbours = k;
}

/// The global graph over the `global` keypoints (the M best-scored correspondences): θ among
/// them, and between every correspondence and each of them.
fn global_graph(
    global: &[usize],
    global_theta: &mut Vec<f32>,
    cross_theta: &mut Vec<f32>,
    image: &[Point3<f64>],
    map: &[Point3<f64>],
    params: &GraphParams,
    s: &mut KeyScratch,
) {
    s.key_image.clear();
    s.key_image.extend(global.iter().map(|&i| image[i]));
    s.key_map.clear();
    s.key_map.extend(global.iter().map(|&i| map[i]));
    params.pair_theta(&s.key_image, &s.key_map, &mut s.theta);
    global_theta.extend_from_slice(&s.theta.values);
    match params.theta {
        PairMetric::Angle => cross_angle_theta(image, map, params.sigma_d, s, cross_theta),
        PairMetric::Distance => cross_distance_theta(image, map, s, params, cross_theta),
    }
}

/// The local graph: nodes by farthest-point sampling of the map points, ~2 nodes per K points,
/// each holding its K nearest correspondences (into `index_out`) and their θ (into `theta_out`). The
/// node count and K.
fn local_graph(
    index_out: &mut Vec<u32>,
    theta_out: &mut Vec<f32>,
    image: &[Point3<f64>],
    map: &[Point3<f64>],
    params: &GraphParams,
    s: &mut LocalScratch,
) -> (usize, usize) {
    let n = map.len();
    let k = params.neighbours.min(n);
    let node_count = (2 * n).div_ceil(k).min(n);
    farthest_point_sampling_into(map, node_count, &mut s.seeds, &mut s.farthest);
    s.cloud.clear();
    s.cloud.extend(map.iter().map(|p| p.cast::<f32>()));
    let index = PointIndex::new(&s.cloud);
    index_out.reserve(node_count * k);
    theta_out.reserve(node_count * k * k);
    for &seed in &s.seeds {
        let group = index.nearest(&s.cloud[seed], k);
        s.group_image.clear();
        s.group_map.clear();
        s.group_image.extend(group.iter().map(|&i| image[i]));
        s.group_map.extend(group.iter().map(|&i| map[i]));
        params.pair_theta(&s.group_image, &s.group_map, &mut s.theta);
        index_out.extend(group.iter().map(|&i| i as u32));
        theta_out.extend_from_slice(&s.theta.values);
    }
    (s.seeds.len(), k)
}

/// Eq. (7) for every (correspondence, keypoint) pair, both clouds centred on the keypoints'
/// centroids (the keypoints are `s.key_image`/`s.key_map`). N × M, row-major, into `cross`.
fn cross_angle_theta(
    image: &[Point3<f64>],
    map: &[Point3<f64>],
    sigma_d: f64,
    s: &mut KeyScratch,
    cross: &mut Vec<f32>,
) {
    let unit = |p: &Point3<f64>, c: &Point3<f64>| -> Vector3<f64> {
        let v = p - c;
        let norm = v.norm();
        if norm > 1e-12 {
            v / norm
        } else {
            Vector3::zeros()
        }
    };
    let (ci, cp) = (centroid(&s.key_image), centroid(&s.key_map));
    s.key_unit_image.clear();
    s.key_unit_image.extend(s.key_image.iter().map(|p| unit(p, &ci)));
    s.key_unit_map.clear();
    s.key_unit_map.extend(s.key_map.iter().map(|p| unit(p, &cp)));
    let inv_sigma2 = 1.0 / (sigma_d * sigma_d);
    cross.reserve(image.len() * s.key_image.len());
    for (o, q) in image.iter().zip(map) {
        let (ui, up) = (unit(o, &ci), unit(q, &cp));
        for (ki, kp) in s.key_unit_image.iter().zip(&s.key_unit_map) {
            let delta = ui.dot(ki).abs() - up.dot(kp).abs();
            cross.push((1.0 - delta * delta * inv_sigma2).max(0.0) as f32);
        }
    }
}

/// Length consistency for every (correspondence, keypoint) pair, as
/// [`distance_consistency`]. N × M, row-major, into `cross`.
fn cross_distance_theta(
    image: &[Point3<f64>],
    map: &[Point3<f64>],
    s: &KeyScratch,
    params: &GraphParams,
    cross: &mut Vec<f32>,
) {
    cross.reserve(image.len() * s.key_image.len());
    for (o, q) in image.iter().zip(map) {
        for (ko, kq) in s.key_image.iter().zip(&s.key_map) {
            let d_map = (q - kq).norm();
            let delta = ((o - ko).norm() - d_map) / (params.sigma_abs + params.sigma_rel * d_map);
            cross.push((1.0 - delta * delta).max(0.0) as f32);
        }
    }
}

/// `count` indices spread over `points`: start from the point farthest from the centroid, then
/// repeatedly take the point farthest from those taken.
pub fn farthest_point_sampling(points: &[Point3<f64>], count: usize) -> Vec<usize> {
    let mut chosen = Vec::new();
    farthest_point_sampling_into(points, count, &mut chosen, &mut Vec::new());
    chosen
}

/// [`farthest_point_sampling`] into `chosen`, with `distance` as its working buffer.
fn farthest_point_sampling_into(
    points: &[Point3<f64>],
    count: usize,
    chosen: &mut Vec<usize>,
    distance: &mut Vec<f64>,
) {
    chosen.clear();
    let count = count.min(points.len());
    if count == 0 {
        return;
    }
    let c = centroid(points);
    let first =
        (0..points.len()).max_by(|&a, &b| (points[a] - c).norm_squared().total_cmp(&(points[b] - c).norm_squared()));
    chosen.push(first.unwrap_or(0));
    distance.clear();
    distance.extend(points.iter().map(|p| (p - points[chosen[0]]).norm_squared()));
    while chosen.len() < count {
        let next = (0..points.len()).max_by(|&a, &b| distance[a].total_cmp(&distance[b])).unwrap_or(0);
        chosen.push(next);
        for (d, p) in distance.iter_mut().zip(points) {
            *d = d.min((p - points[next]).norm_squared());
        }
    }
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
    fn distance_theta_needs_a_metric_copy() {
        let map = grid(150);
        let rigid: Vec<_> = map.iter().map(|p| Point3::new(p.y, -p.x, p.z + 2.0)).collect();
        let scores: Vec<f32> = (0..150).map(|i| i as f32).collect();
        let params = GraphParams { theta: PairMetric::Distance, ..GraphParams::default() };
        let g = build_graphs(&rigid, &map, &scores, &params);
        assert!(g.cross_theta.iter().all(|&t| t > 0.999), "a rigid copy keeps every length");
        let off_diagonal =
            |v: &[f32], k: usize| v.iter().enumerate().filter(|(i, _)| i % (k + 1) != 0).all(|(_, &t)| t > 0.999);
        assert!(off_diagonal(&g.global_theta, 100));
        // Unlike the angle θ, lengths see a scaled copy as inconsistent.
        let scaled: Vec<_> = rigid.iter().map(|p| Point3::from(p.coords * 2.0)).collect();
        let g = build_graphs(&scaled, &map, &scores, &params);
        let consistent = g.cross_theta.iter().filter(|&&t| t > 0.5).count();
        assert!(consistent < g.cross_theta.len() / 10, "{consistent} of {}", g.cross_theta.len());
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
