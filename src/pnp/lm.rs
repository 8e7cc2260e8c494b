//! Levenberg–Marquardt refinement of the pixel reprojection error over SE(3), with IRLS robust
//! weights (the pose's covariance: [`super::covariance`]).
//!
//! The update is a left perturbation of the map-to-camera transform:
//! `x_cam' = exp([ω]×)·x_cam + δt`, so `∂x_cam/∂ω = −[x_cam]×`, `∂x_cam/∂δt = I`.

use super::ops::{checked_pairs, reproj_err2, Cam, MIN_DEPTH};
use super::{MapToCamera, PnpError, RobustLoss};
use crate::geometry::Intrinsics;
use nalgebra::{Isometry3, Matrix3, Matrix6, Point2, Point3, Vector2, Vector3, Vector6};

/// Robust loss `ρ(s)` of a squared residual `s` and its derivative `ρ'(s)` (the IRLS weight).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Loss {
    kind: RobustLoss,
    c2: f64,
    c: f64,
}

impl Loss {
    pub(crate) fn new(kind: RobustLoss, scale: f64) -> Self {
        let c = if scale.is_finite() && scale > 0.0 { scale } else { 1.0 };
        Self { kind, c, c2: c * c }
    }

    #[inline(always)]
    fn eval(&self, s: f64) -> (f64, f64) {
        match self.kind {
            RobustLoss::Trivial => (s, 1.0),
            RobustLoss::Huber => {
                if s <= self.c2 {
                    (s, 1.0)
                } else {
                    let r = s.sqrt();
                    (2.0 * self.c * r - self.c2, self.c / r)
                }
            }
            RobustLoss::Cauchy => {
                let q = 1.0 + s / self.c2;
                (self.c2 * q.ln(), 1.0 / q)
            }
        }
    }
}

/// `exp([ω]×)` by Rodrigues, Taylor near zero.
#[inline(always)]
pub(crate) fn so3_exp(w: &Vector3<f64>) -> Matrix3<f64> {
    let th2 = w.norm_squared();
    let (a, b) = if th2 < 1e-8 {
        (1.0 - th2 / 6.0, 0.5 - th2 / 24.0)
    } else {
        let th = th2.sqrt();
        (th.sin() / th, (1.0 - th.cos()) / th2)
    };
    let k = w.cross_matrix();
    Matrix3::identity() + k * a + k * k * b
}

#[inline(always)]
fn apply(pose: &MapToCamera, d: &Vector6<f64>) -> MapToCamera {
    let r = so3_exp(&Vector3::new(d[0], d[1], d[2]));
    MapToCamera { rotation: r * pose.rotation, translation: r * pose.translation + Vector3::new(d[3], d[4], d[5]) }
}

/// Cost, normal matrix and gradient at `pose` over `idx`, in one pass.
struct Linearization {
    cost: f64,
    h: Matrix6<f64>,
    g: Vector6<f64>,
}

/// Penalty of a point that moved behind the camera (in the loss's units).
fn behind_penalty(loss: &Loss) -> f64 {
    loss.eval(1e8).0
}

fn linearize(
    cam: &Cam,
    px: &[Vector2<f64>],
    pw: &[Vector3<f64>],
    idx: &[usize],
    pose: &MapToCamera,
    loss: &Loss,
) -> Linearization {
    let mut cost = 0.0;
    let mut h = Matrix6::zeros();
    let mut g = Vector6::zeros();
    let penalty = behind_penalty(loss);
    for &i in idx {
        let x = pose.rotation * pw[i] + pose.translation;
        if !(x.z > MIN_DEPTH) {
            cost += penalty;
            continue;
        }
        let iz = 1.0 / x.z;
        let ru = cam.fx * x.x * iz + cam.cx - px[i].x;
        let rv = cam.fy * x.y * iz + cam.cy - px[i].y;
        let (rho, w) = loss.eval(ru * ru + rv * rv);
        cost += rho;
        let (a, c) = (cam.fx * iz, -cam.fx * x.x * iz * iz);
        let (e, f) = (cam.fy * iz, -cam.fy * x.y * iz * iz);
        let ju = Vector6::new(c * x.y, a * x.z - c * x.x, -a * x.y, a, 0.0, c);
        let jv = Vector6::new(-e * x.z + f * x.y, -f * x.x, e * x.x, 0.0, e, f);
        // H is symmetric: its upper triangle is accumulated (each entry the same products in
        // the same order as the full outer products would give it) and mirrored once below.
        for r in 0..6 {
            for c in r..6 {
                h[(r, c)] += (ju[r] * ju[c] + jv[r] * jv[c]) * w;
            }
        }
        g += (ju * ru + jv * rv) * w;
    }
    h.fill_lower_triangle_with_upper_triangle();
    Linearization { cost, h, g }
}

