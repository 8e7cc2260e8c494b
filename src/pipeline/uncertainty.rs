//! The covariance a published pose carries: its inliers' pixel noise, and the map's own error
//! that no number of inliers averages away ([`crate::pnp::map_error_covariance`]).

use nalgebra::{Isometry3, Matrix6, Point2, Point3};
use serde::{Deserialize, Serialize};

use crate::frame::Frame;
use crate::pnp::{map_error_covariance, MapError};

/// What the published covariance counts beside the inliers' pixel noise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CovarianceParams {
    /// The map's accuracy as the camera sees it: the standard deviation, in degrees per image
    /// axis, of the direction error its points share with their neighbours in the view (points
    /// fused from one keyframe, or registered by one depth-to-colour calibration, are off
    /// together). Maps fused from keyframes whose poses came from SfM or odometry are off by
    /// 0.5–1.5° per keyframe; 1° is the middle. A map surveyed to millimetres can set it lower;
    /// 0 publishes the inliers' pixel noise alone, which reads a frame with hundreds of inliers
    /// to a few hundredths of a degree and put the true pose inside the published 95 % ellipsoid
    /// on 0–5 % of the redkitchen poses and 0–35 % of the office presets' (docs/method.md, step
    /// 10).
    pub map_error_deg: f64,
    /// The view is split into `map_error_regions × map_error_regions` parts whose shares of
    /// the map's error are independent: the error averages over the parts of the view the
    /// inliers cover, not over the inliers.
    pub map_error_regions: usize,
}

impl Default for CovarianceParams {
    fn default() -> Self {
        Self { map_error_deg: 1.0, map_error_regions: 3 }
    }
}

impl CovarianceParams {
    /// The covariance to publish for `pose`, solved on `frame` with the pixel-noise covariance
    /// `measured`: the map's error added over the frame's correspondences within
    /// `threshold_px` of the pose. `measured` alone when the map's error is off or cannot be
    /// propagated (fewer than 4 correspondences agree).
    pub fn published(
        &self,
        frame: &Frame,
        pose: &Isometry3<f64>,
        measured: &Matrix6<f64>,
        threshold_px: f64,
    ) -> Matrix6<f64> {
        if self.map_error_deg.is_nan() || self.map_error_deg <= 0.0 {
            return *measured;
        }
        let k = &frame.intrinsics;
        let to_camera = pose.inverse();
        let (pixels, points): (Vec<Point2<f64>>, Vec<Point3<f64>>) = frame
            .correspondences
            .iter()
            .filter(|c| k.reprojection_error(&to_camera.transform_point(&c.point), &c.pixel) < threshold_px)
            .map(|c| (c.pixel, c.point))
            .unzip();
        let map_error = MapError { angle_rad: self.map_error_deg.to_radians(), regions: self.map_error_regions };
        match map_error_covariance(k, &pixels, &points, pose, &map_error) {
            Ok(shared) => measured + shared,
            Err(_) => *measured,
        }
    }
}
