//! A distorting lens: raw pixels are undistorted with CameraInfo's D before PnP (`camera.pixels:
//! raw`), and the kept correspondences go back out in the matcher's own raw pixels.

use angle_i2p::camera::{CameraModel, Distortion, PixelSpace};
use angle_i2p::frame::{Assembled, Frame, FrameAssembler, FramePart};
use angle_i2p::msgs::convert;
use angle_i2p::pipeline::{Localizer, LocalizerParams, Method};
use angle_i2p::synth::{generate, SynthConfig};

/// Rotation error (degrees) and translation error (m) of the ransac pose of `frame`'s parts assembled with `camera`.
fn pose_error(frame: &Frame, camera: CameraModel, space: PixelSpace) -> ([f64; 2], Frame) {
    let mut assembler = FrameAssembler::new(&[]).with_pixel_space(space);
    let stamp = frame.stamp;
    assert!(assembler.push(FramePart::CameraInfo { stamp, camera }, 0).is_none());
    let part = FramePart::Correspondences {
        stamp,
        camera_frame_id: frame.camera_frame_id.clone(),
        map_frame_id: frame.map_frame_id.clone(),
        correspondences: frame.correspondences.clone(),
    };
    let Some(Assembled::Complete(assembled)) = assembler.push(part, 0) else { panic!("a complete frame") };
    let params = LocalizerParams { method: Method::Ransac, ..LocalizerParams::default() };
    let loc = Localizer::new(params).expect("a ransac localizer").process(&assembled);
    let pose = loc.pose.expect("a pose");
    let truth = frame.ground_truth.as_ref().and_then(|g| g.pose).expect("ground truth");
    let d = truth.inverse() * pose;
    ([d.rotation.angle().to_degrees(), d.translation.vector.norm()], assembled)
}

#[test]
fn raw_pixels_of_a_distorting_lens_are_undistorted_before_pnp() {
    let scene = generate(&SynthConfig { frames: 3, seed: 3, ..SynthConfig::preset("sift").expect("sift") });
    let lens = Distortion::PlumbBob([-0.28, 0.09, 0.001, -0.0005, 0.0]);
    let (mut undistorted_sum, mut ignored_sum) = ([0.0; 2], [0.0; 2]);
    for ideal in &scene.frames {
        let mut camera = CameraModel::pinhole(ideal.intrinsics);
        camera.distortion = lens;
        // What a matcher on the raw image reports: the ideal pixels moved by the lens.
        let mut raw = ideal.clone();
        raw.correspondences.iter_mut().for_each(|c| c.pixel = camera.distort_pixel(&c.pixel));
        let (undistorted, assembled) = pose_error(&raw, camera.clone(), PixelSpace::Raw);
        let (ignored, _) = pose_error(&raw, CameraModel::pinhole(ideal.intrinsics), PixelSpace::Raw);
        for k in 0..2 {
            undistorted_sum[k] += undistorted[k];
            ignored_sum[k] += ignored[k];
        }
        // The kept correspondences are published in the matcher's raw pixels.
        let params = LocalizerParams { method: Method::Ransac, ..LocalizerParams::default() };
        let loc = Localizer::new(params).expect("a localizer").process(&assembled);
        let out = convert::localization_messages(&loc, assembled.lens.as_ref());
        let sent = convert::correspondences_from_msg(&out.kept).expect("kept");
        assert!(!sent.is_empty());
        // (the message carries f32 pixels and points)
        for c in &sent {
            let near = raw
                .correspondences
                .iter()
                .any(|r| (r.point - c.point).norm() < 1e-4 && (r.pixel - c.pixel).norm() < 1e-3);
            assert!(near, "kept pixel {:?} is not one the matcher sent", c.pixel);
        }
    }
    let n = scene.frames.len() as f64;
    let [rot, trans] = undistorted_sum.map(|v| v / n);
    let [rot_ignored, trans_ignored] = ignored_sum.map(|v| v / n);
    eprintln!("mean error with D {rot:.3}° {trans:.4} m; D ignored {rot_ignored:.3}° {trans_ignored:.4} m");
    assert!(rot < 0.5 && trans < 0.02, "with D applied: {rot:.3}° {trans:.4} m");
    assert!(trans_ignored > 1.5 * trans && rot_ignored > rot, "D ignored should be worse");
}

#[test]
fn a_stereo_second_cameras_projection_is_refused_with_its_reason() {
    let scene = generate(&SynthConfig { frames: 1, seed: 4, ..SynthConfig::preset("sift").expect("sift") });
    let frame = &scene.frames[0];
    let mut camera = CameraModel::pinhole(frame.intrinsics);
    camera.projection[3] = -40.0;
    let mut assembler = FrameAssembler::new(&[]).with_pixel_space(PixelSpace::Rectified);
    assembler.push(FramePart::CameraInfo { stamp: frame.stamp, camera }, 0);
    let part = FramePart::Correspondences {
        stamp: frame.stamp,
        camera_frame_id: "cam".into(),
        map_frame_id: "map".into(),
        correspondences: frame.correspondences.clone(),
    };
    match assembler.push(part, 0) {
        Some(Assembled::Dropped(r)) => assert!(r.errors.iter().any(|e| e.contains("Tx=-40")), "{:?}", r.errors),
        other => panic!("expected a dropped frame, got {:?}", other.map(|_| "a frame")),
    }
}
