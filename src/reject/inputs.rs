//! Everything the learned rejector consumes for one frame, built in Rust (never inside the
//! network graph): eq. (9) features, the local and global graphs with their θ, and — for
//! training — the ground-truth labels. The same code builds training samples (`angle-i2p
//! export`) and inference inputs, so both sides see identical numbers.

use std::borrow::Cow;

use nalgebra::Point3;

pub use super::features::IndexedMap;
use super::features::{features_into, map_normals, FEATURE_DIM};
use super::graph::{build_graphs_into, GraphScratch, Graphs};
use super::network_params::{KeypointRanking, NetworkParams};
use super::{FrameGeometry, SpectralRejector};

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
    /// Its within-frame ranks in [0, 1], for a model that takes `matcher_rank` instead (blind to
    /// the matcher's scale): filled by [`NetworkInputs::rank_matcher_scores`], else empty.
    pub matcher_ranks: Vec<f32>,
}

/// The values of one input tensor, in the element type the network declares: the f32 ones
/// borrowed from [`NetworkInputs`] (no copy per frame), the indices widened to i64.
#[derive(Clone, Debug, PartialEq)]
pub enum TensorValues<'a> {
    F32(Cow<'a, [f32]>),
    I64(Vec<i64>),
}

/// One named input of the network: row-major values and their shape.
#[derive(Clone, Debug, PartialEq)]
pub struct InputTensor<'a> {
    pub name: &'static str,
    pub shape: Vec<usize>,
    pub values: TensorValues<'a>,
}

/// What building the inputs works in besides the inputs themselves, kept between frames.
#[derive(Clone, Debug, Default)]
pub struct InputScratch {
    image: Vec<Point3<f64>>,
    keypoint_ranks: Vec<f32>,
    graph: GraphScratch,
}

impl NetworkInputs {
    /// The network's input tensors (N correspondences, V local nodes of K, M keypoints): the one
    /// definition of the layout, which the ONNX run feeds and `export` writes (`NAME.npy`) for
    /// training.
    pub fn tensors(&self) -> Vec<InputTensor<'_>> {
        let n = self.features.len();
        let g = &self.graphs;
        let m = g.global_index.len();
        let index = |v: &[u32]| TensorValues::I64(v.iter().map(|&i| i as i64).collect());
        let f32s = |v| TensorValues::F32(Cow::Borrowed(v));
        let tensor = |name, shape: &[usize], values| InputTensor { name, shape: shape.to_vec(), values };
        let mut tensors = vec![
            tensor("features", &[n, FEATURE_DIM], f32s(self.features.as_flattened())),
            tensor("local_index", &[g.nodes, g.neighbours], index(&g.local_index)),
            tensor("local_theta", &[g.nodes, g.neighbours, g.neighbours], f32s(&g.local_theta)),
            tensor("global_index", &[m], index(&g.global_index)),
            tensor("global_theta", &[m, m], f32s(&g.global_theta)),
            tensor("cross_theta", &[n, m], f32s(&g.cross_theta)),
            tensor("matcher_score", &[n], f32s(&self.matcher_scores)),
        ];
        if self.matcher_ranks.len() == n {
            tensors.push(tensor("matcher_rank", &[n], f32s(&self.matcher_ranks)));
        }
        tensors
    }

    /// Fills `matcher_ranks` from `matcher_scores` ([`within_frame_ranks`]).
    pub fn rank_matcher_scores(&mut self) {
        within_frame_ranks(&self.matcher_scores, &mut self.matcher_ranks);
    }
}

/// Each score's rank among the frame's, scaled to [0, 1] (the lowest 0, the highest 1; equal
/// scores share their mean rank, so one score for every match gives 0.5 to all; a non-finite
/// score counts as the lowest), into `ranks`. Any increasing remap of the scores gives the same
/// ranks: what a model trained on them sees does not depend on the matcher's calibration.
/// `training/train.py` (`confidence_rank`) computes the same.
pub fn within_frame_ranks(scores: &[f32], ranks: &mut Vec<f32>) {
    let n = scores.len();
    ranks.clear();
    ranks.resize(n, 0.5);
    if n < 2 {
        return;
    }
    let key = |i: usize| if scores[i].is_finite() { scores[i] } else { f32::NEG_INFINITY };
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| key(a).total_cmp(&key(b)));
    let scale = 1.0 / (n - 1) as f64;
    let mut start = 0;
    while let Some(&first) = order.get(start) {
        let end = start + order[start..].iter().take_while(|&&i| key(i) == key(first)).count();
        let rank = (0.5 * (start + end - 1) as f64 * scale) as f32;
        for &i in &order[start..end] {
            ranks[i] = rank;
        }
        start = end;
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
    let mut inputs = NetworkInputs::default();
    build_inputs_into(&mut inputs, geometry, map, spectral, params, &mut InputScratch::default());
    inputs
}

