//! Robust PnP: sampling, scoring, coverage, prior depths, gating and stopping.

use super::*;

#[test]
fn ransac_finds_pose_with_80_percent_outliers() {
    for seed in 0..5 {
        let (pose, px, pw, truth) = scenario(100 + seed, 500, 0.8);
        let sol = ransac(&k(), &px, &pw, None, &PnpParams::default(), seed).unwrap();
        let (r, t) = pose_error(&sol.pose, &pose);
        assert!(r < 5e-3 && t < 0.1, "seed {seed}: {r} {t}");
        let true_inliers = truth.iter().filter(|&&b| b).count();
        let agree = sol.inliers.iter().zip(&truth).filter(|(a, b)| **a && **b).count();
        assert!(agree as f64 > 0.97 * true_inliers as f64, "{agree}/{true_inliers}");
        assert!(sol.num_inliers < true_inliers + 10);
        assert!(sol.rmse_px < 2.0, "{}", sol.rmse_px);
        assert!(sol.iterations >= 100 && sol.iterations <= 10_000);
    }
}

#[test]
fn prosac_needs_fewer_iterations_when_scores_rank_inliers_high() {
    let mut uniform_iters = 0;
    let mut prosac_iters = 0;
    for seed in 0..4 {
        let (pose, px, pw, truth) = scenario(200 + seed, 1000, 0.85);
        let mut rng = WyRand::new(seed);
        // Inliers score higher on average, with overlap.
        let scores: Vec<f32> = truth
            .iter()
            .map(|&t| if t { uniform(&mut rng, 0.4, 1.0) } else { uniform(&mut rng, 0.0, 0.7) } as f32)
            .collect();
        let params = PnpParams::default();
        let u = ransac(&k(), &px, &pw, None, &params, seed).unwrap();
        let p = ransac(&k(), &px, &pw, Some(&scores), &params, seed).unwrap();
        for s in [&u, &p] {
            let (r, t) = pose_error(&s.pose, &pose);
            assert!(r < 5e-3 && t < 0.1, "seed {seed}: {r} {t}");
        }
        uniform_iters += u.iterations;
        prosac_iters += p.iterations;
    }
    assert!(prosac_iters * 3 < uniform_iters, "prosac {prosac_iters} vs uniform {uniform_iters}");
}

#[test]
fn ransac_is_deterministic_for_a_seed() {
    let (_, px, pw, _) = scenario(5, 300, 0.7);
    let a = ransac(&k(), &px, &pw, None, &PnpParams::default(), 42).unwrap();
    let b = ransac(&k(), &px, &pw, None, &PnpParams::default(), 42).unwrap();
    assert_eq!(a, b);
}

#[test]
fn pose_is_camera_to_map() {
    let (pose, px, pw, _) = scenario(9, 200, 0.0);
    let sol = ransac(&k(), &px, &pw, None, &PnpParams::default(), 1).unwrap();
    // x_map = pose * x_cam: the camera centre in the map is the pose's translation.
    assert!((sol.pose.translation.vector - pose.translation.vector).norm() < 0.05);
    let xc = sol.pose.inverse() * pw[0];
    let q = k().project(&xc).unwrap();
    assert!((q - px[0]).norm() < 5.0);
}

