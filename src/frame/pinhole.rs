//! A frame in the core's pinhole camera: [`PinholeRectifier`] applies a
//! [`CameraModel`](crate::camera::CameraModel) to a frame's pixels, prior and intrinsics (see
//! [`crate::camera`]), caching the prior's resampling table per camera.

use super::Frame;
use crate::camera::{resample_depth, CameraModel, CameraModelError, PixelSpace};

/// What [`PinholeRectifier::apply`] did to a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RectifyReport {
    /// Correspondences whose pixel the lens model could not undistort (left out).
    pub dropped: usize,
    /// Whether pixels and prior were remapped (raw pixels of a distorting lens).
    pub remapped: bool,
}

/// Turns frames into the core's pinhole frames (see the module docs); one per camera stream,
/// so the prior's resampling table is built once per camera model and prior size.
#[derive(Debug, Default)]
pub struct PinholeRectifier {
    pub space: PixelSpace,
    table: Option<ResampleTable>,
}

#[derive(Debug)]
struct ResampleTable {
    model: CameraModel,
    width: u32,
    height: u32,
    source: Vec<Option<u32>>,
}

impl PinholeRectifier {
    pub fn new(space: PixelSpace) -> Self {
        Self { space, table: None }
    }

    /// Sets `frame.intrinsics` to the core camera of `model` and, for raw pixels of a distorting
    /// lens, undistorts every correspondence (dropping those that do not invert) and resamples
    /// the prior onto the ideal grid.
    pub fn apply(&mut self, model: &CameraModel, frame: &mut Frame) -> Result<RectifyReport, CameraModelError> {
        frame.intrinsics = model.core_intrinsics(self.space)?;
        if !model.distorts(self.space) {
            return Ok(RectifyReport::default());
        }
        let before = frame.correspondences.len();
        frame.correspondences.retain_mut(|c| match model.undistort_pixel(&c.pixel) {
            Some(p) => {
                c.pixel = p;
                true
            }
            None => false,
        });
        if let Some(prior) = frame.depth_prior.as_mut() {
            *prior = resample_depth(prior, self.table_for(model, prior.width, prior.height));
        }
        Ok(RectifyReport { dropped: before - frame.correspondences.len(), remapped: true })
    }

    fn table_for(&mut self, model: &CameraModel, width: u32, height: u32) -> &[Option<u32>] {
        let fresh = |t: &ResampleTable| t.model == *model && t.width == width && t.height == height;
        if !self.table.as_ref().is_some_and(fresh) {
            let source = model.resample_table(width, height);
            self.table = Some(ResampleTable { model: model.clone(), width, height, source });
        }
        self.table.as_ref().map(|t| t.source.as_slice()).unwrap_or(&[])
    }
}

#[cfg(test)]
#[path = "pinhole_tests.rs"]
mod tests;
