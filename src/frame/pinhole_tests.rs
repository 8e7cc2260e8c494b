use nalgebra::{Point2, Point3};

use super::*;
use crate::camera::Distortion;
use crate::frame::Correspondence;
use crate::geometry::{DepthImage, Intrinsics};

fn k() -> Intrinsics {
    Intrinsics { fx: 600.0, fy: 610.0, cx: 322.0, cy: 241.0, width: 640, height: 480 }
}

fn barrel() -> Distortion {
    Distortion::PlumbBob([-0.28, 0.09, 0.001, -0.0005, -0.01])
}

/// A frame with placeholder intrinsics (the rectifier sets them).
fn frame_of(correspondences: Vec<Correspondence>) -> Frame {
    Frame {
        stamp: 1,
        camera_frame_id: "cam".into(),
        map_frame_id: "map".into(),
        intrinsics: Intrinsics { fx: 1.0, ..k() },
        correspondences,
        depth_prior: None,
        image: None,
        ground_truth: None,
        lens: None,
        odometry: None,
    }
}

/// A frame of points seen by the distorting camera: raw pixels, and a prior whose value is the
/// raw pixel's column (so where it was read from can be checked).
fn raw_frame(model: &CameraModel, points: &[Point3<f64>]) -> (Frame, Vec<Point2<f64>>) {
    let ideal: Vec<Point2<f64>> = points.iter().map(|p| model.raw.project(p).unwrap()).collect();
    let correspondences = ideal
        .iter()
        .zip(points)
        .map(|(px, p)| Correspondence { pixel: model.distort_pixel(px), point: *p, score: 1.0 })
        .collect();
    let (w, h) = (model.raw.width, model.raw.height);
    let prior = DepthImage::new(w, h, (0..w * h).map(|i| (i % w) as f32 + 1.0).collect());
    let mut frame = frame_of(correspondences);
    frame.depth_prior = Some(prior);
    (frame, ideal)
}

#[test]
fn rectifier_undistorts_pixels_and_resamples_the_prior() {
    let mut model = CameraModel::pinhole(k());
    model.distortion = barrel();
    let points: Vec<Point3<f64>> =
        (0..40).map(|i| Point3::new((i % 8) as f64 * 0.2 - 0.7, (i / 8) as f64 * 0.2 - 0.4, 2.0)).collect();
    let (mut frame, ideal) = raw_frame(&model, &points);
    let raw_pixels: Vec<Point2<f64>> = frame.correspondences.iter().map(|c| c.pixel).collect();
    let mut rectifier = PinholeRectifier::new(PixelSpace::Raw);
    let report = rectifier.apply(&model, &mut frame).unwrap();
    assert_eq!(report, RectifyReport { dropped: 0, remapped: true });
    assert_eq!(frame.intrinsics, k());
    let prior = frame.depth_prior.as_ref().unwrap();
    for ((c, want), raw) in frame.correspondences.iter().zip(&ideal).zip(&raw_pixels) {
        assert!((c.pixel - want).norm() < 1e-6, "{:?} vs {want:?}", c.pixel);
        // Outputs map kept pixels back through the frame's lens (`Frame::lens`).
        let back = model.distort_pixel(&c.pixel);
        assert!((back - raw).norm() < 1e-6);
        // The resampled prior at the ideal pixel holds the raw pixel's column (nearest sample).
        let value = prior.at(c.pixel.x.round() as i64, c.pixel.y.round() as i64).unwrap() as f64 - 1.0;
        assert!((value - raw.x).abs() <= 1.6, "prior read at column {value}, raw pixel at {}", raw.x);
    }
}

#[test]
fn rectifier_leaves_a_distortion_free_frame_bit_for_bit() {
    let model = CameraModel::pinhole(k());
    let points = [Point3::new(0.1, -0.2, 1.5), Point3::new(-0.3, 0.2, 2.5)];
    let (mut frame, _) = raw_frame(&model, &points);
    let (pixels, prior) = (frame.correspondences.clone(), frame.depth_prior.clone());
    let report = PinholeRectifier::new(PixelSpace::Raw).apply(&model, &mut frame).unwrap();
    assert_eq!(report, RectifyReport::default());
    assert_eq!(frame.correspondences, pixels);
    assert_eq!(frame.depth_prior, prior);
    assert_eq!(frame.intrinsics, k());
}

#[test]
fn pixels_the_lens_model_cannot_invert_are_dropped_and_counted() {
    let mut model = CameraModel::pinhole(k());
    model.distortion = Distortion::PlumbBob([-0.5, 0.0, 0.0, 0.0, 0.0]);
    let mut frame = frame_of(vec![
        Correspondence { pixel: Point2::new(330.0, 250.0), point: Point3::new(0.0, 0.0, 1.0), score: 1.0 },
        Correspondence { pixel: Point2::new(322.0 + 3.0 * 600.0, 241.0), point: Point3::origin(), score: 1.0 },
    ]);
    let report = PinholeRectifier::new(PixelSpace::Raw).apply(&model, &mut frame).unwrap();
    assert_eq!(report, RectifyReport { dropped: 1, remapped: true });
    assert_eq!(frame.correspondences.len(), 1);
}