#[test]
fn degenerate_and_invalid_inputs_are_errors() {
    let intr = k();
    let params = PnpParams::default();
    // Too few points.
    let (_, px, pw, _) = scenario(1, 3, 0.0);
    assert!(matches!(ransac(&intr, &px, &pw, None, &params, 0), Err(PnpError::TooFewPoints { .. })));
    assert!(solve_pnp_nonminimal(&intr, &px, &pw, &RefineOptions::default()).is_err());
    assert!(epnp(&intr, &px, &pw).is_err());
    // Collinear map points.
    let pw: Vec<Point3<f64>> = (0..50).map(|i| Point3::new(i as f64 * 0.1, 0.0, 5.0)).collect();
    let px: Vec<Point2<f64>> = pw.iter().map(|p| intr.project(p).unwrap()).collect();
    assert!(matches!(ransac(&intr, &px, &pw, None, &params, 0), Err(PnpError::Degenerate(_))));
    assert!(solve_pnp_nonminimal(&intr, &px, &pw, &RefineOptions::default()).is_err());
    // All NaN.
    let nan_px = vec![Point2::new(f64::NAN, 1.0); 50];
    let nan_pw = vec![Point3::new(1.0, f64::NAN, 1.0); 50];
    assert!(matches!(ransac(&intr, &nan_px, &nan_pw, None, &params, 0), Err(PnpError::TooFewPoints { .. })));
    assert!(solve_pnp_nonminimal(&intr, &nan_px, &nan_pw, &RefineOptions::default()).is_err());
    assert!(refine_pose(&intr, &nan_px, &nan_pw, &Isometry3::identity(), &RefineOptions::default()).is_err());
    // Bad intrinsics, lengths, parameters.
    let (_, px, pw, _) = scenario(2, 50, 0.0);
    let bad = Intrinsics { fx: f64::NAN, ..intr };
    assert_eq!(ransac(&bad, &px, &pw, None, &params, 0), Err(PnpError::InvalidIntrinsics));
    assert!(matches!(ransac(&intr, &px[..10], &pw, None, &params, 0), Err(PnpError::LengthMismatch { .. })));
    assert!(matches!(ransac(&intr, &px, &pw, Some(&[1.0; 3]), &params, 0), Err(PnpError::LengthMismatch { .. })));
    let p = PnpParams { threshold_px: f64::NAN, ..params.clone() };
    assert!(matches!(ransac(&intr, &px, &pw, None, &p, 0), Err(PnpError::InvalidParams(_))));
    // Pure outliers: no consensus (or, by chance, a tiny one), never a panic.
    let mut rng = WyRand::new(3);
    let rnd_px: Vec<Point2<f64>> =
        (0..100).map(|_| Point2::new(uniform(&mut rng, 0.0, 640.0), uniform(&mut rng, 0.0, 480.0))).collect();
    let rnd_pw: Vec<Point3<f64>> = (0..100)
        .map(|_| Point3::new(uniform(&mut rng, -5.0, 5.0), uniform(&mut rng, -5.0, 5.0), uniform(&mut rng, 1.0, 9.0)))
        .collect();
    let strict = PnpParams { min_inliers: 20, ..params.clone() };
    assert!(matches!(ransac(&intr, &rnd_px, &rnd_pw, None, &strict, 0), Err(PnpError::NoConsensus { .. })));
}

#[test]
fn non_finite_correspondences_are_ignored() {
    let (pose, mut px, mut pw, _) = scenario(4, 200, 0.5);
    px[3] = Point2::new(f64::NAN, 0.0);
    pw[7] = Point3::new(f64::INFINITY, 0.0, 1.0);
    let mut scores = vec![0.5f32; 200];
    scores[9] = f32::NAN;
    let sol = ransac(&k(), &px, &pw, Some(&scores), &PnpParams::default(), 0).unwrap();
    assert!(!sol.inliers[3] && !sol.inliers[7]);
    let (r, t) = pose_error(&sol.pose, &pose);
    assert!(r < 5e-3 && t < 0.1, "{r} {t}");
}

fn is_psd(c: &nalgebra::Matrix6<f64>) -> bool {
    let eig = nalgebra::SymmetricEigen::new(*c);
    eig.eigenvalues.iter().all(|&l| l >= -1e-12 * eig.eigenvalues.amax())
}

