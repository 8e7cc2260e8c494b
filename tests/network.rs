//! The learned rejector in Rust: inputs built here equal the ones the model was checked with
//! (`models/parity/sample`: `angle-i2p export bags/synth-hard`, first frame; re-recorded, with
//! `training/parity.py`'s PyTorch scores, whenever the inputs change on purpose), and ONNX
//! Runtime's scores equal PyTorch's (≤ 1e-4) on them — the parity of training and inference.
//! Needs ONNX Runtime (`make ort`); skipped without it, a failure in CI.

use std::path::{Path, PathBuf};
use std::process::Command;

use angle_i2p::bag::read_frames;
use angle_i2p::npy;
use angle_i2p::params::{resolve_cli, LocalizerParams};
use angle_i2p::pipeline::Localizer;
use angle_i2p::reject::graph::Graphs;
use angle_i2p::reject::inputs::{build_inputs, IndexedMap, NetworkInputs};
use angle_i2p::reject::model_constants::metadata_of;
use angle_i2p::reject::network::{NetworkError, NetworkParams, NetworkRejector};
use angle_i2p::reject::network_params::ModelConstant;
use angle_i2p::reject::{FrameGeometry, Rejector, SpectralRejector};

mod common;
use common::{manifest, onnx_runtime, run_ok, skip_or_fail};

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

// The model constants (`src/reject/model_constants.rs`): the `network.*` values a model was
// trained with, carried in its ONNX metadata and enforced at load.

/// `params` with ONNX Runtime where the tests find it and the model at `model`; `None`
/// (skipped, a failure in CI) without ONNX Runtime.
fn with_model(model: &Path, params: NetworkParams) -> Option<NetworkParams> {
    let onnxruntime_path = onnx_runtime()?.display().to_string();
    Some(NetworkParams { model_path: model.display().to_string(), onnxruntime_path, ..params })
}

/// A Python for `training/stamp_metadata.py` (it needs no package); `None`, after
/// [`skip_or_fail`], without one.
fn stamper() -> Option<PathBuf> {
    if let Some(venv) = common::python() {
        return Some(venv);
    }
    let plain = PathBuf::from("python3");
    if Command::new(&plain).arg("--version").output().is_ok_and(|o| o.status.success()) {
        return Some(plain);
    }
    skip_or_fail("no python3 to run training/stamp_metadata.py");
    None
}

/// A copy of the shipped model in `dir` with its metadata rewritten by `stamp_metadata.py ARGS`
/// (the weights, and so the scores, are the shipped model's).
fn restamped(dir: &Path, args: &[&str]) -> Option<PathBuf> {
    let out = dir.join("restamped.onnx");
    run_ok(
        Command::new(stamper()?)
            .arg(manifest().join("training/stamp_metadata.py"))
            .arg(manifest().join("models/angle_i2p.onnx"))
            .arg("--out")
            .arg(&out)
            .args(args),
    );
    Some(out)
}

/// The shipped reference of every parameter (`params/expert.yaml`) with `overrides` (`-p` style),
/// the model's constants given there.
fn shipped_params(overrides: &[&str]) -> LocalizerParams {
    resolve_cli(Some(&manifest().join("params/expert.yaml")), overrides).expect("the shipped params").localizer
}

/// The first frame of `bags/synth-hard`, as the network's geometry, and its map.
fn first_frame() -> (FrameGeometry, IndexedMap) {
    let bag = read_frames(manifest().join("bags/synth-hard"), &angle_i2p::params::TopicMap::default()).unwrap();
    let params = LocalizerParams::default();
    let geometry = FrameGeometry::build(&bag.frames[0], params.depth_kind, Some(&params.align));
    (geometry, IndexedMap::new(bag.map.expect("a map").points))
}

/// The shipped model carries the defaults: its metadata is what a model trained with them
/// carries, it runs with them, and the shipped params file (which names every one) agrees.
#[test]
fn the_shipped_model_carries_the_default_constants() {
    let Some(mut rejector) = rejector("angle_i2p.onnx") else { return };
    let defaults = NetworkParams::default();
    assert_eq!(rejector.model_constants().metadata(), metadata_of(&defaults));
    for c in ModelConstant::ALL {
        assert_eq!(c.text(rejector.params()), c.text(&defaults), "{}", c.name());
    }
    let shipped = shipped_params(&[]);
    assert_eq!(shipped.network.given.len(), ModelConstant::ALL.len(), "the shipped file names every constant");
    let loaded = Localizer::new(shipped).expect("the shipped params with the shipped model");
    assert_eq!(loaded.params().network.graph, defaults.graph);
    // The stamp changed no weight: the parity scores still hold (also the test above).
    assert_close(&rejector.run(&stored_inputs()).unwrap(), &f32s(&sample_dir(), "scores_torch"), 1e-4, "scores");
}

