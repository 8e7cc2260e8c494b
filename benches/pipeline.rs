//! Per-frame cost of each stage at N = 400, 1000, 2000, 4000 correspondences (synthetic "hard" tier:
//! ~15 % inliers, half moved patch-wise): the consistency matrices (angle, distance), the
//! scale-and-shift alignment, the spectral scorer (and with every correspondence in Θ, where N
//! is above its anchors), and the whole frame with consistency
//! rejection, the learned rejector (when ONNX Runtime is there: `make ort`; also with the
//! verification against the dense prior off) and plain LO-RANSAC, and one verification of a
//! pose, measured in the same run.
//!
//! `cargo bench --bench pipeline`; `ANGLE_I2P_BENCH_MODELS=a.onnx,b.onnx` also times the network
//! alone for other model files (same inputs), for the size/latency trade-off.

use std::hint::black_box;
use std::time::Duration;

use angle_i2p::consistency::{angle_consistency, distance_consistency, ConsistencyMatrix, ScaleShiftParams};
use angle_i2p::geometry::DepthKind;
use angle_i2p::params::LocalizerParams;
use angle_i2p::pipeline::{Localizer, Method};
use angle_i2p::reject::network::{NetworkParams, NetworkRejector};
use angle_i2p::reject::{FrameGeometry, Rejector, SpectralParams, SpectralRejector};
use angle_i2p::synth::{generate, SynthConfig};
use angle_i2p::verify::{PriorVerifier, RenderMap, VerifyParams};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};

fn scene(n: usize) -> (Vec<angle_i2p::frame::Frame>, angle_i2p::frame::MapCloud) {
    let config =
        SynthConfig { frames: 3, correspondences: n, seed: 42, ..SynthConfig::preset("hard").expect("preset") };
    let scene = generate(&config);
    (scene.frames, scene.map)
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("frame");
    group.sample_size(20).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_millis(500));
    let align = ScaleShiftParams::default();
    for n in [400usize, 1000, 2000, 4000] {
        let (frames, map) = scene(n);
        let map = Some(map);
        let frame = &frames[1];
        let geometry = FrameGeometry::build(frame, DepthKind::Depth, Some(&align));
        let mut theta = ConsistencyMatrix::default();
        group.bench_with_input(BenchmarkId::new("angle_consistency", n), &geometry, |b, g| {
            b.iter(|| angle_consistency(black_box(&g.image_points), &g.map_points, None, 0.2, &mut theta))
        });
        group.bench_with_input(BenchmarkId::new("distance_consistency", n), &geometry, |b, g| {
            b.iter(|| distance_consistency(black_box(&g.image_points), &g.map_points, 0.05, 0.1, &mut theta))
        });
        group.bench_with_input(BenchmarkId::new("align_scale_shift", n), frame, |b, f| {
            b.iter(|| FrameGeometry::build(black_box(f), DepthKind::Depth, Some(&align)))
        });
        // One verification: the map rendered at a pose and compared with the prior.
        if let (Some(map), Some(prior), Some(truth)) =
            (&map, &frame.depth_prior, frame.ground_truth.as_ref().and_then(|g| g.pose))
        {
            let params = VerifyParams::default();
            let render = RenderMap::new(&map.points, params.max_map_points);
            if let Some(verifier) = PriorVerifier::new(&render, prior, DepthKind::Depth, &frame.intrinsics, &params) {
                group.bench_with_input(BenchmarkId::new("verify_pose", n), &truth, |b, t| {
                    b.iter(|| verifier.agreement(black_box(t)))
                });
            }
        }
        let mut scorer = SpectralRejector::default();
        group.bench_with_input(BenchmarkId::new("spectral_scorer", n), &geometry, |b, g| {
            b.iter(|| scorer.reject(black_box(g)).expect("scores"))
        });
        if n > SpectralParams::default().max_nodes {
            let mut whole = SpectralRejector::new(SpectralParams { max_nodes: 0, ..SpectralParams::default() });
            group.bench_with_input(BenchmarkId::new("spectral_scorer_whole", n), &geometry, |b, g| {
                b.iter(|| whole.reject(black_box(g)).expect("scores"))
            });
        }
        // The learned rejector's two halves: inputs built in Rust, then the network in ort.
        if let Ok(mut network) = NetworkRejector::new(NetworkParams::default(), SpectralParams::default()) {
            if let Some(map) = &map {
                network.set_map(map);
            }
            group.bench_with_input(BenchmarkId::new("network_inputs", n), &geometry, |b, g| {
                b.iter(|| network.inputs(black_box(g)))
            });
            let inputs = network.inputs(&geometry);
            group.bench_with_input(BenchmarkId::new("network_run", n), &inputs, |b, i| {
                b.iter(|| network.run(black_box(i)).expect("scores"))
            });
            for path in extra_models() {
                let params = NetworkParams { model_path: path.clone(), ..NetworkParams::default() };
                let Ok(mut other) = NetworkRejector::new(params, SpectralParams::default()) else {
                    eprintln!("skipping {path}: cannot load it");
                    continue;
                };
                let name = std::path::Path::new(&path).file_stem().map(|s| s.to_string_lossy().into_owned());
                let id = format!("network_run_{}", name.unwrap_or_default());
                group.bench_with_input(BenchmarkId::new(id, n), &inputs, |b, i| {
                    b.iter(|| other.run(black_box(i)).expect("scores"))
                });
            }
        }
        // The whole frame per method; angle-i2p also without verification against the prior
        // (the baseline of that stage, in the same run).
        let plain = VerifyParams { enabled: false, ..VerifyParams::default() };
        let runs = [
            (Method::Ransac, VerifyParams::default(), ""),
            (Method::Consistency, VerifyParams::default(), ""),
            (Method::AngleI2p, VerifyParams::default(), ""),
            (Method::AngleI2p, plain, "_no_verify"),
        ];
        for (method, verify, suffix) in runs {
            let mut localizer = match Localizer::new(LocalizerParams { method, verify, ..LocalizerParams::default() }) {
                Ok(localizer) => localizer,
                Err(e) => {
                    eprintln!("skipping {}: {e}", method.name());
                    continue;
                }
            };
            if let Some(map) = &map {
                localizer.set_map(map);
            }
            group.bench_with_input(
                BenchmarkId::new(format!("localize_{}{suffix}", method.name()), n),
                frame,
                |b, f| b.iter(|| localizer.process(black_box(f))),
            );
        }
    }
    group.finish();
}

/// Model files named in `ANGLE_I2P_BENCH_MODELS` (comma-separated).
fn extra_models() -> Vec<String> {
    std::env::var("ANGLE_I2P_BENCH_MODELS")
        .map(|v| v.split(',').filter(|p| !p.trim().is_empty()).map(|p| p.trim().to_string()).collect())
        .unwrap_or_default()
}

criterion_group!(benches, bench);
criterion_main!(benches);
