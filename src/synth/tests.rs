use nalgebra::{Matrix3, Point2, Point3, Vector3};

use super::*;

fn small(preset: &str, frames: usize, seed: u64) -> SynthConfig {
    let base = SynthConfig::preset(preset).unwrap_or_default();
    SynthConfig { frames, seed, ..base }
}

/// The frame's compressed camera image (synth encodes JPEG).
fn compressed(frame: &Frame) -> Option<&EncodedImage> {
    frame.image.as_ref().and_then(CameraImage::compressed)
}

fn gt(frame: &Frame) -> (Isometry3<f64>, &DepthImage) {
    let g = frame.ground_truth.as_ref().expect("ground truth");
    (g.pose.expect("pose"), g.depth.as_ref().expect("depth"))
}

#[test]
fn presets_and_config() {
    for name in PRESETS {
        assert!(SynthConfig::preset(name).is_some(), "{name}");
    }
    assert!(SynthConfig::preset("nope").is_none());
    let hard = SynthConfig::preset("HARD").expect("hard");
    assert_eq!(hard.correspondences, 400);
    assert!((hard.patch_outlier_fraction - 0.5).abs() < 1e-12);
    let json = serde_json::to_string(&hard).expect("ser");
    let back: SynthConfig = serde_json::from_str(&json).expect("de");
    assert_eq!(back, hard);
    // Partial configs take defaults.
    let partial: SynthConfig = serde_yaml::from_str("seed: 5\nframes: 2\n").expect("yaml");
    assert_eq!(partial.seed, 5);
    assert_eq!(partial.width, 320);
    // Garbage is sanitised, not a panic.
    let bad = SynthConfig {
        fx: f64::NAN,
        inlier_ratio: 7.0,
        width: 0,
        prior_scale_range: [3.0, -1.0],
        ..SynthConfig::default()
    };
    let s = bad.sanitized();
    assert!(s.fx.is_finite() && s.fx > 0.0);
    assert_eq!(s.inlier_ratio, 1.0);
    assert!(s.width >= 8);
    assert!(s.prior_scale_range[0] <= s.prior_scale_range[1]);
    assert!(s.intrinsics().is_valid());
}

#[test]
fn degenerate_configs_do_not_panic() {
    let none = generate(&SynthConfig { frames: 0, ..SynthConfig::default() });
    assert!(none.frames.is_empty());
    assert!(!none.map.points.is_empty());
    let empty = generate(&SynthConfig {
        frames: 1,
        correspondences: 0,
        width: 16,
        height: 12,
        fx: 13.0,
        fy: 13.0,
        cx: 8.0,
        cy: 6.0,
        ..SynthConfig::default()
    });
    assert_eq!(empty.frames.len(), 1);
    assert!(empty.frames[0].correspondences.is_empty());
    let all_patch = generate(&SynthConfig {
        frames: 1,
        width: 32,
        height: 24,
        fx: 26.0,
        fy: 26.0,
        cx: 16.0,
        cy: 12.0,
        correspondences: 50,
        patch_outlier_fraction: 1.0,
        inlier_ratio: 0.5,
        ..SynthConfig::default()
    });
    assert_eq!(all_patch.stats[0].patch_moved, 50);
    assert_eq!(all_patch.stats[0].inliers, 0);
}

#[test]
fn deterministic_for_a_seed() {
    let cfg =
        SynthConfig { width: 160, height: 120, fx: 131.25, fy: 131.25, cx: 80.0, cy: 60.0, ..small("hard", 3, 11) };
    let a = generate(&cfg);
    let b = generate(&cfg);
    assert_eq!(a.map.points, b.map.points);
    assert_eq!(a.stats, b.stats);
    for (fa, fb) in a.frames.iter().zip(&b.frames) {
        assert_eq!(fa.stamp, fb.stamp);
        assert_eq!(fa.correspondences, fb.correspondences);
        assert_eq!(fa.depth_prior, fb.depth_prior);
        assert_eq!(compressed(fa).map(|i| &i.data), compressed(fb).map(|i| &i.data));
        assert_eq!(gt(fa).0, gt(fb).0);
        assert_eq!(gt(fa).1, gt(fb).1);
    }
    let c = generate(&SynthConfig { seed: 12, ..cfg });
    assert_ne!(a.frames[0].correspondences, c.frames[0].correspondences);
}

