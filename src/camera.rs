//! The camera a `sensor_msgs/CameraInfo` describes, reduced to the ideal pinhole camera the
//! core works in.
//!
//! ROS cameras come in two pixel spaces (image_geometry's `PinholeCameraModel`):
//! - **raw** pixels (`image_raw`): K with lens distortion D (`plumb_bob`,
//!   `rational_polynomial`, `equidistant`). A raw pixel is undistorted into the distortion-free
//!   camera with the same K, and a depth prior computed on the raw image is resampled onto that
//!   camera's grid, so the pose stays the pose of the optical frame. R and P are not used (they
//!   describe the rectified image, which raw pixels are not in).
//! - **rectified** pixels (`image_rect`, what `image_proc` publishes): already distortion-free,
//!   in the camera of P's left 3×3; D is not used. A P with a translation (`Tx`, `Ty`: the second
//!   camera of a stereo pair) is refused, since the pose would then be of another frame.
//!
//! `frame::pinhole::PinholeRectifier` applies this to whole frames (pixels, prior, intrinsics),
//! once per frame where the edges assemble it.

use nalgebra::{Point2, Vector2};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::geometry::{DepthImage, Intrinsics};

/// Which pixel space the correspondences (and the depth prior) are in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelSpace {
    /// The raw image CameraInfo describes: undistorted with K and D.
    #[default]
    Raw,
    /// The rectified image (`image_proc`): intrinsics from P, no distortion.
    Rectified,
}

/// A camera model that cannot be used.
#[derive(Debug, Error, PartialEq)]
pub enum CameraModelError {
    #[error("distortion model {model:?} is not supported (plumb_bob, rational_polynomial, equidistant)")]
    UnknownModel { model: String },
    #[error("distortion model {model} needs {needed} coefficients, got {got}")]
    Coefficients { model: &'static str, needed: usize, got: usize },
    #[error("distortion coefficient {index} is not finite ({value})")]
    NonFinite { index: usize, value: f64 },
    #[error(
        "P has a translation (Tx={tx}, Ty={ty}): a stereo pair's second camera; use its left camera's P or raw pixels"
    )]
    StereoProjection { tx: f64, ty: f64 },
    #[error("P's intrinsics are not usable: fx={fx} fy={fy} cx={cx} cy={cy}")]
    BadProjection { fx: f64, fy: f64, cx: f64, cy: f64 },
}

/// Lens distortion of normalized image coordinates (OpenCV's models, as ROS names them).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Distortion {
    None,
    /// `plumb_bob`: k1, k2, p1, p2, k3 (Brown–Conrady).
    PlumbBob([f64; 5]),
    /// `rational_polynomial`: k1, k2, p1, p2, k3, k4, k5, k6.
    RationalPolynomial([f64; 8]),
    /// `equidistant` (fisheye): k1, k2, k3, k4 on the angle θ = atan(r).
    Equidistant([f64; 4]),
}

/// Steps of the iterative inversions, and the residual (normalized units) they must reach.
const MAX_STEPS: usize = 50;
const TOLERANCE: f64 = 1e-10;

