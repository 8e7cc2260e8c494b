//! The operations every stage of robust PnP shares: the projection of a map point into the
//! pixel it should match (one definition for scoring, local optimisation and refinement), the
//! correspondences in sampling order, and the checks on the inputs.

use nalgebra::{Matrix3, Point2, Point3, SymmetricEigen, Vector2, Vector3};

use super::{MapToCamera, PnpError, PnpParams, Problem};
use crate::geometry::Intrinsics;
use crate::rng::WyRand;

/// Pinhole parameters in the form the inner loops use.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Cam {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Cam {
    pub(crate) fn new(k: &Intrinsics) -> Self {
        Self { fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy }
    }

    /// The unit bearing of a pixel.
    pub(crate) fn bearing(&self, p: &Vector2<f64>) -> Vector3<f64> {
        Vector3::new((p.x - self.cx) / self.fx, (p.y - self.cy) / self.fy, 1.0).normalize()
    }
}

pub(crate) use crate::geometry::MIN_DEPTH;

/// Squared pixel reprojection error, `+∞` behind the camera: the one projection op.
#[inline(always)]
pub(crate) fn reproj_err2(cam: &Cam, pose: &MapToCamera, pw: &Vector3<f64>, px: &Vector2<f64>) -> f64 {
    let x = pose.rotation * pw + pose.translation;
    if !(x.z > MIN_DEPTH) {
        return f64::INFINITY;
    }
    let iz = 1.0 / x.z;
    let du = cam.fx * x.x * iz + cam.cx - px.x;
    let dv = cam.fy * x.y * iz + cam.cy - px.y;
    du * du + dv * dv
}

/// The finite correspondences, compact, and where each came from.
pub(crate) struct FinitePairs {
    pub pixels: Vec<Vector2<f64>>,
    pub points: Vec<Vector3<f64>>,
    /// Index of each in the input.
    pub original: Vec<usize>,
}

/// Validated compact copies of the finite correspondences.
pub(crate) fn finite_pairs(pixels: &[Point2<f64>], points: &[Point3<f64>]) -> FinitePairs {
    let mut out = FinitePairs {
        pixels: Vec::with_capacity(pixels.len()),
        points: Vec::with_capacity(pixels.len()),
        original: Vec::with_capacity(pixels.len()),
    };
    for (i, (p, x)) in pixels.iter().zip(points).enumerate() {
        if p.coords.iter().chain(x.coords.iter()).all(|v| v.is_finite()) {
            out.pixels.push(p.coords);
            out.points.push(x.coords);
            out.original.push(i);
        }
    }
    out
}

/// The finite correspondences of a non-minimal problem, after the basic checks; at least 4.
pub(crate) fn checked_pairs(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
) -> Result<FinitePairs, PnpError> {
    check_basic(intrinsics, pixels.len(), points.len())?;
    let pairs = finite_pairs(pixels, points);
    if pairs.pixels.len() < 4 {
        return Err(PnpError::TooFewPoints { usable: pairs.pixels.len(), required: 4 });
    }
    Ok(pairs)
}

pub(crate) fn check_basic(intrinsics: &Intrinsics, pixels: usize, points: usize) -> Result<(), PnpError> {
    if !intrinsics.is_valid() {
        return Err(PnpError::InvalidIntrinsics);
    }
    if pixels != points {
        return Err(PnpError::LengthMismatch { pixels, points, scores: None });
    }
    Ok(())
}

/// Every per-correspondence guidance slice must have one value per correspondence.
pub(crate) fn check_guidance_length(problem: &Problem, len: Option<usize>) -> Result<(), PnpError> {
    match len {
        Some(l) if l != problem.pixels.len() => Err(PnpError::LengthMismatch {
            pixels: problem.pixels.len(),
            points: problem.points.len(),
            scores: Some(l),
        }),
        _ => Ok(()),
    }
}