#[test]
fn frames_are_well_formed_and_finite() {
    let scene = generate(&small("sift", 4, 3));
    let n = scene.map.points.len();
    assert!((30_000..=90_000).contains(&n), "map points {n}");
    assert_eq!(scene.map.frame_id, "map");
    assert!(scene.map.points.iter().all(|p| p.coords.iter().all(|v| v.is_finite())));
    assert_eq!(scene.frames.len(), 4);
    for (k, (f, s)) in scene.frames.iter().zip(&scene.stats).enumerate() {
        assert_eq!(f.stamp, FIRST_STAMP + (k as i64 + 1) * 100_000_000);
        assert_eq!(f.camera_frame_id, CAMERA_FRAME_ID);
        assert_eq!(f.map_frame_id, MAP_FRAME_ID);
        assert!(f.intrinsics.is_valid());
        assert_eq!((f.intrinsics.width, f.intrinsics.height), (320, 240));
        assert_eq!(f.correspondences.len(), 800);
        for c in &f.correspondences {
            assert!(c.pixel.x >= 0.0 && c.pixel.y >= 0.0 && c.pixel.x <= 319.0 && c.pixel.y <= 239.0);
            assert!(c.point.coords.iter().all(|v| v.is_finite()));
            assert!((0.0..=1.0).contains(&c.score));
        }
        let (pose, depth) = gt(f);
        assert!(pose.translation.vector.iter().all(|v| v.is_finite()));
        assert_eq!((depth.width, depth.height), (320, 240));
        assert!(depth.data.iter().all(|d| d.is_finite() && *d > 0.3 && *d < 10.0));
        let prior = f.depth_prior.as_ref().expect("prior");
        assert_eq!((prior.width, prior.height), (160, 120));
        assert!(prior.data.iter().all(|d| d.is_finite() && *d > 0.0));
        assert!(s.clearance_m >= 0.8, "camera {k} only {} m from a surface", s.clearance_m);
        assert!(s.prior_scale >= 0.4 && s.prior_scale <= 2.5);
        assert!(s.prior_shift.abs() <= 0.2 * s.median_depth * 1.05 + 1e-9);
        let img = compressed(f).expect("image");
        assert_eq!(img.format, "jpeg");
        let decoded = image::load_from_memory(&img.data).expect("decodes");
        assert_eq!((decoded.width(), decoded.height()), (320, 240));
        // Not a flat image: some contrast.
        let luma = decoded.to_luma8();
        let (lo, hi) = luma.pixels().fold((255u8, 0u8), |(lo, hi), p| (lo.min(p.0[0]), hi.max(p.0[0])));
        assert!(hi as i32 - lo as i32 > 60, "contrast {lo}..{hi}");
    }
}

#[test]
fn inliers_lift_onto_their_points_and_ratio_matches() {
    for preset in PRESETS {
        let cfg = small(preset, 4, 21);
        let scene = generate(&cfg);
        for (f, s) in scene.frames.iter().zip(&scene.stats) {
            let (pose, depth) = gt(f);
            let mask = inlier_mask(f, 0.05);
            for ((c, l), inlier) in f.correspondences.iter().zip(&s.labels).zip(&mask) {
                let d = lifted_distance(&f.intrinsics, &pose, depth, &c.pixel, &c.point).expect("depth known");
                match l {
                    CorrLabel::Inlier => assert!(d < 0.05 && *inlier, "{preset}: inlier {d} m off"),
                    _ => assert!(d >= 0.05 && !*inlier, "{preset}: outlier {l:?} only {d} m off"),
                }
            }
            assert!(
                (s.inlier_ratio - cfg.inlier_ratio).abs() < 0.02,
                "{preset}: ratio {} vs {}",
                s.inlier_ratio,
                cfg.inlier_ratio
            );
            let moved = s.patch_moved as f64 / s.correspondences as f64;
            assert!(
                moved >= cfg.patch_outlier_fraction - 1e-9 && moved <= cfg.patch_outlier_fraction + 0.1,
                "{preset}: moved {moved}"
            );
        }
    }
}

