//! The debug image (`node.debug_image`): the camera image with the kept matches green and the
//! rejected ones red, drawn and published by a thread of its own, the newest frame only. A
//! frame's image not yet drawn when the next frame's arrives is superseded (counted,
//! `debug_images_superseded`): drawing never holds up localization, and a flood of large camera
//! images costs one image's decoding at a time (#38: twenty 4096² images queued behind the
//! worker held 370 MB and kept a good frame waiting 3 s).

use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;

use ros2_client::Publisher;

use super::diagnostics::Stats;
use super::image as img;
use super::log::{lock, warn};
use super::recorder::Recorder;
use crate::camera::CameraModel;
use crate::frame::{CameraImage, Correspondence, Frame, Stamp};
use crate::limits::InputLimits;
use crate::msgs;
use crate::pipeline::Localization;

/// What one frame's debug image is drawn from.
#[derive(Clone, Debug)]
pub struct DebugJob {
    stamp: Stamp,
    camera_frame_id: String,
    image: CameraImage,
    lens: Option<CameraModel>,
    all: Vec<Correspondence>,
    kept: Vec<Correspondence>,
}

impl DebugJob {
    /// Of `frame` localized as `loc`; `None` when the frame has no camera image.
    pub fn of(frame: &Frame, loc: &Localization) -> Option<Self> {
        Some(Self {
            stamp: loc.stamp,
            camera_frame_id: loc.camera_frame_id.clone(),
            image: frame.image.clone()?,
            lens: frame.lens.clone(),
            all: frame.correspondences.clone(),
            kept: loc.kept.clone(),
        })
    }
}

/// The newest job waiting, and whether the drawer is to stop.
#[derive(Default)]
struct Slot {
    job: Option<DebugJob>,
    closed: bool,
}

/// The drawer: a thread that draws and publishes the newest submitted frame.
pub struct DebugImages {
    shared: Arc<(Mutex<Slot>, Condvar)>,
    stats: Arc<Mutex<Stats>>,
    thread: Option<JoinHandle<()>>,
}

impl DebugImages {
    /// Starts drawing on its own thread, publishing on `publisher` (`topic`, recorded by
    /// `recorder`), camera images decoded within `limits`.
    pub fn start(
        publisher: Publisher<msgs::Image>,
        topic: String,
        limits: InputLimits,
        recorder: Recorder,
        stats: Arc<Mutex<Stats>>,
    ) -> Self {
        let shared = Arc::new((Mutex::new(Slot::default()), Condvar::new()));
        let (slot, counts) = (shared.clone(), stats.clone());
        let thread = std::thread::Builder::new()
            .name("debug_image".into())
            .spawn(move || {
                while let Some(job) = next_job(&slot) {
                    match draw(&job, &limits) {
                        Ok(msg) => {
                            recorder.write(&topic, &msg, &counts);
                            if let Err(e) = publisher.publish(msg) {
                                warn(format!("publishing on {topic} failed: {e:?}"));
                                lock(&counts).error("publish_failed", format!("{topic}: {e:?}"));
                            }
                        }
                        Err(e) => lock(&counts).error("debug_image", format!("frame {}: {e}", job.stamp)),
                    }
                }
            })
            .map_err(|e| warn(format!("no debug image: cannot start its thread: {e}")))
            .ok();
        Self { shared, stats, thread }
    }

    /// Hands the drawer `frame`'s debug image; one still waiting is superseded (counted).
    pub fn submit(&self, frame: &Frame, loc: &Localization) {
        let Some(job) = DebugJob::of(frame, loc) else {
            lock(&self.stats).error("debug_image", format!("frame {}: no camera image for this frame", loc.stamp));
            return;
        };
        let (slot, wake) = &*self.shared;
        if lock(slot).job.replace(job).is_some() {
            lock(&self.stats).debug_images_superseded += 1;
        }
        wake.notify_one();
    }
}

