use nalgebra::Vector2;

use super::*;

fn k() -> Intrinsics {
    Intrinsics { fx: 600.0, fy: 610.0, cx: 322.0, cy: 241.0, width: 640, height: 480 }
}

fn models() -> Vec<Distortion> {
    vec![
        Distortion::PlumbBob([-0.28, 0.09, 0.001, -0.0005, -0.01]),
        Distortion::RationalPolynomial([0.4, -0.1, 0.0008, 0.0003, 0.02, 0.7, -0.05, 0.01]),
        Distortion::Equidistant([-0.03, 0.01, -0.004, 0.0008]),
    ]
}

#[test]
fn coefficients_from_camera_info() {
    assert_eq!(Distortion::from_ros("plumb_bob", &[0.0; 5]), Ok(Distortion::None));
    assert_eq!(Distortion::from_ros("plumb_bob", &[]), Ok(Distortion::None));
    assert_eq!(
        Distortion::from_ros("plumb_bob", &[0.1, 0.2, 0.3, 0.4]),
        Ok(Distortion::PlumbBob([0.1, 0.2, 0.3, 0.4, 0.0]))
    );
    let fourteen: Vec<f64> = (1..=14).map(|i| i as f64 * 0.01).collect();
    assert!(matches!(Distortion::from_ros("rational_polynomial", &fourteen), Ok(Distortion::RationalPolynomial(_))));
    assert!(matches!(Distortion::from_ros("equidistant", &[0.1, 0.0, 0.0, 0.0]), Ok(Distortion::Equidistant(_))));
    assert_eq!(
        Distortion::from_ros("equidistant", &[0.1]),
        Err(CameraModelError::Coefficients { model: "equidistant", needed: 4, got: 1 })
    );
    assert!(matches!(Distortion::from_ros("kannala", &[0.1; 4]), Err(CameraModelError::UnknownModel { .. })));
    assert!(matches!(
        Distortion::from_ros("plumb_bob", &[0.1, f64::NAN, 0.0, 0.0, 0.0]),
        Err(CameraModelError::NonFinite { index: 1, .. })
    ));
}

#[test]
fn non_finite_coefficients_are_refused() {
    let err = Distortion::from_ros("plumb_bob", &[0.1, f64::INFINITY, 0.0, 0.0, 0.0]).unwrap_err();
    assert_eq!(err, CameraModelError::NonFinite { index: 1, value: f64::INFINITY });
}

#[test]
fn plumb_bob_matches_a_hand_computed_value() {
    let d = Distortion::PlumbBob([0.1, 0.0, 0.0, 0.0, 0.0]);
    let out = d.distort(Vector2::new(0.5, 0.0));
    assert!((out.x - 0.5 * (1.0 + 0.1 * 0.25)).abs() < 1e-15 && out.y == 0.0);
    let fisheye = Distortion::Equidistant([0.0; 4]);
    let out = fisheye.distort(Vector2::new(1.0, 0.0));
    assert!((out.x - std::f64::consts::FRAC_PI_4).abs() < 1e-15, "θ_d = atan(1) with no coefficients");
}

#[test]
fn undistort_inverts_distort_across_the_field_of_view() {
    for d in models() {
        for i in -6..=6 {
            for j in -5..=5 {
                let p = Vector2::new(i as f64 * 0.1, j as f64 * 0.1);
                let back = d.undistort(d.distort(p)).unwrap_or_else(|| panic!("{d:?} at {p:?}"));
                assert!((back - p).norm() < 1e-8, "{d:?}: {p:?} came back as {back:?}");
            }
        }
    }
}

#[test]
fn undistort_gives_up_where_a_model_folds_over() {
    // Strong barrel distortion folds back beyond r ≈ 1.1: such pixels have no inverse.
    let d = Distortion::PlumbBob([-0.5, 0.0, 0.0, 0.0, 0.0]);
    assert_eq!(d.undistort(Vector2::new(3.0, 0.0)), None);
}

#[test]
fn rectified_pixels_use_p_and_refuse_a_stereo_second_camera() {
    let mut model = CameraModel::pinhole(k());
    model.distortion = models()[0];
    model.projection = [580.0, 0.0, 320.5, 0.0, 0.0, 585.0, 240.5, 0.0, 0.0, 0.0, 1.0, 0.0];
    let rect = model.core_intrinsics(PixelSpace::Rectified).unwrap();
    assert_eq!((rect.fx, rect.fy, rect.cx, rect.cy, rect.width), (580.0, 585.0, 320.5, 240.5, 640));
    assert_eq!(model.core_intrinsics(PixelSpace::Raw).unwrap(), k());
    assert!(!model.distorts(PixelSpace::Rectified) && model.distorts(PixelSpace::Raw));
    model.projection[3] = -58.0;
    assert_eq!(
        model.core_intrinsics(PixelSpace::Rectified),
        Err(CameraModelError::StereoProjection { tx: -58.0, ty: 0.0 })
    );
    model.projection = [0.0; 12];
    assert_eq!(model.core_intrinsics(PixelSpace::Rectified).unwrap(), k(), "an empty P means K");
}