/// [`build_inputs`] into `inputs`, reusing its buffers and `scratch`'s (the learned rejector
/// keeps both across frames).
pub fn build_inputs_into(
    inputs: &mut NetworkInputs,
    geometry: &FrameGeometry,
    map: Option<&IndexedMap>,
    spectral: &mut SpectralRejector,
    params: &NetworkParams,
    scratch: &mut InputScratch,
) {
    // The keypoints' spectral scores and the map normals need only the geometry: side by side.
    let spectral_scores = &mut inputs.spectral_scores;
    let (spectral_ok, n_map) = rayon::join(
        || spectral.scores_into(geometry, spectral_scores).is_ok(),
        || match map {
            Some(m) => map_normals(m, geometry),
            None => vec![nalgebra::Vector3::zeros(); geometry.len()],
        },
    );
    if !spectral_ok {
        inputs.spectral_scores.clear();
        inputs.spectral_scores.resize(geometry.len(), 0.0);
    }
    scratch.image.clear();
    scratch.image.extend((0..geometry.len()).map(|i| match geometry.image_points.get(i) {
        Some(p) if p.coords.iter().all(|v| v.is_finite()) => *p,
        _ => geometry.map_points[i],
    }));
    features_into(&mut inputs.features, geometry, &geometry.image_normals, &n_map, params.align_prior);
    keypoint_ranks(&inputs.spectral_scores, geometry, params, &mut scratch.keypoint_ranks);
    let graph_scratch = &mut scratch.graph;
    build_graphs_into(
        &mut inputs.graphs,
        &scratch.image,
        &geometry.map_points,
        &scratch.keypoint_ranks,
        &params.graph,
        graph_scratch,
    );
    inputs.matcher_scores.clear();
    inputs.matcher_scores.extend_from_slice(&geometry.matcher_scores);
    impute_missing_confidence(&mut inputs.matcher_scores, params.missing_confidence);
}

/// A matcher that publishes no confidence gives every match of the frame one score: the
/// network reads `missing` for them instead ([`NetworkParams::missing_confidence`]). Informative
/// scores are left as they are. (The keypoints' ranking needs nothing of this: with one score
/// for all, spectral × confidence is the spectral order.)
fn impute_missing_confidence(scores: &mut [f32], missing: f32) {
    if let Some(&first) = scores.first() {
        if scores.iter().all(|&s| s == first) {
            scores.fill(missing);
        }
    }
}

/// The scores that pick the keypoints ([`KeypointRanking`]). A matcher that publishes no
/// confidence (all zero; with ranks, all 0.5) leaves the spectral order.
fn keypoint_ranks(spectral: &[f32], geometry: &FrameGeometry, params: &NetworkParams, ranks: &mut Vec<f32>) {
    ranks.clear();
    match params.keypoint_ranking {
        KeypointRanking::Spectral => ranks.extend_from_slice(spectral),
        KeypointRanking::SpectralMatcher => ranks.extend(
            spectral
                .iter()
                .zip(&geometry.matcher_scores)
                .map(|(&s, &m)| s * (if m.is_finite() { m.clamp(0.0, 1.0) } else { 0.0 } + 1e-3)),
        ),
        KeypointRanking::SpectralMatcherRank => {
            within_frame_ranks(&geometry.matcher_scores, ranks);
            for (r, &s) in ranks.iter_mut().zip(spectral) {
                *r = s * (*r + 1e-3);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{impute_missing_confidence, within_frame_ranks, NetworkInputs};

    fn ranks(scores: &[f32]) -> Vec<f32> {
        let mut out = Vec::new();
        within_frame_ranks(scores, &mut out);
        out
    }

    /// Lowest 0, highest 1, ties share their mean rank, non-finite scores are the lowest; one
    /// score for all (a matcher without confidence) or a single match reads 0.5.
    #[test]
    fn ranks_span_zero_to_one_with_ties_at_their_mean() {
        assert_eq!(ranks(&[0.3, 0.1, 0.3, 0.9]), vec![0.5, 0.0, 0.5, 1.0]);
        assert_eq!(ranks(&[f32::NAN, 0.2, 0.1]), vec![0.0, 1.0, 0.5]);
        assert_eq!(ranks(&[0.7; 4]), vec![0.5; 4]);
        assert_eq!(ranks(&[0.7]), vec![0.5]);
        assert!(ranks(&[]).is_empty());
    }

    /// What the ranks exist for: a matcher's scores and any increasing remap of them (another
    /// calibration: scaled, cubed, squared away from 0–1) give the same input.
    #[test]
    fn ranks_ignore_the_matchers_calibration() {
        let scores: Vec<f32> = (0..50).map(|i| ((i * 37 % 50) as f32 + 0.5) / 50.0).collect();
        let remapped: Vec<f32> = scores.iter().map(|s| 3.0 * s * s * s + 10.0).collect();
        assert_eq!(ranks(&scores), ranks(&remapped));
    }

    /// `matcher_rank` is an input tensor only once the ranks are filled (a model that names it).
    #[test]
    fn the_rank_tensor_is_fed_once_filled() {
        let mut inputs = NetworkInputs { matcher_scores: vec![0.2, 0.4], ..NetworkInputs::default() };
        inputs.features = vec![[0.0; super::FEATURE_DIM]; 2];
        let names = |i: &NetworkInputs| i.tensors().iter().map(|t| t.name).collect::<Vec<_>>();
        assert!(!names(&inputs).contains(&"matcher_rank"));
        inputs.rank_matcher_scores();
        assert!(names(&inputs).contains(&"matcher_rank"));
        assert_eq!(inputs.matcher_ranks, vec![0.0, 1.0]);
    }

    #[test]
    fn one_score_for_every_match_reads_as_the_missing_confidence() {
        for published in [0.0f32, 1.0, 0.6] {
            let mut scores = vec![published; 5];
            impute_missing_confidence(&mut scores, 0.25);
            assert_eq!(scores, vec![0.25; 5], "all {published}");
        }
        let mut informative = vec![0.1, 0.9, 0.1];
        impute_missing_confidence(&mut informative, 0.25);
        assert_eq!(informative, vec![0.1, 0.9, 0.1]);
        impute_missing_confidence(&mut [], 0.25);
    }
}
