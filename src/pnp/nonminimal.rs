//! Non-minimal PnP: EPnP then Levenberg–Marquardt, on correspondences assumed to be inliers.

use nalgebra::{Point2, Point3, Vector2};

use super::epnp::epnp_normalized;
use super::lm::{refine_all, RefineOptions, RefineResult};
use super::ops::{checked_pairs, Cam};
use super::PnpError;
use crate::geometry::Intrinsics;

/// Non-minimal PnP: EPnP on all finite correspondences (≥ 4 non-planar map points, assumed
/// inliers) then Levenberg–Marquardt on the reprojection error. The pose is camera-to-map.
pub fn solve_pnp_nonminimal(
    intrinsics: &Intrinsics,
    pixels: &[Point2<f64>],
    points: &[Point3<f64>],
    options: &RefineOptions,
) -> Result<RefineResult, PnpError> {
    let pairs = checked_pairs(intrinsics, pixels, points)?;
    let (px, pw) = (pairs.pixels, pairs.points);
    let cam = Cam::new(intrinsics);
    let uv: Vec<Vector2<f64>> =
        px.iter().map(|p| Vector2::new((p.x - cam.cx) / cam.fx, (p.y - cam.cy) / cam.fy)).collect();
    let init = epnp_normalized(&uv, &pw)?;
    Ok(refine_all(&cam, &px, &pw, init, options))
}