#[test]
fn covariance_is_symmetric_psd_and_shrinks_with_more_points() {
    let mut traces = Vec::new();
    for n in [40usize, 400] {
        let mut rng = WyRand::new(77);
        let pose = random_pose(&mut rng);
        let (px, pw) = visible(&mut rng, &pose, n, 1.0);
        let sol = ransac(&k(), &px, &pw, None, &PnpParams::default(), 0).unwrap();
        let c = sol.covariance;
        assert!((c - c.transpose()).amax() <= 1e-12 * c.amax());
        assert!(is_psd(&c));
        let direct = pose_covariance(&k(), &px, &pw, &sol.pose).unwrap();
        assert!((direct - c).amax() < 1e-6 * c.amax() + 1e-15);
        // Position standard deviation roughly matches the actual error scale.
        traces.push(c.trace());
    }
    assert!(traces[1] < 0.3 * traces[0], "{traces:?}");
}

#[test]
fn covariance_matches_monte_carlo_spread() {
    // Fixed geometry, many noise draws: the empirical position spread matches the predicted one.
    let mut rng = WyRand::new(5);
    let pose = random_pose(&mut rng);
    let (clean, pw) = visible(&mut rng, &pose, 60, 0.0);
    let mut errs = Vec::new();
    let mut predicted = nalgebra::Matrix6::zeros();
    let runs = 200;
    for _ in 0..runs {
        let px: Vec<Point2<f64>> =
            clean.iter().map(|p| Point2::new(p.x + normal(&mut rng), p.y + normal(&mut rng))).collect();
        let s = solve_pnp_nonminimal(&k(), &px, &pw, &RefineOptions::default()).unwrap();
        predicted += pose_covariance(&k(), &px, &pw, &s.pose).unwrap() / runs as f64;
        errs.push(covariance_error(&s.pose, &pose));
    }
    assert_spread_matches(&errs, &predicted);
}

/// The error of `est` against `truth` in the covariances' parameterisation: position, and
/// rotation in the map frame (`R_est = exp([δθ]×)·R_true`).
fn covariance_error(est: &Isometry3<f64>, truth: &Isometry3<f64>) -> nalgebra::Vector6<f64> {
    let d = est.translation.vector - truth.translation.vector;
    let dr = (est.rotation * truth.rotation.inverse()).scaled_axis();
    nalgebra::Vector6::new(d.x, d.y, d.z, dr.x, dr.y, dr.z)
}

/// Each axis's empirical variance over `errs` is within 0.6–1.6× the `predicted` one.
fn assert_spread_matches(errs: &[nalgebra::Vector6<f64>], predicted: &nalgebra::Matrix6<f64>) {
    for i in 0..6 {
        let emp = errs.iter().map(|e| e[i] * e[i]).sum::<f64>() / errs.len() as f64;
        let ratio = emp / predicted[(i, i)];
        assert!((0.6..1.6).contains(&ratio), "axis {i}: empirical {emp} predicted {} ratio {ratio}", predicted[(i, i)]);
    }
}

#[test]
fn params_deserialize_with_defaults() {
    let p: PnpParams = serde_yaml::from_str("threshold_px: 4.0\nloss: cauchy\n").unwrap();
    assert_eq!(p.threshold_px, 4.0);
    assert_eq!(p.loss, RobustLoss::Cauchy);
    assert_eq!(p.max_iterations, 10_000);
    assert_eq!(p.min_inliers, 6);
    assert_eq!(p.confidence, 0.9999);
}

/// Success rate and cost over inlier ratios (run with `--ignored --nocapture`).
#[test]
#[ignore]
fn stress_success_rates() {
    for &n in &[300usize, 1000] {
        for &ratio in &[0.05, 0.08, 0.1, 0.15, 0.3, 0.55] {
            let trials = 40;
            let mut ok = 0;
            let mut iters = 0;
            let mut worst_r: f64 = 0.0;
            let t0 = std::time::Instant::now();
            for seed in 0..trials {
                let (pose, px, pw, _) = scenario(1000 + seed, n, 1.0 - ratio);
                if let Ok(s) = ransac(&k(), &px, &pw, None, &PnpParams::default(), seed) {
                    let (r, t) = pose_error(&s.pose, &pose);
                    iters += s.iterations;
                    if r < 1e-2 && t < 0.2 {
                        ok += 1;
                    } else {
                        worst_r = worst_r.max(r);
                    }
                }
            }
            let ms = t0.elapsed().as_secs_f64() * 1e3 / trials as f64;
            println!("n={n} inliers={ratio}: {ok}/{trials} ok, mean iters {}, {ms:.2} ms/solve, worst wrong rot {worst_r:.3}", iters / trials as usize);
        }
    }
}

