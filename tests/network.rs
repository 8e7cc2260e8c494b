//! The learned rejector in Rust: inputs built here equal the ones the model was checked with
//! (`models/parity/sample`: `angle-i2p export bags/synth-hard`, first frame; re-recorded, with
//! `training/parity.py`'s PyTorch scores, whenever the inputs change on purpose), and ONNX
//! Runtime's scores equal PyTorch's (≤ 1e-4) on them — the parity of training and inference.
//! Needs ONNX Runtime (`make ort`); skipped without it, a failure in CI.

use std::path::{Path, PathBuf};

use angle_i2p::bag::read_frames;
use angle_i2p::npy;
use angle_i2p::params::LocalizerParams;
use angle_i2p::reject::graph::Graphs;
use angle_i2p::reject::inputs::{build_inputs, IndexedMap, NetworkInputs};
use angle_i2p::reject::network::{NetworkParams, NetworkRejector};
use angle_i2p::reject::{FrameGeometry, SpectralRejector};

mod common;
use common::{manifest, onnx_runtime};

fn sample_dir() -> PathBuf {
    manifest().join("models/parity/sample")
}

fn f32s(dir: &Path, name: &str) -> Vec<f32> {
    npy::read::<f32>(&dir.join(format!("{name}.npy"))).unwrap().0
}

fn u32s(dir: &Path, name: &str) -> (Vec<u32>, Vec<usize>) {
    let (v, shape) = npy::read::<i64>(&dir.join(format!("{name}.npy"))).unwrap();
    (v.into_iter().map(|i| i as u32).collect(), shape)
}

/// The recorded sample (`models/parity/sample`), the inputs PyTorch scored.
fn stored_inputs() -> NetworkInputs {
    inputs_in(&sample_dir())
}

/// Network inputs stored as `angle-i2p export` writes them, in `dir`.
fn inputs_in(dir: &Path) -> NetworkInputs {
    let flat = f32s(dir, "features");
    let (local_index, local_shape) = u32s(dir, "local_index");
    let (global_index, _) = u32s(dir, "global_index");
    NetworkInputs {
        features: flat.chunks_exact(24).map(|c| c.try_into().unwrap()).collect(),
        graphs: Graphs {
            local_index,
            nodes: local_shape[0],
            neighbours: local_shape[1],
            local_theta: f32s(dir, "local_theta"),
            global_index,
            global_theta: f32s(dir, "global_theta"),
            cross_theta: f32s(dir, "cross_theta"),
        },
        spectral_scores: f32s(dir, "spectral"),
        matcher_scores: f32s(dir, "correspondences").chunks_exact(6).map(|c| c[5]).collect(),
        matcher_ranks: Vec::new(),
    }
}

fn assert_close(a: &[f32], b: &[f32], tol: f32, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    let worst = a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
    assert!(worst <= tol, "{what}: max difference {worst}");
}

#[test]
fn rust_inputs_are_reproduced_exactly() {
    let bag = read_frames(manifest().join("bags/synth-hard"), &angle_i2p::params::TopicMap::default()).unwrap();
    let params = LocalizerParams::default();
    let frame = &bag.frames[0];
    let geometry = FrameGeometry::build(frame, params.depth_kind, Some(&params.align));
    let map = IndexedMap::new(bag.map.unwrap().points);
    let mut spectral = SpectralRejector::new(params.network.keypoint_spectral(params.spectral.clone()));
    let now = build_inputs(&geometry, Some(&map), &mut spectral, &params.network);
    let stored = stored_inputs();
    let flat: Vec<f32> = now.features.iter().flatten().copied().collect();
    let stored_flat: Vec<f32> = stored.features.iter().flatten().copied().collect();
    assert_close(&flat, &stored_flat, 1e-6, "features");
    assert_eq!(now.graphs.local_index, stored.graphs.local_index);
    assert_eq!(now.graphs.global_index, stored.graphs.global_index);
    assert_close(&now.graphs.local_theta, &stored.graphs.local_theta, 1e-6, "local θ");
    assert_close(&now.graphs.global_theta, &stored.graphs.global_theta, 1e-6, "global θ");
    assert_close(&now.graphs.cross_theta, &stored.graphs.cross_theta, 1e-6, "cross θ");
}

/// The rejector running the shipped model file `model` (under `models/`); `None` (skipped, a
/// failure in CI) without ONNX Runtime.
fn rejector(model: &str) -> Option<NetworkRejector> {
    let params = NetworkParams {
        model_path: manifest().join("models").join(model).display().to_string(),
        onnxruntime_path: onnx_runtime()?.display().to_string(),
        ..NetworkParams::default()
    };
    Some(NetworkRejector::new(params, Default::default()).unwrap())
}

#[test]
fn onnx_runtime_scores_equal_pytorch_scores() {
    let Some(mut rejector) = rejector("angle_i2p.onnx") else { return };
    let scores = rejector.run(&stored_inputs()).unwrap();
    let torch = f32s(&sample_dir(), "scores_torch");
    assert_close(&scores, &torch, 1e-4, "scores");
}

/// A model that declares fewer inputs (the no-global-attention ablation has no global ones) is
/// fed just those, and scores every correspondence.
#[test]
fn a_model_without_global_inputs_runs_on_the_same_inputs() {
    let Some(mut rejector) = rejector("ablations/no_global.onnx") else { return };
    let inputs = stored_inputs();
    let scores = rejector.run(&inputs).unwrap();
    assert_eq!(scores.len(), inputs.features.len());
    assert!(scores.iter().all(|s| (0.0..=1.0).contains(s)));
}

/// The model that takes the matcher's confidence as within-frame ranks
/// (`models/ablations/confidence_rank.onnx`, input `matcher_rank`) scores the same inputs, and
/// a matcher publishing the same order on another scale (cubed) gets the same scores.
#[test]
fn the_rank_model_scores_any_calibration_of_the_same_order_alike() {
    let Some(mut ranked) = rejector("ablations/confidence_rank.onnx") else { return };
    let mut inputs = stored_inputs();
    inputs.rank_matcher_scores();
    let scores = ranked.run(&inputs).unwrap();
    assert_eq!(scores.len(), inputs.features.len());
    assert!(scores.iter().all(|s| (0.0..=1.0).contains(s)));
    let mut recalibrated = stored_inputs();
    recalibrated.matcher_scores.iter_mut().for_each(|s| *s = 10.0 * *s * *s * *s);
    recalibrated.rank_matcher_scores();
    assert_eq!(ranked.run(&recalibrated).unwrap(), scores);
    let mut shuffled = stored_inputs();
    shuffled.matcher_scores.reverse();
    shuffled.rank_matcher_scores();
    assert_ne!(ranked.run(&shuffled).unwrap(), scores, "the order is an input");
}

/// The model trained on rooms only (`models/ablations/rooms_only.onnx`, the default before the
/// mix; see the model card) takes the same inputs and scores every correspondence, differently.
#[test]
fn the_rooms_only_model_runs_on_the_same_inputs() {
    let Some(mut rooms) = rejector("ablations/rooms_only.onnx") else { return };
    let Some(mut default) = rejector("angle_i2p.onnx") else { return };
    let inputs = stored_inputs();
    let scores = rooms.run(&inputs).unwrap();
    assert_eq!(scores.len(), inputs.features.len());
    assert!(scores.iter().all(|s| (0.0..=1.0).contains(s)));
    let other = default.run(&inputs).unwrap();
    assert!(scores.iter().zip(&other).any(|(a, b)| (a - b).abs() > 1e-3), "a different model");
}
