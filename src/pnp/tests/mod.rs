//! Tests of robust PnP: the minimal and non-minimal solvers (`solvers`), the robust
//! estimation around them (`robust`) and its verification (`verification`), on shared
//! synthetic scenes.

use super::*;
use crate::geometry::Intrinsics;
use crate::rng::WyRand;
use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

/// Robust PnP with scores only (the tests' common case).
fn ransac(
    k: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    scores: Option<&[f32]>,
    params: &PnpParams,
    seed: u64,
) -> Result<PnpSolution, PnpError> {
    ransac_guided(k, pixels, points, &Guidance { scores, ..Guidance::default() }, params, seed)
}

/// Robust PnP with scores and prior depths.
fn ransac_with_prior(
    k: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    scores: Option<&[f32]>,
    prior_depths: Option<&[f64]>,
    params: &PnpParams,
    seed: u64,
) -> Result<PnpSolution, PnpError> {
    ransac_guided(k, pixels, points, &Guidance { scores, prior_depths, ..Guidance::default() }, params, seed)
}

/// [`solve_pnp_ransac`] with the seed given apart.
fn ransac_guided(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    guidance: &Guidance,
    params: &PnpParams,
    seed: u64,
) -> Result<PnpSolution, PnpError> {
    let problem = Problem { intrinsics, pixels, points };
    solve_pnp_ransac(&problem, guidance, &PnpParams { seed, ..params.clone() })
}

fn k() -> Intrinsics {
    Intrinsics { fx: 600.0, fy: 580.0, cx: 320.0, cy: 240.0, width: 640, height: 480 }
}

fn uniform(rng: &mut WyRand, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

fn normal(rng: &mut WyRand) -> f64 {
    let u1 = uniform(rng, 1e-12, 1.0);
    let u2 = uniform(rng, 0.0, 1.0);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// A random camera-to-map pose.
fn random_pose(rng: &mut WyRand) -> Isometry3<f64> {
    let axis = Vector3::new(normal(rng), normal(rng), normal(rng));
    let angle = uniform(rng, 0.0, std::f64::consts::PI);
    let q = UnitQuaternion::from_scaled_axis(axis.normalize() * angle);
    let t = Vector3::new(uniform(rng, -20.0, 20.0), uniform(rng, -20.0, 20.0), uniform(rng, -5.0, 5.0));
    Isometry3::from_parts(Translation3::from(t), q)
}

/// Visible map points with their (noisy) pixels under camera-to-map `pose`.
fn visible(rng: &mut WyRand, pose: &Isometry3<f64>, n: usize, noise_px: f64) -> (Vec<Point2<f64>>, Vec<Point3<f64>>) {
    let intr = k();
    let mut px = Vec::with_capacity(n);
    let mut pw = Vec::with_capacity(n);
    for _ in 0..n {
        let p = Point2::new(uniform(rng, 0.0, 640.0), uniform(rng, 0.0, 480.0));
        let xc = intr.back_project(&p, uniform(rng, 2.0, 25.0));
        pw.push(pose * xc);
        px.push(Point2::new(p.x + noise_px * normal(rng), p.y + noise_px * normal(rng)));
    }
    (px, pw)
}

/// `n` map points visible from `pose`, each matched to a random pixel (uncorrelated outliers).
fn random_pixel_matches(rng: &mut WyRand, pose: &Isometry3<f64>, n: usize) -> (Vec<Point2<f64>>, Vec<Point3<f64>>) {
    let (_, points) = visible(rng, pose, n, 0.0);
    let pixels = points.iter().map(|_| Point2::new(uniform(rng, 0.0, 640.0), uniform(rng, 0.0, 480.0))).collect();
    (pixels, points)
}

/// Replaces a fraction of the correspondences by random pixel ↔ map point pairs; returns the
/// ground-truth inlier flags.
fn corrupt(rng: &mut WyRand, px: &mut [Point2<f64>], pw: &[Point3<f64>], outlier_ratio: f64) -> Vec<bool> {
    let n = px.len();
    let n_out = (n as f64 * outlier_ratio).round() as usize;
    let mut idx: Vec<usize> = (0..n).collect();
    rng.shuffle(&mut idx);
    let mut truth = vec![true; n];
    for &i in &idx[..n_out] {
        px[i] = Point2::new(uniform(rng, 0.0, 640.0), uniform(rng, 0.0, 480.0));
        truth[i] = false;
    }
    let _ = pw;
    truth
}

fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let d = a.inverse() * b;
    (d.rotation.angle(), (a.translation.vector - b.translation.vector).norm())
}

/// A pose, its pixels and map points, and which correspondences are true.
type Scenario = (Isometry3<f64>, Vec<Point2<f64>>, Vec<Point3<f64>>, Vec<bool>);

/// `n` matches of a random pose with 1 px noise, `outlier_ratio` of them corrupted.
fn scenario(seed: u64, n: usize, outlier_ratio: f64) -> Scenario {
    let mut rng = WyRand::new(seed);
    let pose = random_pose(&mut rng);
    let (mut px, pw) = visible(&mut rng, &pose, n, 1.0);
    let truth = corrupt(&mut rng, &mut px, &pw, outlier_ratio);
    (pose, px, pw, truth)
}

mod robust;
mod solvers;
mod verification;
