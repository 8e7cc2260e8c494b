//! Map loading at building scale: indexing a `synth --preset building` map of 200 k, 1 M and
//! 5 M points (`MapIndex::build`: the point tree and the voxel grid, side by side), what the
//! lazy normals replace (every point's normal, computed eagerly, at 200 k), one culled render
//! source query (the points in view at a pose) on each map, and one frame's map normals (its
//! correspondences' map points, the network's input, once the planar cells are built).
//!
//! `cargo bench --bench map_load` (`ANGLE_I2P_BENCH_MAP_POINTS=200000,1000000` for other sizes).

use std::hint::black_box;
use std::time::Duration;

use angle_i2p::map_index::{MapIndex, View};
use angle_i2p::synth::{SynthConfig, SynthRun};
use angle_i2p::verify::VerifyParams;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};

fn sizes() -> Vec<usize> {
    std::env::var("ANGLE_I2P_BENCH_MAP_POINTS")
        .ok()
        .map(|v| v.split(',').filter_map(|s| s.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![200_000, 1_000_000, 5_000_000])
}

fn building(map_points: usize) -> SynthRun {
    let preset = SynthConfig::preset("building").expect("building preset");
    SynthRun::new(&SynthConfig { frames: 1, map_points, ..preset })
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("map_load");
    group.sample_size(10).measurement_time(Duration::from_secs(10)).warm_up_time(Duration::from_millis(200));
    let verify = VerifyParams::default();
    let settings = verify.index_settings();
    for n in sizes() {
        let run = building(n);
        let points = run.map().points.clone();
        group.bench_with_input(BenchmarkId::new("index_build", n), &points, |b, p| {
            b.iter(|| MapIndex::build(black_box(p.clone()), &settings))
        });
        let index = MapIndex::build(points, &settings);
        if n <= 200_000 {
            group.bench_with_input(BenchmarkId::new("eager_normals", n), &index, |b, i| b.iter(|| i.eager_normals()));
        }
        let (frame, _) = run.frames(0..1).pop().expect("one frame");
        let pose = frame.ground_truth.and_then(|g| g.pose).expect("a synthetic frame has its pose");
        let view = View { pose: &pose, intrinsics: &frame.intrinsics, range_m: verify.cull_range_m, near_m: 0.05 };
        group.bench_with_input(BenchmarkId::new("points_in_view", n), &index, |b, i| {
            b.iter(|| i.visible(black_box(&view), verify.max_map_points).len())
        });
        index.prepare_searches();
        let queries: Vec<nalgebra::Point3<f64>> = frame.correspondences.iter().map(|c| c.point).collect();
        group.bench_with_input(BenchmarkId::new("frame_normals", n), &index, |b, i| {
            b.iter(|| i.nearest_normals(black_box(&queries)).len())
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
