//! How uncertain a solved pose is: the Gauss–Newton covariance of its inliers' pixel noise, and
//! the part of the map's own error that no number of inliers averages away.
//!
//! Both are in the camera-to-map parameterisation `(x, y, z, rot x, rot y, rot z)` with
//! `p' = p + δp` and `R_map_cam' = exp([δθ]×)·R_map_cam` (ROS order, perturbed in the map frame).
//!
//! The noise term `σ̂²·(JᵀJ)⁻¹` shrinks as `1/n`: a frame with 600 inliers reads its pose to a
//! few hundredths of a degree. A real map is not that exact. Fused from keyframes whose poses
//! came from SfM or odometry, with a depth camera registered to the colour one by a calibration,
//! its points are off by a fraction of a degree as the camera sees them, and points fused from
//! one keyframe, or one stretch of surface, are off together — an error the inliers of that part
//! of the view share, so it averages over the parts, not over the points. [`map_error_covariance`]
//! models it as an angular error of `σ_map` shared by the points of each region of the view
//! (a `regions × regions` grid) and independent between regions, propagated through the
//! least-squares pose (a sandwich `H⁻¹·Jᵀ C J·H⁻¹`, with `C` the error's covariance over the
//! points). It does not shrink with the number of inliers, only with the regions they cover: a
//! pose whose inliers crowd into one region takes its whole error.

use super::ops::{check_basic, finite_pairs, Cam, MIN_DEPTH};
use super::{MapToCamera, PnpError};
use crate::geometry::Intrinsics;
use nalgebra::{Isometry3, Matrix6, Point2, Point3, SymmetricEigen, Vector2, Vector3, Vector6};

/// Gauss–Newton covariance of the camera-to-map pose over the points `idx`:
/// `σ²·(JᵀJ)⁻¹` with `σ² = Σ|r|² / (2n − 6)`. `None` with fewer than 4 points in front of the
/// camera.
pub(crate) fn covariance(
    cam: &Cam,
    px: &[Vector2<f64>],
    pw: &[Vector3<f64>],
    idx: &[usize],
    pose: &MapToCamera,
) -> Option<Matrix6<f64>> {
    let mut h = Matrix6::zeros();
    let (mut sq, mut n) = (0.0, 0usize);
    for &i in idx {
        let Some(point) = PointJacobian::at(cam, pose, &pw[i]) else { continue };
        let (ru, rv) = (point.projected.x - px[i].x, point.projected.y - px[i].y);
        sq += ru * ru + rv * rv;
        n += 1;
        h += point.information();
    }
    if n < 4 || !sq.is_finite() {
        return None;
    }
    let sigma2 = sq / (2 * n - 6) as f64;
    finite(inverse_information(&h)? * sigma2)
}

/// The map's own error, in what the camera sees: an angle shared by the points of a region of
/// the view, independent between regions (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapError {
    /// Its standard deviation, radians, per image axis.
    pub angle_rad: f64,
    /// The view is split into `regions × regions` parts whose errors are independent.
    pub regions: usize,
}

impl MapError {
    /// The most regions per image axis (4096 in all); more are taken as this many.
    pub const MAX_REGIONS: usize = 64;
}

/// Covariance of a camera-to-map pose given its (inlier) correspondences (the noise term, see
/// the module doc). Needs ≥ 4 finite correspondences in front of the camera.
pub fn pose_covariance(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    pose: &Isometry3<f64>,
) -> Result<Matrix6<f64>, PnpError> {
    check_basic(intrinsics, pixels.len(), points.len())?;
    let pairs = finite_pairs(pixels, points);
    let (px, pw) = (pairs.pixels, pairs.points);
    let idx: Vec<usize> = (0..px.len()).collect();
    let m2c = MapToCamera::from_camera_to_map(pose);
    covariance(&Cam::new(intrinsics), &px, &pw, &idx, &m2c)
        .ok_or(PnpError::TooFewPoints { usable: px.len(), required: 4 })
}

