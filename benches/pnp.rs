//! Robust PnP benchmarks: LO-RANSAC (uniform) and PROSAC at N = 400/1000/2000 with ~15 %
//! inliers, and the non-minimal solver (EPnP + LM) on 100 inliers.

use angle_i2p::geometry::Intrinsics;
use angle_i2p::pnp::{
    solve_pnp_nonminimal, solve_pnp_ransac, Guidance, PnpParams, PnpSolution, Problem, RefineOptions,
};
use angle_i2p::rng::SplitMix64;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion, Vector3};
use std::hint::black_box;
use std::time::Duration;

/// The crate's splitmix64, with the ranges the problems need.
struct Gen(SplitMix64);

impl Gen {
    fn next(&mut self) -> f64 {
        self.0.next_f64()
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
    fn normal(&mut self) -> f64 {
        let u1 = self.range(1e-12, 1.0);
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * self.next()).cos()
    }
}

fn intrinsics() -> Intrinsics {
    Intrinsics { fx: 600.0, fy: 600.0, cx: 320.0, cy: 240.0, width: 640, height: 480 }
}

struct Synthetic {
    pixels: Vec<Point2<f64>>,
    points: Vec<Point3<f64>>,
    scores: Vec<f32>,
}

/// `n` correspondences, a fraction `inlier_ratio` of them correct (1 px noise); scores rank
/// inliers high with overlap (inliers U(0.4, 1), outliers U(0, 0.7)).
fn problem(seed: u64, n: usize, inlier_ratio: f64) -> Synthetic {
    let mut g = Gen(SplitMix64(seed));
    let k = intrinsics();
    let pose = Isometry3::from_parts(
        Translation3::new(3.0, -2.0, 1.0),
        UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -1.2, 0.2)),
    );
    let n_in = (n as f64 * inlier_ratio).round() as usize;
    let mut pixels = Vec::with_capacity(n);
    let mut points = Vec::with_capacity(n);
    let mut scores = Vec::with_capacity(n);
    for i in 0..n {
        let p = Point2::new(g.range(0.0, 640.0), g.range(0.0, 480.0));
        points.push(pose * k.back_project(&p, g.range(2.0, 30.0)));
        if i < n_in {
            pixels.push(Point2::new(p.x + g.normal(), p.y + g.normal()));
            scores.push(g.range(0.4, 1.0) as f32);
        } else {
            pixels.push(Point2::new(g.range(0.0, 640.0), g.range(0.0, 480.0)));
            scores.push(g.range(0.0, 0.7) as f32);
        }
    }
    Synthetic { pixels, points, scores }
}

/// One robust solve of `p`, seeded.
fn solve(k: &Intrinsics, p: &Synthetic, scores: Option<&[f32]>, params: &PnpParams, seed: u64) -> Option<PnpSolution> {
    let problem = Problem { intrinsics: k, pixels: &p.pixels, points: &p.points };
    let guidance = Guidance { scores, ..Guidance::default() };
    solve_pnp_ransac(&problem, &guidance, &PnpParams { seed, ..params.clone() }).ok()
}

fn bench(c: &mut Criterion) {
    let k = intrinsics();
    let params = PnpParams::default();
    let mut group = c.benchmark_group("pnp_ransac");
    group.sample_size(10).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_millis(500));
    for n in [400usize, 1000, 2000] {
        let p = problem(n as u64, n, 0.15);
        group.bench_with_input(BenchmarkId::new("uniform_15pct", n), &p, |b, p| {
            let mut seed = 0;
            b.iter(|| {
                seed += 1;
                black_box(solve(&k, p, None, &params, seed))
            })
        });
        group.bench_with_input(BenchmarkId::new("prosac_15pct", n), &p, |b, p| {
            let mut seed = 0;
            b.iter(|| {
                seed += 1;
                black_box(solve(&k, p, Some(&p.scores), &params, seed))
            })
        });
    }
    // Fixed budget for comparison with PoseLib's LO-RANSAC (10k iterations on 400 points).
    let fixed = PnpParams { min_iterations: 10_000, max_iterations: 10_000, ..params.clone() };
    let p = problem(400, 400, 0.15);
    group.bench_function("uniform_10k_iterations/400", |b| b.iter(|| black_box(solve(&k, &p, None, &fixed, 1))));
    group.finish();

    let mut group = c.benchmark_group("pnp_nonminimal");
    group.sample_size(20).measurement_time(Duration::from_secs(2)).warm_up_time(Duration::from_millis(500));
    let p = problem(7, 100, 1.0);
    group.bench_function("epnp_lm_100", |b| {
        b.iter(|| black_box(solve_pnp_nonminimal(&k, &p.pixels, &p.points, &RefineOptions::default()).ok()))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