#[test]
fn inliers_reproject_within_noise() {
    let cfg = small("sift", 3, 5);
    let scene = generate(&cfg);
    for (f, s) in scene.frames.iter().zip(&scene.stats) {
        let (pose, _) = gt(f);
        let inv = pose.inverse();
        let (mut sum, mut sum_expected, mut n) = (0.0, 0.0, 0.0);
        for (c, l) in f.correspondences.iter().zip(&s.labels) {
            if *l != CorrLabel::Inlier {
                continue;
            }
            let pc = inv * c.point;
            let px = f.intrinsics.project(&pc).expect("in front");
            let e2 = (px - c.pixel).norm_squared();
            // Pixel noise plus the 3D point's noise seen at this depth (both per axis).
            let expected = 2.0 * (cfg.pixel_noise_px.powi(2) + (f.intrinsics.fx * cfg.map_noise_m / pc.z).powi(2));
            assert!(e2.sqrt() < 5.0 * expected.sqrt(), "reprojection {} px", e2.sqrt());
            sum += e2;
            sum_expected += expected;
            n += 1.0;
        }
        assert!(n > 100.0);
        let (rms, rms_expected) = ((sum / n).sqrt(), (sum_expected / n).sqrt());
        assert!(rms < 1.2 * rms_expected && rms > 0.5 * rms_expected, "rms {rms} vs expected {rms_expected}");
    }
}

#[test]
fn prior_is_affine_in_depth_within_the_warp() {
    let cfg = small("sift", 4, 9);
    let scene = generate(&cfg);
    for (f, s) in scene.frames.iter().zip(&scene.stats) {
        let (_, depth) = gt(f);
        let prior = f.depth_prior.as_ref().expect("prior");
        let (mut sum, mut n) = (0.0, 0.0);
        for v in (0..240).step_by(3) {
            for u in (0..320).step_by(3) {
                let Some(d) = depth.at(u, v) else { continue };
                let Some(p) = prior.sample(&Point2::new(u as f64, v as f64), 320, 240) else { continue };
                sum += ((s.prior_scale * p + s.prior_shift) - d as f64).abs() / d as f64;
                n += 1.0;
            }
        }
        let mean = sum / n;
        assert!(mean < cfg.warp_amplitude, "mean relative error {mean}");
        assert!(mean > 0.002, "suspiciously exact prior: {mean}");
    }
    // Without warp and blur the prior is GT up to the half-resolution sampling and rounding.
    let exact = generate(&SynthConfig { warp_amplitude: 0.0, blur_sigma_px: 0.0, ..small("sift", 2, 9) });
    for (f, s) in exact.frames.iter().zip(&exact.stats) {
        let (_, depth) = gt(f);
        let prior = f.depth_prior.as_ref().expect("prior");
        let mut errors = Vec::new();
        for v in (0..240).step_by(2) {
            for u in (0..320).step_by(2) {
                let (Some(d), Some(p)) = (depth.at(u, v), prior.sample(&Point2::new(u as f64, v as f64), 320, 240))
                else {
                    continue;
                };
                errors.push(((s.prior_scale * p + s.prior_shift) - d as f64).abs() / d as f64);
            }
        }
        errors.sort_by(|a, b| a.total_cmp(b));
        let median = errors[errors.len() / 2];
        assert!(median < 0.01, "median relative error without warp {median}");
    }
}