/// P3P throughput (run with `--release --ignored --nocapture`).
#[test]
#[ignore]
fn p3p_timing() {
    let mut rng = WyRand::new(1);
    let pose = random_pose(&mut rng);
    let (px, pw) = visible(&mut rng, &pose, 300, 1.0);
    let intr = k();
    let b: Vec<Vector3<f64>> = px.iter().map(|p| intr.bearing(p)).collect();
    let t0 = std::time::Instant::now();
    let mut total = 0;
    for _ in 0..100_000 {
        let (a, c, d) = (rng.below(300), rng.below(300), rng.below(300));
        if a == c || a == d || c == d {
            continue;
        }
        total += p3p(&[b[a], b[c], b[d]], &[pw[a], pw[c], pw[d]]).len();
    }
    println!("p3p: {:.3} µs/call, {:.2} sols/call", t0.elapsed().as_secs_f64() * 1e6 / 1e5, total as f64 / 1e5);
}

#[test]
fn extreme_values_do_not_panic() {
    let intr = k();
    let (_, mut px, mut pw, _) = scenario(8, 100, 0.3);
    for i in 0..10 {
        pw[i] = Point3::new(1e200, -1e200, 1e200);
        px[i + 10] = Point2::new(1e300, -1e300);
    }
    let _ = ransac(&intr, &px, &pw, None, &PnpParams::default(), 0);
    let _ = solve_pnp_nonminimal(&intr, &px, &pw, &RefineOptions::default());
    let _ = epnp(&intr, &px, &pw);
    let huge: Vec<Point3<f64>> =
        (0..20).map(|i| Point3::new(1e200 * i as f64, 1e199 * (i * i) as f64, 1e200)).collect();
    let hp: Vec<Point2<f64>> = (0..20).map(|i| Point2::new(i as f64, (i * 7 % 13) as f64)).collect();
    assert!(ransac(&intr, &hp, &huge, None, &PnpParams::default(), 0).is_err());
    let _ = solve_pnp_nonminimal(&intr, &hp, &huge, &RefineOptions::default());
    let bad_pose = Isometry3::from_parts(Translation3::new(f64::NAN, 0.0, 0.0), UnitQuaternion::identity());
    assert!(refine_pose(&intr, &px, &pw, &bad_pose, &RefineOptions::default()).is_err());
    let _ = pose_covariance(&intr, &px, &pw, &bad_pose);
}

#[test]
fn ransac_handles_planar_maps() {
    // A wall 8 m in front of the camera: EPnP is degenerate there, RANSAC (P3P + LM) is not.
    let mut rng = WyRand::new(21);
    let pose = random_pose(&mut rng);
    let intr = k();
    let mut px = Vec::new();
    let mut pw = Vec::new();
    for _ in 0..300 {
        let p = Point2::new(uniform(&mut rng, 0.0, 640.0), uniform(&mut rng, 0.0, 480.0));
        pw.push(pose * intr.back_project(&p, 8.0));
        px.push(Point2::new(p.x + normal(&mut rng), p.y + normal(&mut rng)));
    }
    corrupt(&mut rng, &mut px, &pw, 0.6);
    let sol = ransac(&intr, &px, &pw, None, &PnpParams::default(), 0).unwrap();
    let (r, t) = pose_error(&sol.pose, &pose);
    assert!(r < 1e-2 && t < 0.2, "{r} {t}");
    assert!(matches!(epnp(&intr, &px, &pw), Err(PnpError::Degenerate(_))));
}