impl Distortion {
    /// From CameraInfo's `distortion_model` and `d`. Missing trailing coefficients of
    /// `plumb_bob`/`rational_polynomial` are zero (drivers send 4 or 5, 8 or 14); all-zero
    /// coefficients (or an empty `d`) mean no distortion.
    pub fn from_ros(model: &str, d: &[f64]) -> Result<Self, CameraModelError> {
        if let Some((index, &value)) = d.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(CameraModelError::NonFinite { index, value });
        }
        if d.iter().all(|&v| v == 0.0) {
            return Ok(Distortion::None);
        }
        let padded = |n: usize, name: &'static str| -> Result<Vec<f64>, CameraModelError> {
            if d.len() < 4 {
                return Err(CameraModelError::Coefficients { model: name, needed: n, got: d.len() });
            }
            Ok((0..n).map(|i| d.get(i).copied().unwrap_or(0.0)).collect())
        };
        match model {
            "plumb_bob" | "" => {
                let c = padded(5, "plumb_bob")?;
                Ok(Distortion::PlumbBob([c[0], c[1], c[2], c[3], c[4]]))
            }
            "rational_polynomial" => {
                let c = padded(8, "rational_polynomial")?;
                Ok(Distortion::RationalPolynomial([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
            }
            "equidistant" | "fisheye" => match d {
                [k1, k2, k3, k4, ..] => Ok(Distortion::Equidistant([*k1, *k2, *k3, *k4])),
                _ => Err(CameraModelError::Coefficients { model: "equidistant", needed: 4, got: d.len() }),
            },
            other => Err(CameraModelError::UnknownModel { model: other.to_string() }),
        }
    }

    pub fn is_none(&self) -> bool {
        matches!(self, Distortion::None)
    }

    /// Distorts normalized coordinates (x, y) = (X/Z, Y/Z).
    pub fn distort(&self, p: Vector2<f64>) -> Vector2<f64> {
        match *self {
            Distortion::None => p,
            Distortion::Equidistant(k) => {
                let r = p.norm();
                if r < 1e-12 {
                    return p;
                }
                p * (equidistant_angle(r.atan(), k) / r)
            }
            _ => p * self.radial(p) + self.tangential(p),
        }
    }

    /// Inverts [`distort`](Self::distort); `None` where the model does not converge (far outside
    /// the calibrated field of view).
    pub fn undistort(&self, distorted: Vector2<f64>) -> Option<Vector2<f64>> {
        match *self {
            Distortion::None => Some(distorted),
            Distortion::Equidistant(k) => undistort_equidistant(distorted, k),
            _ => self.undistort_brown(distorted),
        }
    }

    /// OpenCV's scheme for the Brown models: p ← (p_d − tangential(p)) / radial(p), iterated
    /// until p distorts back onto p_d.
    fn undistort_brown(&self, distorted: Vector2<f64>) -> Option<Vector2<f64>> {
        let mut p = distorted;
        for _ in 0..MAX_STEPS {
            if (self.distort(p) - distorted).norm() < TOLERANCE {
                return Some(p);
            }
            let radial = self.radial(p);
            if !(radial.is_finite() && radial > 1e-6) {
                return None;
            }
            p = (distorted - self.tangential(p)) / radial;
        }
        ((self.distort(p) - distorted).norm() < 1e-6).then_some(p)
    }

    /// The radial factor (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶) of the Brown
    /// models (k4..k6 are zero for plumb_bob); 1 for the others.
    fn radial(&self, p: Vector2<f64>) -> f64 {
        let k = match *self {
            Distortion::PlumbBob([k1, k2, _, _, k3]) => [k1, k2, k3, 0.0, 0.0, 0.0],
            Distortion::RationalPolynomial([k1, k2, _, _, k3, k4, k5, k6]) => [k1, k2, k3, k4, k5, k6],
            _ => return 1.0,
        };
        let r2 = p.norm_squared();
        let (r4, r6) = (r2 * r2, r2 * r2 * r2);
        (1.0 + k[0] * r2 + k[1] * r4 + k[2] * r6) / (1.0 + k[3] * r2 + k[4] * r4 + k[5] * r6)
    }

    /// The tangential (decentring) term of the Brown models; zero for the others.
    fn tangential(&self, p: Vector2<f64>) -> Vector2<f64> {
        let (p1, p2) = match *self {
            Distortion::PlumbBob([_, _, p1, p2, _]) | Distortion::RationalPolynomial([_, _, p1, p2, ..]) => (p1, p2),
            _ => return Vector2::zeros(),
        };
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        Vector2::new(2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x), p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)
    }
}

/// θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸).
fn equidistant_angle(theta: f64, k: [f64; 4]) -> f64 {
    let t2 = theta * theta;
    theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
}

/// Newton on θ_d(θ) = |x_d| over θ ∈ [0, π/2), then r = tan θ along x_d's direction.
fn undistort_equidistant(distorted: Vector2<f64>, k: [f64; 4]) -> Option<Vector2<f64>> {
    let rd = distorted.norm();
    if rd < 1e-12 {
        return Some(distorted);
    }
    let mut theta = rd.min(1.5);
    for _ in 0..MAX_STEPS {
        let f = equidistant_angle(theta, k) - rd;
        if f.abs() < TOLERANCE {
            break;
        }
        let t2 = theta * theta;
        let slope = 1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])));
        if !(slope.is_finite() && slope.abs() > 1e-9) {
            return None;
        }
        theta = (theta - f / slope).clamp(0.0, 1.57);
    }
    let converged = (equidistant_angle(theta, k) - rd).abs() < 1e-6 && theta < 1.57;
    converged.then(|| distorted * (theta.tan() / rd))
}

/// What a CameraInfo says about the camera: K, D and P's left 3×3 (with its translation).
#[derive(Clone, Debug, PartialEq)]
pub struct CameraModel {
    /// The raw image's intrinsics (K) and size.
    pub raw: Intrinsics,
    pub distortion: Distortion,
    /// P as sent (row-major 3×4); all zero when the driver left it empty.
    pub projection: [f64; 12],
    /// A distortion model this build does not know (`distortion` is then `None`): raw pixels
    /// of such a camera are refused with its name, rectified ones (which do not use D) are fine.
    pub unsupported_model: Option<String>,
}