/// Least-squares rigid fit (Kabsch); returns the RMS residual of `b ≈ R a + t`.
fn rigid_fit_rms(a: &[Point3<f64>], b: &[Point3<f64>]) -> f64 {
    let ca = a.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / a.len() as f64;
    let cb = b.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / b.len() as f64;
    let mut hm = Matrix3::zeros();
    for (p, q) in a.iter().zip(b) {
        hm += (p.coords - ca) * (q.coords - cb).transpose();
    }
    let svd = hm.svd(true, true);
    let (u, vt) = (svd.u.expect("u"), svd.v_t.expect("v"));
    let mut d = Matrix3::identity();
    if (vt.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = vt.transpose() * d * u.transpose();
    let sum: f64 = a.iter().zip(b).map(|(p, q)| (r * (p.coords - ca) + cb - q.coords).norm_squared()).sum();
    (sum / a.len() as f64).sqrt()
}

#[test]
fn patch_outliers_are_locally_rigid_but_wrong() {
    // Noise-free points, so that a patch's true places are its points before moving.
    let cfg = SynthConfig { pixel_noise_px: 0.0, map_noise_m: 0.0, ..small("hard", 3, 17) };
    let scene = generate(&cfg);
    let mut checked = 0;
    for (f, s) in scene.frames.iter().zip(&scene.stats) {
        let (pose, depth) = gt(f);
        let mut by_patch: std::collections::BTreeMap<u32, Vec<usize>> = Default::default();
        for (j, l) in s.labels.iter().enumerate() {
            if let CorrLabel::Patch { patch, .. } = l {
                by_patch.entry(*patch).or_default().push(j);
                let c = &f.correspondences[j];
                let d = lifted_distance(&f.intrinsics, &pose, depth, &c.pixel, &c.point).expect("depth");
                assert!(d >= 0.05, "moved point only {d} m from its true place");
            }
        }
        assert_eq!(by_patch.len(), s.patches);
        for members in by_patch.values() {
            // Members that were true before moving: their true places map rigidly onto the moved points.
            let base: Vec<usize> = members
                .iter()
                .copied()
                .filter(|&j| matches!(s.labels[j], CorrLabel::Patch { base_inlier: true, .. }))
                .collect();
            if base.len() < 4 {
                continue;
            }
            let truth: Vec<Point3<f64>> = base
                .iter()
                .filter_map(|&j| lift_pixel(&f.intrinsics, &pose, depth, &f.correspondences[j].pixel))
                .collect();
            let moved: Vec<Point3<f64>> = base.iter().map(|&j| f.correspondences[j].point).collect();
            let rms = rigid_fit_rms(&truth, &moved);
            assert!(rms < 0.01, "patch not rigid: rms {rms}");
            // Pairwise distances preserved up to the point noise.
            for i in 0..truth.len() {
                for k in i + 1..truth.len() {
                    let (dt, dm) = ((truth[i] - truth[k]).norm(), (moved[i] - moved[k]).norm());
                    assert!((dt - dm).abs() < 0.02, "pairwise {dt} vs {dm}");
                }
            }
            let mean_shift = truth.iter().zip(&moved).map(|(a, b)| (a - b).norm()).sum::<f64>() / truth.len() as f64;
            assert!(mean_shift > 0.075, "patch barely moved: {mean_shift}");
            checked += 1;
        }
        // Patches are spatially compact in the image.
        for members in by_patch.values() {
            let first = f.correspondences[members[0]].pixel;
            for &j in members {
                assert!((f.correspondences[j].pixel - first).norm() < 2.0 * cfg.patch_radius_px + 1e-9);
            }
        }
    }
    assert!(checked >= 3, "only {checked} patches checked");
}

#[test]
fn inlier_ratio_spread_varies_frames() {
    let cfg = SynthConfig { inlier_ratio_spread: 0.3, ..small("hard", 6, 8) };
    let scene = generate(&cfg);
    let ratios: Vec<f64> = scene.stats.iter().map(|s| s.inlier_ratio).collect();
    let (lo, hi) = ratios.iter().fold((1.0_f64, 0.0_f64), |(lo, hi), r| (lo.min(*r), hi.max(*r)));
    assert!(hi - lo > 0.01, "ratios {ratios:?}");
    assert!(ratios.iter().all(|r| *r > 0.03 && *r < 0.45), "ratios {ratios:?}");
}

#[test]
fn snapping_to_the_map_keeps_inliers() {
    let cfg = SynthConfig { snap_to_map: true, ..small("sift", 2, 4) };
    let scene = generate(&cfg);
    for s in &scene.stats {
        assert!((s.inlier_ratio - 0.5).abs() < 0.02, "ratio {}", s.inlier_ratio);
    }
}

/// `cargo test --release synth::tests::timing -- --ignored --nocapture`
#[test]
#[ignore]
fn timing() {
    for name in PRESETS {
        let cfg = SynthConfig::preset(name).unwrap_or_default();
        let t = std::time::Instant::now();
        let scene = generate(&cfg);
        let dt = t.elapsed();
        for k in [0, 7, 13] {
            if let Some(img) = scene.frames.get(k).and_then(compressed) {
                if let Ok(decoded) = image::load_from_memory(&img.data) {
                    let _ = decoded.save(std::env::temp_dir().join(format!("synth_{name}_{k}.png")));
                }
            }
        }
        let ir: Vec<String> = scene.stats.iter().map(|s| format!("{:.3}", s.inlier_ratio)).collect();
        let jpeg: usize = scene.frames.iter().filter_map(compressed).map(|i| i.data.len()).sum();
        println!(
            "{name}: {} frames in {:.2} s, map {} pts, mean ir {:.3}, jpeg {} kB/frame, min clearance {:.2} m, ir {:?}",
            scene.frames.len(),
            dt.as_secs_f64(),
            scene.map.points.len(),
            scene.mean_inlier_ratio(),
            jpeg / scene.frames.len().max(1) / 1024,
            scene.stats.iter().map(|s| s.clearance_m).fold(f64::INFINITY, f64::min),
            ir
        );
    }
}

#[test]
fn modifiers_make_other_sensors_scenes_and_priors() {
    assert!(SynthConfig::preset("hard+nope").is_none());
    let close = SynthConfig::preset("easy+close+small-map+disparity").expect("preset");
    assert_eq!((close.width, close.height, close.fx), (640, 480, 615.0));
    assert_eq!(close.prior_kind, SynthPriorKind::Disparity);
    assert!((close.inlier_ratio - 0.83).abs() < 1e-12);
    let hd = SynthConfig::preset("extreme+hd+harsh").expect("preset");
    assert_eq!((hd.width, hd.height, hd.fx), (1280, 720, 900.0));
    assert!((hd.patch_radius_px - 80.0).abs() < 1e-9, "patches scale with the image");

    let scene = generate(&SynthConfig { frames: 2, seed: 3, ..close });
    let points = scene.map.points.len();
    assert!((1_000..15_000).contains(&points), "a small map: {points} points");
    for (f, s) in scene.frames.iter().zip(&scene.stats) {
        assert!(s.median_depth > 0.3 && s.median_depth < 1.6, "close range: median depth {}", s.median_depth);
        // Disparity: larger where the ground truth is nearer.
        let (_, depth) = gt(f);
        let prior = f.depth_prior.as_ref().expect("prior");
        let k = f.intrinsics;
        let (near, far) = depth
            .data
            .iter()
            .enumerate()
            .filter(|(_, d)| **d > 0.0)
            .fold(((f32::INFINITY, 0usize), (0f32, 0usize)), |(n, fa), (i, &d)| {
                (if d < n.0 { (d, i) } else { n }, if d > fa.0 { (d, i) } else { fa })
            });
        let at = |i: usize| {
            let p = Point2::new((i % k.width as usize) as f64, (i / k.width as usize) as f64);
            prior.sample(&p, k.width, k.height).expect("known")
        };
        assert!(at(near.1) > at(far.1), "disparity falls with depth");
    }
}

/// An office: an Xtion's camera, surfaces up to a few metres away, confused copies of a cubicle
/// that all sit one period along the row from the true point (one direction per frame), and a
/// map that the fused keyframes' errors moved by centimetres, not decimetres.
#[test]
fn an_office_has_confused_copies_and_a_drifted_map() {
    let office = SynthConfig::preset("hard+office").expect("preset");
    assert_eq!((office.width, office.height, office.fx), (640, 480, 570.0));
    let scene = generate(&SynthConfig { frames: 3, seed: 5, ..office.clone() });
    let period = office.repeat_period_m;
    let mut copies = 0;
    for (f, s) in scene.frames.iter().zip(&scene.stats) {
        assert!(s.median_depth > 1.5 && s.median_depth < 5.0, "median depth {}", s.median_depth);
        let (pose, depth) = gt(f);
        let shifts: Vec<f64> = f
            .correspondences
            .iter()
            .filter_map(|c| lift_pixel(&f.intrinsics, &pose, depth, &c.pixel).map(|l| c.point - l))
            .filter(|d| (d.x.abs() - period).abs() < 0.1 && d.y.abs() < 0.1 && d.z.abs() < 0.1)
            .map(|d| d.x.signum())
            .collect();
        assert!(shifts.windows(2).all(|w| w[0] == w[1]), "one direction a frame");
        copies += shifts.len();
        // True matches sit on the drifted map: a few centimetres off the true surface at most.
        for (c, label) in f.correspondences.iter().zip(&s.labels) {
            if *label == CorrLabel::Inlier {
                let lifted = lift_pixel(&f.intrinsics, &pose, depth, &c.pixel).expect("an inlier has depth");
                assert!((c.point - lifted).norm() < 0.1, "an inlier {} m off", (c.point - lifted).norm());
            }
        }
    }
    assert!(copies >= 3, "{copies} confused copies in 3 frames");
    // Without drift or copies the same preset's other scenes keep their outputs.
    let plain = SynthConfig::preset("hard").expect("preset");
    assert_eq!(plain.repeat_period_m, 0.0);
    assert_eq!(plain.map_keyframe_m, 0.0);
}

/// `partial-map`: the map holds the room's first half along x only; a match on the rest pairs
/// its pixel with a point of that half, so it is never a true match, and frames that see both
/// halves have fewer true matches than the tier's.
#[test]
fn a_partial_map_holds_half_the_room_and_no_true_match_beyond_it() {
    let config = SynthConfig { frames: 6, seed: 11, ..SynthConfig::preset("sift+partial-map").expect("preset") };
    assert!((config.mapped_share - 0.5).abs() < 1e-12);
    let edge = config.mapped_share * config.room_size[0];
    let scene = generate(&config);
    // Noise and the fused map's drift move points a few centimetres at most.
    let beyond = scene.map.points.iter().filter(|p| p.x as f64 > edge + 0.1).count();
    assert_eq!(beyond, 0, "{} of {} map points beyond x = {edge} m", beyond, scene.map.points.len());
    let whole = generate(&SynthConfig { mapped_share: 1.0, ..config.clone() });
    assert!(whole.map.points.len() > scene.map.points.len() * 3 / 2);
    for frame in &scene.frames {
        let (pose, depth) = gt(frame);
        let mask = inlier_mask(frame, config.inlier_threshold_m);
        for (c, inlier) in frame.correspondences.iter().zip(mask) {
            let seen = lift_pixel(&frame.intrinsics, &pose, &depth, &c.pixel).expect("a surface point");
            assert!(!inlier || seen.x <= edge + 0.1, "a true match at x = {:.2} m, beyond the map", seen.x);
        }
    }
    assert!(scene.mean_inlier_ratio() < whole.mean_inlier_ratio());
}