/// 12 true matches spread over the image, 20 matches in one 40 px patch whose map points were
/// displaced together (they agree with one wrong pose), 60 random outliers: counting inliers
/// picks the patch's pose, counting covered cells picks the true one.
#[test]
fn coverage_scoring_prefers_spread_support_over_a_displaced_patch() {
    let mut rng = WyRand::new(7);
    let pose = random_pose(&mut rng);
    let intr = k();
    let (mut px, mut pw) = visible(&mut rng, &pose, 12, 0.5);
    let moved = Isometry3::new(Vector3::new(0.8, -0.5, 0.3), Vector3::new(0.2, 0.4, -0.1));
    for _ in 0..20 {
        let p = Point2::new(uniform(&mut rng, 300.0, 340.0), uniform(&mut rng, 200.0, 240.0));
        let xc = intr.back_project(&p, uniform(&mut rng, 4.0, 5.0));
        px.push(p);
        pw.push(moved * (pose * xc));
    }
    let (random_px, random_pw) = random_pixel_matches(&mut rng, &pose, 60);
    px.extend(random_px);
    pw.extend(random_pw);
    let params = PnpParams { max_iterations: 20_000, ..PnpParams::default() };
    let by_count =
        ransac(&intr, &px, &pw, None, &PnpParams { coverage_cell_px: 0.0, ..params.clone() }, 1).expect("a pose");
    let by_cells = ransac(&intr, &px, &pw, None, &PnpParams { coverage_cell_px: 32.0, ..params }, 1).expect("a pose");
    let (rot, trans) = pose_error(&by_cells.pose, &pose);
    assert!(rot < 0.01 && trans < 0.05, "coverage: {rot} rad, {trans} m off");
    assert!(by_cells.inliers[..12].iter().filter(|&&f| f).count() >= 11);
    let (rot, _) = pose_error(&by_count.pose, &pose);
    assert!(rot > 0.05, "inlier count should have picked the patch's pose (the case this scoring exists for)");
}

#[test]
fn depth_agreement_finds_the_affine_prior_map() {
    let d = [1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 1.2, 2.2, 3.2, f64::NAN];
    let mut pairs: Vec<(f64, f64)> = d.iter().map(|&d| (d, 2.0 * d + 0.5)).collect();
    for p in &mut pairs[6..9] {
        p.1 *= 1.5; // a displaced patch: 50 % deeper than the prior says
    }
    pairs[9].1 = 4.0;
    let agree = super::coverage::depth_agreement(&pairs, 0.1);
    assert_eq!(agree, [true, true, true, true, true, true, false, false, false, true]);
    // Too few known depths: no evidence either way.
    assert!(super::coverage::depth_agreement(&pairs[..2], 0.1).iter().all(|&a| a));
}

/// 10 true matches, and 16 wrong ones that happen to agree with one other pose over the whole
/// image (more cells than the truth) but whose depths under that pose the prior contradicts:
/// without prior depths the wrong pose wins, with them the true one.
#[test]
fn prior_depths_reject_a_pose_the_prior_contradicts() {
    let mut rng = WyRand::new(11);
    let pose = random_pose(&mut rng);
    let intr = k();
    let (mut px, mut pw) = visible(&mut rng, &pose, 10, 0.3);
    let to_cam = pose.inverse();
    let mut prior: Vec<f64> = pw.iter().map(|p| (to_cam * p).z / 3.0 + 0.2).collect();
    let wrong = random_pose(&mut rng);
    let (wrong_px, wrong_pw) = visible(&mut rng, &wrong, 16, 0.3);
    px.extend(wrong_px);
    pw.extend(wrong_pw);
    prior.extend((0..16).map(|_| uniform(&mut rng, 0.5, 8.0)));
    let (_, more_pw) = visible(&mut rng, &pose, 40, 0.0);
    for q in more_pw {
        px.push(Point2::new(uniform(&mut rng, 0.0, 640.0), uniform(&mut rng, 0.0, 480.0)));
        pw.push(q);
        prior.push(uniform(&mut rng, 0.5, 8.0));
    }
    let params = PnpParams { max_iterations: 20_000, ..PnpParams::default() };
    let without = ransac(&intr, &px, &pw, None, &params, 3).expect("a pose");
    assert!(pose_error(&without.pose, &wrong).0 < 0.01, "without the prior the larger wrong set wins");
    let with = ransac_with_prior(&intr, &px, &pw, None, Some(&prior), &params, 3).expect("a pose");
    let (rot, trans) = pose_error(&with.pose, &pose);
    assert!(rot < 0.01 && trans < 0.05, "{rot} rad, {trans} m off");
    let mismatched = ransac_with_prior(&intr, &px, &pw, None, Some(&prior[..3]), &params, 3);
    assert!(matches!(mismatched, Err(PnpError::LengthMismatch { .. })));
}