impl CameraModel {
    /// A distortion-free camera whose rectified intrinsics are its raw ones.
    pub fn pinhole(intrinsics: Intrinsics) -> Self {
        let k = &intrinsics;
        let projection = [k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0];
        Self { raw: intrinsics, distortion: Distortion::None, projection, unsupported_model: None }
    }

    /// The pinhole camera the core works in for pixels in `space`.
    pub fn core_intrinsics(&self, space: PixelSpace) -> Result<Intrinsics, CameraModelError> {
        match (space, &self.unsupported_model) {
            (PixelSpace::Raw, Some(model)) => Err(CameraModelError::UnknownModel { model: model.clone() }),
            (PixelSpace::Raw, None) => Ok(self.raw),
            (PixelSpace::Rectified, _) => self.rectified_intrinsics(),
        }
    }

    /// P's left 3×3 (the raw K when P is empty, as some drivers leave it for raw-only cameras).
    fn rectified_intrinsics(&self) -> Result<Intrinsics, CameraModelError> {
        let p = &self.projection;
        if p.iter().all(|&v| v == 0.0) {
            return Ok(self.raw);
        }
        let (tx, ty) = (p[3], p[7]);
        if tx != 0.0 || ty != 0.0 {
            return Err(CameraModelError::StereoProjection { tx, ty });
        }
        let k = Intrinsics { fx: p[0], fy: p[5], cx: p[2], cy: p[6], ..self.raw };
        if !k.is_valid() {
            return Err(CameraModelError::BadProjection { fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy });
        }
        Ok(k)
    }

    /// Whether pixels of `space` need mapping at all (raw pixels of a distorting lens).
    pub fn distorts(&self, space: PixelSpace) -> bool {
        space == PixelSpace::Raw && !self.distortion.is_none()
    }

    /// A raw pixel in the distortion-free camera with the same K; `None` where the model does
    /// not invert.
    pub fn undistort_pixel(&self, pixel: &Point2<f64>) -> Option<Point2<f64>> {
        let k = &self.raw;
        let distorted = Vector2::new((pixel.x - k.cx) / k.fx, (pixel.y - k.cy) / k.fy);
        let p = self.distortion.undistort(distorted)?;
        let out = Point2::new(k.fx * p.x + k.cx, k.fy * p.y + k.cy);
        (out.x.is_finite() && out.y.is_finite()).then_some(out)
    }

    /// The inverse of [`undistort_pixel`](Self::undistort_pixel): an ideal pixel back in the raw image.
    pub fn distort_pixel(&self, pixel: &Point2<f64>) -> Point2<f64> {
        let k = &self.raw;
        let p = self.distortion.distort(Vector2::new((pixel.x - k.cx) / k.fx, (pixel.y - k.cy) / k.fy));
        Point2::new(k.fx * p.x + k.cx, k.fy * p.y + k.cy)
    }

    /// For each pixel of a `width`×`height` image on the ideal camera's grid (the prior's own
    /// resolution, pixel centres mapped as [`DepthImage::sample`] does), the raw-grid pixel to
    /// read, row-major; `None` outside the raw image.
    pub fn resample_table(&self, width: u32, height: u32) -> Vec<Option<u32>> {
        let (sx, sy) = (width as f64 / self.raw.width as f64, height as f64 / self.raw.height as f64);
        let mut table = Vec::with_capacity(width as usize * height as usize);
        for v in 0..height {
            for u in 0..width {
                let ideal = Point2::new((u as f64 + 0.5) / sx - 0.5, (v as f64 + 0.5) / sy - 0.5);
                let raw = self.distort_pixel(&ideal);
                let (ru, rv) = (((raw.x + 0.5) * sx - 0.5).round(), ((raw.y + 0.5) * sy - 0.5).round());
                let inside = ru >= 0.0 && rv >= 0.0 && ru < width as f64 && rv < height as f64;
                table.push(inside.then(|| rv as u32 * width + ru as u32));
            }
        }
        table
    }
}

/// Resamples `prior` through `table` (from [`CameraModel::resample_table`] at its size); pixels
/// without a source are unknown (0).
pub fn resample_depth(prior: &DepthImage, table: &[Option<u32>]) -> DepthImage {
    let data =
        table.iter().map(|source| source.and_then(|i| prior.data.get(i as usize).copied()).unwrap_or(0.0)).collect();
    DepthImage { width: prior.width, height: prior.height, data }
}

#[cfg(test)]
#[path = "camera_tests.rs"]
mod tests;