pub(crate) fn validate(params: &PnpParams) -> Result<(), PnpError> {
    if !(params.threshold_px.is_finite() && params.threshold_px > 0.0) {
        return Err(PnpError::InvalidParams("threshold_px must be finite and > 0"));
    }
    if !(params.confidence > 0.0 && params.confidence <= 1.0) {
        return Err(PnpError::InvalidParams("confidence must be in (0, 1]"));
    }
    if params.max_iterations == 0 {
        return Err(PnpError::InvalidParams("max_iterations must be > 0"));
    }
    if !(params.loss_scale_px.is_finite() && params.loss_scale_px > 0.0) {
        return Err(PnpError::InvalidParams("loss_scale_px must be finite and > 0"));
    }
    Ok(())
}

/// Rejects coincident or collinear map point sets.
pub(crate) fn check_spread(pw: &[Vector3<f64>]) -> Result<(), PnpError> {
    let n = pw.len() as f64;
    let c = pw.iter().sum::<Vector3<f64>>() / n;
    let mut cov = Matrix3::zeros();
    for p in pw {
        let d = p - c;
        cov += d * d.transpose();
    }
    if !cov.iter().all(|v| v.is_finite()) {
        return Err(PnpError::Degenerate("map point spread overflows"));
    }
    let eig =
        SymmetricEigen::try_new(cov, f64::EPSILON, 1000).ok_or(PnpError::Degenerate("eigen decomposition failed"))?;
    let mut ev: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    if !(ev[0].is_finite() && ev[0] > 0.0) {
        return Err(PnpError::Degenerate("map points coincide"));
    }
    if ev[1] <= 1e-10 * ev[0] {
        return Err(PnpError::Degenerate("map points are collinear"));
    }
    Ok(())
}

/// The usable correspondences stored once in a random order ("positions"), so that scoring
/// streams through memory and SPRT sees an unbiased sequence.
pub(crate) struct Positions {
    pub cam: Cam,
    pub px: Vec<Vector2<f64>>,
    pub pw: Vec<Vector3<f64>>,
    /// Each position's unit bearing, for the minimal solver.
    pub bearings: Vec<Vector3<f64>>,
    /// Each position's index in the input.
    pub original: Vec<usize>,
    /// Squared inlier threshold, pixels².
    pub th2: f64,
}

impl Positions {
    /// The pairs in an order drawn from `rng`.
    pub(crate) fn shuffled(intrinsics: &Intrinsics, pairs: FinitePairs, threshold_px: f64, rng: &mut WyRand) -> Self {
        let mut order: Vec<usize> = (0..pairs.pixels.len()).collect();
        rng.shuffle(&mut order);
        let cam = Cam::new(intrinsics);
        let px: Vec<Vector2<f64>> = order.iter().map(|&i| pairs.pixels[i]).collect();
        Self {
            cam,
            bearings: px.iter().map(|p| cam.bearing(p)).collect(),
            px,
            pw: order.iter().map(|&i| pairs.points[i]).collect(),
            original: order.iter().map(|&i| pairs.original[i]).collect(),
            th2: threshold_px * threshold_px,
        }
    }

    pub(crate) fn len(&self) -> usize {
        self.px.len()
    }

    /// Squared reprojection error at position `pos`.
    #[inline(always)]
    pub(crate) fn err2(&self, pose: &MapToCamera, pos: usize) -> f64 {
        reproj_err2(&self.cam, pose, &self.pw[pos], &self.px[pos])
    }

    /// Depth of the map point at `pos` in the camera of `pose`.
    pub(crate) fn pose_depth(&self, pose: &MapToCamera, pos: usize) -> f64 {
        (pose.rotation * self.pw[pos] + pose.translation).z
    }

    /// The inlier positions of `pose`, ascending.
    pub(crate) fn collect_inliers(&self, pose: &MapToCamera, out: &mut Vec<usize>) {
        out.clear();
        for (i, (p, q)) in self.pw.iter().zip(&self.px).enumerate() {
            if reproj_err2(&self.cam, pose, p, q) < self.th2 {
                out.push(i);
            }
        }
    }
}