/// A prior pose gates the search: with 120 matches consistent with one pose and 60 with
/// another 8 m away (a repeated structure), plain RANSAC returns the better supported one; with
/// a gate around the other, RANSAC never scores a hypothesis outside it and returns that one.
#[test]
fn a_pose_gate_keeps_the_search_near_the_prior() {
    let mut rng = WyRand::new(77);
    let strong = random_pose(&mut rng);
    let weak = Isometry3::from_parts(
        Translation3::from(strong.translation.vector + Vector3::new(8.0, 0.0, 0.0)),
        UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.4)) * strong.rotation,
    );
    let (mut px, mut pw) = visible(&mut rng, &strong, 120, 0.5);
    let (px_weak, pw_weak) = visible(&mut rng, &weak, 60, 0.5);
    px.extend(px_weak);
    pw.extend(pw_weak);
    let (px_noise, pw_noise) = random_pixel_matches(&mut rng, &strong, 120);
    px.extend(px_noise);
    pw.extend(pw_noise);
    let params = PnpParams::default();

    let free = ransac(&k(), &px, &pw, None, &params, 3).unwrap();
    assert!(pose_error(&free.pose, &strong).1 < 0.2, "without a gate the better supported pose wins");

    let gate = PoseGate {
        centre: Isometry3::from_parts(
            Translation3::from(weak.translation.vector + Vector3::new(0.3, -0.2, 0.1)),
            weak.rotation,
        ),
        radius_m: 1.0,
        max_angle_rad: 0.2,
    };
    let guidance = Guidance { gate: Some(&gate), ..Guidance::default() };
    let gated = ransac_guided(&k(), &px, &pw, &guidance, &params, 3).unwrap();
    let (r, t) = pose_error(&gated.pose, &weak);
    assert!(r < 5e-3 && t < 0.2, "{r} {t}");
    assert!(gate.check(&gated.pose).is_ok());
}

/// A search run in stages is the search run at once: each stage goes on where the last one
/// stopped (the same sampler, random stream and best hypothesis), so the fast path's stages and
/// the confirmation after them are one robust pass, not three.
#[test]
fn a_search_run_in_stages_is_the_search_run_at_once() {
    let (_, px, pw, _) = scenario(17, 300, 0.85);
    let scores: Vec<f32> = (0..px.len()).map(|i| ((i * 7919) % 997) as f32).collect();
    let params = PnpParams { max_iterations: 2000, min_iterations: 20, seed: 3, ..PnpParams::default() };
    let problem = Problem { intrinsics: &k(), pixels: &px, points: &pw };
    let guidance = Guidance { scores: Some(&scores), ..Guidance::default() };
    let at_once = solve_pnp_ransac(&problem, &guidance, &params).unwrap();
    let mut staged = RansacSearch::new(&problem, &guidance, &params).unwrap();
    let mut iterations = Vec::new();
    for until in [100, 400, 2000] {
        staged.run_until(until, params.min_iterations);
        iterations.push(staged.iterations());
    }
    let staged = staged.solution().unwrap();
    assert_eq!(staged.pose, at_once.pose);
    assert_eq!(staged.inliers, at_once.inliers);
    assert_eq!(staged.iterations, at_once.iterations);
    assert!(iterations.windows(2).all(|w| w[0] <= w[1]), "{iterations:?}");
}

