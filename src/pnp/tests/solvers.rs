//! P3P, EPnP and Levenberg–Marquardt on exact and noisy correspondences.

use super::*;

fn check_p3p(seed: u64) -> Result<(), String> {
    let mut rng = WyRand::new(seed);
    let pose = random_pose(&mut rng);
    let (px, pw) = visible(&mut rng, &pose, 3, 0.0);
    let intr = k();
    let bearings = [intr.bearing(&px[0]), intr.bearing(&px[1]), intr.bearing(&px[2])];
    let sols = p3p(&bearings, &[pw[0], pw[1], pw[2]]);
    if sols.is_empty() {
        return Err(format!("seed {seed}: no solution"));
    }
    let best = sols
        .iter()
        .map(|s| pose_error(&s.to_camera_to_map(), &pose))
        .min_by(|a, b| (a.0 + a.1).total_cmp(&(b.0 + b.1)))
        .unwrap();
    if best.0 < 1e-6 && best.1 < 1e-5 {
        Ok(())
    } else {
        Err(format!("seed {seed}: error {best:?}"))
    }
}

#[test]
fn p3p_recovers_exact_pose() {
    let mut failures = Vec::new();
    for seed in 0..2000 {
        if let Err(e) = check_p3p(seed) {
            failures.push(e);
        }
    }
    // Random triples include a few badly conditioned ones; those must be rare.
    assert!(failures.len() <= 4, "{} failures: {:?}", failures.len(), &failures[..failures.len().min(5)]);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    #[test]
    fn p3p_solutions_reproject_their_sample(seed in any::<u64>()) {
        let mut rng = WyRand::new(seed);
        let pose = random_pose(&mut rng);
        let (px, pw) = visible(&mut rng, &pose, 3, 0.0);
        let intr = k();
        let bearings = [intr.bearing(&px[0]), intr.bearing(&px[1]), intr.bearing(&px[2])];
        let sols = p3p(&bearings, &[pw[0], pw[1], pw[2]]);
        prop_assert!(sols.len() <= 4);
        // Every returned pose is a proper rigid motion that reprojects the three points.
        for s in sols.iter() {
            prop_assert!((s.rotation.determinant() - 1.0).abs() < 1e-9);
            for i in 0..3 {
                let xc = s.transform_point(&pw[i]);
                prop_assert!(xc.z > 0.0);
                let q = intr.project(&xc).unwrap();
                prop_assert!((q - px[i]).norm() < 1e-4, "reprojection {}", (q - px[i]).norm());
            }
        }
    }
}

#[test]
fn p3p_rejects_degenerate_samples() {
    let y = [Vector3::new(0.0, 0.0, 1.0), Vector3::new(0.1, 0.0, 1.0), Vector3::new(0.0, 0.1, 1.0)];
    let collinear = [Point3::new(0.0, 0.0, 5.0), Point3::new(1.0, 0.0, 5.0), Point3::new(2.0, 0.0, 5.0)];
    assert!(p3p(&y, &collinear).is_empty());
    let coincident = [Point3::new(0.0, 0.0, 5.0), Point3::new(0.0, 0.0, 5.0), Point3::new(2.0, 0.0, 5.0)];
    assert!(p3p(&y, &coincident).is_empty());
    let pts = [Point3::new(0.0, 0.0, 5.0), Point3::new(1.0, 0.0, 5.0), Point3::new(0.0, 1.0, 5.0)];
    assert!(p3p(&[y[0], y[0], y[2]], &pts).is_empty());
    assert!(p3p(&[Vector3::new(f64::NAN, 0.0, 1.0), y[1], y[2]], &pts).is_empty());
    assert!(p3p(&[Vector3::zeros(), y[1], y[2]], &pts).is_empty());
}

#[test]
fn epnp_and_nonminimal_recover_exact_pose() {
    let mut rng = WyRand::new(7);
    for n in [4usize, 6, 20, 200] {
        for _ in 0..20 {
            let pose = random_pose(&mut rng);
            let (px, pw) = visible(&mut rng, &pose, n, 0.0);
            let e = epnp(&k(), &px, &pw).unwrap();
            let (r, t) = pose_error(&e, &pose);
            if n >= 6 {
                assert!(r < 1e-6 && t < 1e-5, "epnp n={n}: {r} {t}");
            }
            let s = solve_pnp_nonminimal(&k(), &px, &pw, &RefineOptions::default()).unwrap();
            let (r, t) = pose_error(&s.pose, &pose);
            // With 4 points EPnP can pick a wrong branch; LM then stays in its basin.
            if n >= 6 {
                assert!(r < 1e-8 && t < 1e-7, "nonminimal n={n}: {r} {t}");
                assert!(s.rmse_px < 1e-6);
            }
        }
    }
}

#[test]
fn nonminimal_with_noise_is_accurate() {
    let mut rng = WyRand::new(11);
    let pose = random_pose(&mut rng);
    let (px, pw) = visible(&mut rng, &pose, 100, 1.0);
    let s = solve_pnp_nonminimal(&k(), &px, &pw, &RefineOptions::default()).unwrap();
    let (r, t) = pose_error(&s.pose, &pose);
    assert!(r < 2e-3 && t < 0.05, "{r} {t}");
    // RMS of the 2D residual norm: √2·σ for σ = 1 px per axis.
    assert!((s.rmse_px - 2f64.sqrt()).abs() < 0.3, "{}", s.rmse_px);
}

#[test]
fn lm_converges_from_perturbed_pose() {
    let mut rng = WyRand::new(3);
    for _ in 0..20 {
        let pose = random_pose(&mut rng);
        let (px, pw) = visible(&mut rng, &pose, 50, 0.0);
        let delta = Isometry3::from_parts(
            Translation3::new(0.3 * normal(&mut rng), 0.3 * normal(&mut rng), 0.3 * normal(&mut rng)),
            UnitQuaternion::from_scaled_axis(Vector3::new(normal(&mut rng), normal(&mut rng), normal(&mut rng)) * 0.05),
        );
        let start = pose * delta;
        for loss in [RobustLoss::Trivial, RobustLoss::Huber, RobustLoss::Cauchy] {
            let opts = RefineOptions { max_iterations: 100, loss, loss_scale_px: 2.0 };
            let r = refine_pose(&k(), &px, &pw, &start, &opts).unwrap();
            let (er, et) = pose_error(&r.pose, &pose);
            assert!(er < 1e-8 && et < 1e-7, "{loss:?}: {er} {et}");
        }
    }
}