/// What `map_error` adds to the covariance of a camera-to-map pose solved on these (inlier)
/// correspondences: `H⁻¹·(Σ_regions f²·s sᵀ)·H⁻¹·σ_map²`, `s` the sum of a region's Jacobian
/// rows per image axis (module doc). Zero when `map_error.angle_rad` is 0. Needs ≥ 4 finite
/// correspondences in front of the camera.
pub fn map_error_covariance(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    pose: &Isometry3<f64>,
    map_error: &MapError,
) -> Result<Matrix6<f64>, PnpError> {
    check_basic(intrinsics, pixels.len(), points.len())?;
    let pairs = finite_pairs(pixels, points);
    let too_few = || PnpError::TooFewPoints { usable: pairs.pixels.len(), required: 4 };
    let (cam, m2c) = (Cam::new(intrinsics), MapToCamera::from_camera_to_map(pose));
    let regions = map_error.regions.clamp(1, MapError::MAX_REGIONS);
    let region_of = |p: &Vector2<f64>| {
        let cell =
            |v: f64, size: u32| ((v / size.max(1) as f64 * regions as f64).floor().max(0.0) as usize).min(regions - 1);
        cell(p.y, intrinsics.height) * regions + cell(p.x, intrinsics.width)
    };
    let mut h = Matrix6::zeros();
    let mut sums = vec![(Vector6::zeros(), Vector6::zeros()); regions * regions];
    let mut n = 0usize;
    for (pixel, point) in pairs.pixels.iter().zip(&pairs.points) {
        let Some(jacobian) = PointJacobian::at(&cam, &m2c, point) else { continue };
        h += jacobian.information();
        let sum = &mut sums[region_of(pixel)];
        sum.0 += jacobian.u;
        sum.1 += jacobian.v;
        n += 1;
    }
    if n < 4 {
        return Err(too_few());
    }
    let (fu, fv) = (cam.fx * map_error.angle_rad, cam.fy * map_error.angle_rad);
    let shared: Matrix6<f64> =
        sums.iter().map(|(u, v)| u * u.transpose() * (fu * fu) + v * v.transpose() * (fv * fv)).sum();
    let h_inv = inverse_information(&h).ok_or_else(too_few)?;
    finite(h_inv * shared * h_inv).ok_or(PnpError::Degenerate("map error covariance is not finite"))
}

/// One point's projection under a pose and its Jacobian rows (∂u, ∂v over the six parameters).
struct PointJacobian {
    projected: Vector2<f64>,
    u: Vector6<f64>,
    v: Vector6<f64>,
}

impl PointJacobian {
    /// `None` behind the camera (or not finite).
    fn at(cam: &Cam, pose: &MapToCamera, point: &Vector3<f64>) -> Option<Self> {
        let r = pose.rotation;
        let x = r * point + pose.translation;
        if !(x.z > MIN_DEPTH) {
            return None;
        }
        let iz = 1.0 / x.z;
        let projected = Vector2::new(cam.fx * x.x * iz + cam.cx, cam.fy * x.y * iz + cam.cy);
        // ∂x_cam/∂(δp, δθ) = [−R | [x_cam]× R] for p' = p + δp, R_map_cam' = exp([δθ]×) R_map_cam.
        let xr = x.cross_matrix() * r;
        let du = Vector3::new(cam.fx * iz, 0.0, -cam.fx * x.x * iz * iz);
        let dv = Vector3::new(0.0, cam.fy * iz, -cam.fy * x.y * iz * iz);
        let (up, ut) = (-(r.transpose() * du), xr.transpose() * du);
        let (vp, vt) = (-(r.transpose() * dv), xr.transpose() * dv);
        let u = Vector6::new(up.x, up.y, up.z, ut.x, ut.y, ut.z);
        let v = Vector6::new(vp.x, vp.y, vp.z, vt.x, vt.y, vt.z);
        (projected.iter().chain(&u).chain(&v).all(|a| a.is_finite())).then_some(Self { projected, u, v })
    }

    /// Its share of `JᵀJ`.
    fn information(&self) -> Matrix6<f64> {
        self.u * self.u.transpose() + self.v * self.v.transpose()
    }
}

/// `H⁻¹` of an information matrix; unobservable directions get a huge (but finite) variance
/// instead of a panic or NaN. `None` when `H` is not finite or zero.
fn inverse_information(h: &Matrix6<f64>) -> Option<Matrix6<f64>> {
    if !h.iter().all(|v| v.is_finite()) {
        return None;
    }
    let eig = SymmetricEigen::try_new(*h, f64::EPSILON, 1000)?;
    let lmax = eig.eigenvalues.amax();
    if !(lmax.is_finite() && lmax > 0.0) {
        return None;
    }
    let floor = lmax * 1e-14;
    let inv = Vector6::from_iterator(eig.eigenvalues.iter().map(|&l| 1.0 / l.max(floor)));
    Some(eig.eigenvectors * Matrix6::from_diagonal(&inv) * eig.eigenvectors.transpose())
}

/// `m` symmetrised, when every entry is finite.
fn finite(m: Matrix6<f64>) -> Option<Matrix6<f64>> {
    let m = (m + m.transpose()) * 0.5;
    m.iter().all(|v| v.is_finite()).then_some(m)
}