/// LM on the points `idx`; returns the refined pose, its robust cost and the iterations run.
/// Never worse than `pose` in cost.
pub(crate) fn lm_refine(
    cam: &Cam,
    px: &[Vector2<f64>],
    pw: &[Vector3<f64>],
    idx: &[usize],
    mut pose: MapToCamera,
    loss: &Loss,
    max_iterations: usize,
) -> (MapToCamera, f64, usize) {
    let mut lin = linearize(cam, px, pw, idx, &pose, loss);
    let mut mu = 1e-4;
    let mut it = 0;
    while it < max_iterations {
        it += 1;
        if !(lin.cost > 0.0) || !lin.g.iter().chain(lin.h.iter()).all(|v| v.is_finite()) {
            break;
        }
        let mut accepted = false;
        let mut converged = false;
        while mu < 1e10 {
            let mut a = lin.h;
            for k in 0..6 {
                a[(k, k)] += mu * lin.h[(k, k)].max(1e-9);
            }
            let Some(chol) = a.cholesky() else {
                mu *= 10.0;
                continue;
            };
            let delta = -chol.solve(&lin.g);
            if !delta.iter().all(|v| v.is_finite()) {
                mu *= 10.0;
                continue;
            }
            let cand = apply(&pose, &delta);
            let lc = linearize(cam, px, pw, idx, &cand, loss);
            if lc.cost < lin.cost {
                converged = lin.cost - lc.cost < 1e-12 * lin.cost || delta.norm_squared() < 1e-24;
                pose = cand;
                lin = lc;
                mu = (mu * 0.1).max(1e-12);
                accepted = true;
                break;
            }
            mu *= 10.0;
        }
        if !accepted || converged {
            break;
        }
    }
    (pose, lin.cost, it)
}

/// Options of [`refine_pose`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineOptions {
    pub max_iterations: usize,
    pub loss: RobustLoss,
    /// Scale of the robust loss, pixels.
    pub loss_scale_px: f64,
}

impl Default for RefineOptions {
    fn default() -> Self {
        Self { max_iterations: 50, loss: RobustLoss::Trivial, loss_scale_px: 2.0 }
    }
}

/// Result of [`refine_pose`].
#[derive(Clone, Debug, PartialEq)]
pub struct RefineResult {
    /// Camera-to-map pose.
    pub pose: Isometry3<f64>,
    /// Final robust cost (sum of `ρ(|r|²)`, pixels²).
    pub cost: f64,
    /// Plain RMS reprojection error over the points in front of the camera, pixels.
    pub rmse_px: f64,
    pub iterations: usize,
}

/// Levenberg–Marquardt refinement of a camera-to-map pose on all (finite) correspondences,
/// minimising the robust reprojection error in pixels. Needs ≥ 4 finite correspondences and a
/// finite initial pose.
pub fn refine_pose(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    initial: &Isometry3<f64>,
    options: &RefineOptions,
) -> Result<RefineResult, PnpError> {
    let pairs = checked_pairs(intrinsics, pixels, points)?;
    let (px, pw) = (pairs.pixels, pairs.points);
    let start = MapToCamera::from_camera_to_map(initial);
    if !start.is_finite() {
        return Err(PnpError::InvalidParams("non-finite initial pose"));
    }
    Ok(refine_all(&Cam::new(intrinsics), &px, &pw, start, options))
}

/// LM from `start` over all the given correspondences, with the plain RMS reprojection error of
/// the result: the shared tail of [`refine_pose`] and the non-minimal solver.
pub(crate) fn refine_all(
    cam: &Cam,
    px: &[Vector2<f64>],
    pw: &[Vector3<f64>],
    start: MapToCamera,
    options: &RefineOptions,
) -> RefineResult {
    let idx: Vec<usize> = (0..px.len()).collect();
    let loss = Loss::new(options.loss, options.loss_scale_px);
    let (pose, cost, iterations) = lm_refine(cam, px, pw, &idx, start, &loss, options.max_iterations);
    let (mut sq, mut n) = (0.0, 0usize);
    for i in 0..px.len() {
        let e = reproj_err2(cam, &pose, &pw[i], &px[i]);
        if e.is_finite() {
            sq += e;
            n += 1;
        }
    }
    let rmse_px = if n > 0 { (sq / n as f64).sqrt() } else { f64::INFINITY };
    RefineResult { pose: pose.to_camera_to_map(), cost, rmse_px, iterations }
}