#[test]
fn map_error_covariance_matches_monte_carlo_spread_of_a_shared_error() {
    // Fixed geometry; in each run every region of the view (3 × 3) shifts its pixels together by
    // an angle drawn with σ_map per axis, as points fused from one keyframe are off together.
    let mut rng = WyRand::new(11);
    let pose = random_pose(&mut rng);
    let (clean, pw) = visible(&mut rng, &pose, 90, 0.0);
    let map_error = MapError { angle_rad: 0.5f64.to_radians(), regions: 3 };
    let predicted = map_error_covariance(&k(), &clean, &pw, &pose, &map_error).unwrap();
    let region = |p: &Point2<f64>| ((p.y / 480.0 * 3.0) as usize).min(2) * 3 + ((p.x / 640.0 * 3.0) as usize).min(2);
    let (runs, mut errs) = (300, Vec::new());
    for _ in 0..runs {
        let shifts: Vec<(f64, f64)> = (0..9)
            .map(|_| (normal(&mut rng) * k().fx * map_error.angle_rad, normal(&mut rng) * k().fy * map_error.angle_rad))
            .collect();
        let px: Vec<Point2<f64>> = clean
            .iter()
            .map(|p| {
                let (du, dv) = shifts[region(p)];
                Point2::new(p.x + du, p.y + dv)
            })
            .collect();
        let s = solve_pnp_nonminimal(&k(), &px, &pw, &RefineOptions::default()).unwrap();
        errs.push(covariance_error(&s.pose, &pose));
    }
    assert_spread_matches(&errs, &predicted);
}

#[test]
fn map_error_shrinks_over_the_regions_the_inliers_cover_and_is_zero_when_off() {
    let mut rng = WyRand::new(12);
    let pose = random_pose(&mut rng);
    let (px, pw) = visible(&mut rng, &pose, 400, 0.0);
    let map_error = MapError { angle_rad: 1f64.to_radians(), regions: 3 };
    let spread = map_error_covariance(&k(), &px, &pw, &pose, &map_error).unwrap();
    assert!(is_psd(&spread) && (spread - spread.transpose()).amax() <= 1e-12 * spread.amax());
    // The same number of inliers crowded into the top-left region: one shared error, no averaging.
    let (corner_px, corner_pw): (Vec<_>, Vec<_>) =
        px.iter().zip(&pw).filter(|(p, _)| p.x < 640.0 / 3.0 && p.y < 160.0).map(|(p, w)| (*p, *w)).unzip();
    assert!(corner_px.len() >= 20, "{}", corner_px.len());
    let corner = map_error_covariance(&k(), &corner_px, &corner_pw, &pose, &map_error).unwrap();
    let rotation = |c: &nalgebra::Matrix6<f64>| c[(3, 3)] + c[(4, 4)] + c[(5, 5)];
    assert!(rotation(&corner) > 1.5 * rotation(&spread), "{} vs {}", rotation(&corner), rotation(&spread));
    // It does not shrink with the number of inliers: a tenth of them, about the same.
    let few = map_error_covariance(&k(), &px[..40], &pw[..40], &pose, &map_error).unwrap();
    assert!((0.5..2.5).contains(&(rotation(&few) / rotation(&spread))), "{} vs {}", rotation(&few), rotation(&spread));
    let off = MapError { angle_rad: 0.0, ..map_error };
    assert_eq!(map_error_covariance(&k(), &px, &pw, &pose, &off).unwrap(), nalgebra::Matrix6::zeros());
}