impl Drop for DebugImages {
    fn drop(&mut self) {
        let (slot, wake) = &*self.shared;
        lock(slot).closed = true;
        wake.notify_one();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// The next job to draw, waiting for one; `None` once the drawer is closed.
fn next_job(shared: &(Mutex<Slot>, Condvar)) -> Option<DebugJob> {
    let (slot, wake) = shared;
    let mut guard = lock(slot);
    loop {
        if guard.closed {
            return None;
        }
        if let Some(job) = guard.job.take() {
            return Some(job);
        }
        guard = wake.wait(guard).unwrap_or_else(std::sync::PoisonError::into_inner);
    }
}

/// The longest side of the debug image: a larger camera image is scaled down to it before the
/// matches are drawn (a viewer's image; a 4096² one held as rgb8 in the publisher is 50 MB).
pub const DEBUG_IMAGE_MAX_SIDE: u32 = 1920;

/// The camera image (rgb8, scaled down to [`DEBUG_IMAGE_MAX_SIDE`] when larger) with kept
/// correspondences as green and rejected ones as red 5×5 squares, at the matcher's pixels of
/// the (raw) image: a frame whose pixels were undistorted for the localizer (`lens`) has
/// them distorted back. A compressed image is decoded here, within `limits`.
fn draw(job: &DebugJob, limits: &InputLimits) -> Result<msgs::Image, String> {
    let mut rgb = img::from_encoded(&job.image, limits)?;
    let longest = rgb.width().max(rgb.height());
    let scale = if longest > DEBUG_IMAGE_MAX_SIDE { f64::from(DEBUG_IMAGE_MAX_SIDE) / f64::from(longest) } else { 1.0 };
    if scale < 1.0 {
        let (w, h) = ((f64::from(rgb.width()) * scale).round(), (f64::from(rgb.height()) * scale).round());
        rgb = image::imageops::thumbnail(&rgb, (w as u32).max(1), (h as u32).max(1));
    }
    let in_image = |cs: &[Correspondence]| -> Vec<Correspondence> {
        let raw = |c: &Correspondence| job.lens.as_ref().map_or(c.pixel, |lens| lens.distort_pixel(&c.pixel));
        cs.iter().map(|c| Correspondence { pixel: (raw(c).coords * scale).into(), ..*c }).collect()
    };
    img::draw_matches(&mut rgb, &in_image(&job.all), &in_image(&job.kept));
    Ok(img::image_msg(job.stamp, &job.camera_frame_id, rgb))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Distortion;
    use crate::geometry::Intrinsics;
    use crate::pipeline::Method;
    use nalgebra::{Point2, Point3};

    #[test]
    fn the_debug_image_draws_undistorted_matches_at_their_raw_pixels() {
        let raw = Intrinsics { fx: 300.0, fy: 300.0, cx: 160.0, cy: 120.0, width: 320, height: 240 };
        let lens = CameraModel {
            raw,
            distortion: Distortion::PlumbBob([-0.3, 0.1, 0.0, 0.0, 0.0]),
            projection: [0.0; 12],
            unsupported_model: None,
        };
        // Near a corner, where the lens moves pixels most: the matcher saw (290, 220).
        let seen = Point2::new(290.0, 220.0);
        let ideal = lens.undistort_pixel(&seen).expect("inside the lens' range");
        assert!((ideal - seen).norm() > 10.0, "the test needs a visible displacement");
        let c = Correspondence { pixel: ideal, point: Point3::origin(), score: 1.0 };
        let frame = Frame {
            stamp: 1,
            camera_frame_id: "cam".into(),
            map_frame_id: "map".into(),
            intrinsics: raw,
            correspondences: vec![c],
            depth_prior: None,
            image: Some(CameraImage::Raw(image::RgbImage::new(320, 240))),
            ground_truth: None,
            lens: Some(lens),
            odometry: None,
        };
        let loc = Localization { kept: vec![c], ..Localization::nothing_yet(&frame, Method::AngleI2p) };
        let msg = draw(&DebugJob::of(&frame, &loc).expect("an image"), &InputLimits::default()).expect("an image");
        let at = |x: f64, y: f64| {
            let i = (y.round() as usize * msg.width as usize + x.round() as usize) * 3;
            [msg.data[i], msg.data[i + 1], msg.data[i + 2]]
        };
        assert_eq!(at(seen.x, seen.y), img::KEPT, "drawn where the matcher saw it");
        assert_eq!(at(ideal.x, ideal.y), [0, 0, 0], "not at the undistorted pixel");
    }

    /// A camera image larger than the debug image's bound is scaled down to it, the matches
    /// drawn where they are in the scaled image (#38: 4096² images held whole made the node's
    /// memory grow by 50 MB an image).
    #[test]
    fn a_large_camera_image_gives_a_bounded_debug_image() {
        let k = Intrinsics { fx: 3000.0, fy: 3000.0, cx: 1920.0, cy: 1080.0, width: 3840, height: 2160 };
        let c = Correspondence { pixel: Point2::new(3000.0, 1000.0), point: Point3::origin(), score: 1.0 };
        let frame = Frame {
            stamp: 1,
            camera_frame_id: "cam".into(),
            map_frame_id: "map".into(),
            intrinsics: k,
            correspondences: vec![c],
            depth_prior: None,
            image: Some(CameraImage::Raw(image::RgbImage::new(3840, 2160))),
            ground_truth: None,
            lens: None,
            odometry: None,
        };
        let loc = Localization { kept: vec![c], ..Localization::nothing_yet(&frame, Method::AngleI2p) };
        let msg = draw(&DebugJob::of(&frame, &loc).expect("an image"), &InputLimits::default()).expect("an image");
        assert_eq!((msg.width, msg.height), (DEBUG_IMAGE_MAX_SIDE, 1080));
        let i = (500 * msg.width as usize + 1500) * 3;
        assert_eq!([msg.data[i], msg.data[i + 1], msg.data[i + 2]], img::KEPT, "the match, scaled by ½");
    }
}