/// Every shipped model loads with its own params file, and those name no value the model
/// contradicts.
#[test]
fn every_shipped_model_loads_with_its_params_file() {
    if onnx_runtime().is_none() {
        return;
    }
    let dir = manifest().join("params/ablations");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    assert!(files.len() >= 6, "{files:?}");
    for file in files {
        let params = resolve_cli::<&str>(Some(&file), &[]).unwrap().localizer;
        let model = params.network.model_path.clone();
        let localizer = Localizer::new(params).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        assert!(!model.is_empty() && localizer.params().network.model_path == model);
    }
    let mut params = LocalizerParams::default();
    params.network.model_path = "models/ablations/no_scale_alignment.onnx".into();
    let localizer = Localizer::new(params).unwrap();
    assert!(!localizer.params().network.align_prior, "the model's prior alignment reaches the geometry step");
}

/// A params file that sets a model constant to another value than the model's is refused,
/// naming the key, its value and the model's: the shipped file (angle θ) with the distance-θ
/// model, and a copy of the shipped model stamped with K = 16 against `network.neighbours:=32`.
#[test]
fn a_params_value_the_model_contradicts_is_refused() {
    if onnx_runtime().is_none() {
        return;
    }
    let params = shipped_params(&["network.model_path:=models/ablations/distance_theta.onnx"]);
    let err = Localizer::new(params).err().expect("refused").to_string();
    assert!(err.contains("distance_theta.onnx"), "{err}");
    assert!(err.contains("network.theta is angle") && err.contains("trained with distance"), "{err}");
    let dir = tempfile::tempdir().unwrap();
    let Some(model) = restamped(dir.path(), &["--set", "neighbours=16"]) else { return };
    let mut given = NetworkParams::default();
    given.given.insert(ModelConstant::Neighbours);
    let Some(params) = with_model(&model, given) else { return };
    let err = NetworkRejector::new(params, Default::default()).err().expect("refused");
    assert!(matches!(err, NetworkError::Constants { .. }), "{err}");
    let text = err.to_string();
    assert!(text.contains("network.neighbours is 32") && text.contains("trained with 16"), "{text}");
    let shipped = shipped_params(&[&format!("network.model_path:={}", model.display())]);
    let text = Localizer::new(shipped).err().expect("the shipped file names neighbours: 32").to_string();
    assert!(text.contains("network.neighbours"), "{text}");
}

/// A constant the params do not give is the model's: K = 16 stamped reaches the graphs.
#[test]
fn a_constant_not_given_is_the_models() {
    let dir = tempfile::tempdir().unwrap();
    let Some(model) = restamped(dir.path(), &["--set", "neighbours=16"]) else { return };
    let Some(params) = with_model(&model, NetworkParams::default()) else { return };
    let mut rejector = NetworkRejector::new(params, Default::default()).unwrap();
    assert_eq!(rejector.params().graph.neighbours, 16);
    let (geometry, map) = first_frame();
    rejector.set_map_index(&std::sync::Arc::new(map));
    assert_eq!(rejector.inputs(&geometry).graphs.neighbours, 16);
}

/// A model without constants (an older one) runs with the params' values, whatever they are.
#[test]
fn a_model_without_constants_runs_with_the_params_values() {
    let dir = tempfile::tempdir().unwrap();
    let Some(model) = restamped(dir.path(), &["--clear"]) else { return };
    let mut params = NetworkParams::default();
    params.graph.neighbours = 8;
    params.given.insert(ModelConstant::Neighbours);
    let Some(params) = with_model(&model, params) else { return };
    let mut older = NetworkRejector::new(params, Default::default()).unwrap();
    assert!(older.model_constants().is_empty());
    assert_eq!(older.params().graph.neighbours, 8);
    // Same weights as the shipped model: the same scores on the parity sample.
    let scores = older.run(&stored_inputs()).unwrap();
    let Some(mut shipped) = rejector("angle_i2p.onnx") else { return };
    assert_eq!(scores, shipped.run(&stored_inputs()).unwrap());
}
