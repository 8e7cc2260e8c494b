//! The localizer end to end on synthetic frames (always) and on the shared real bags (when
//! present): accuracy of the rejection + PnP pipeline, and bad input turned into reasons.

use angle_i2p::app;
use angle_i2p::bag::read_frames;
use angle_i2p::eval::{inlier_mask, inlier_ratio, nees, pose_errors, summarize, FrameMetrics, PoseErrors};
use angle_i2p::frame::{Correspondence, Frame, MapCloud};
use angle_i2p::geometry::DepthKind;
use angle_i2p::params::LocalizerParams;
use angle_i2p::pipeline::{Failure, Localizer, Method};
use angle_i2p::synth::{generate, SynthConfig};

mod common;
use common::{onnx_runtime, shared_bag};

fn localize_all(frames: &[Frame], method: Method) -> (Vec<FrameMetrics>, f64) {
    localize_all_with_map(frames, None, method)
}

fn localize_all_with_map(frames: &[Frame], map: Option<&MapCloud>, method: Method) -> (Vec<FrameMetrics>, f64) {
    localize_params(frames, map, LocalizerParams { method, ..LocalizerParams::default() })
}

fn localize_params(frames: &[Frame], map: Option<&MapCloud>, params: LocalizerParams) -> (Vec<FrameMetrics>, f64) {
    let method = params.method;
    let mut localizer = Localizer::new(params).unwrap_or_else(|e| panic!("{}: {e}", method.name()));
    if let Some(map) = map {
        localizer.set_map(map);
    }
    let mut raw_ir = 0.0;
    let rows = frames
        .iter()
        .map(|f| {
            let gt = f.ground_truth.as_ref().expect("ground truth");
            let (pose, depth) = (gt.pose.as_ref().expect("gt pose"), gt.depth.as_ref().expect("gt depth"));
            raw_ir += inlier_ratio(&inlier_mask(&f.correspondences, &f.intrinsics, pose, depth));
            let loc = localizer.process(f);
            FrameMetrics {
                stamp: f.stamp,
                inlier_ratio: inlier_ratio(&inlier_mask(&loc.kept, &f.intrinsics, pose, depth)),
                errors: loc.pose.map(|p| PoseErrors {
                    nees: loc.covariance.and_then(|c| nees(&p, pose, &c)),
                    ..pose_errors(&p, pose, &f.intrinsics, depth)
                }),
                ms: Some(loc.timings.total_ms),
            }
        })
        .collect();
    (rows, 100.0 * raw_ir / frames.len() as f64)
}

#[test]
fn consistency_rejection_localizes_synthetic_hard_frames() {
    let scene = generate(&SynthConfig { frames: 8, seed: 7, ..SynthConfig::preset("hard").unwrap() });
    let (rows, raw_ir) = localize_all(&scene.frames, Method::Consistency);
    let s = summarize(&rows);
    assert!(s.rr >= 75.0, "RR {:.1} %", s.rr);
    assert!(s.ir >= 2.0 * raw_ir, "kept IR {:.1} % vs raw {:.1} %", s.ir, raw_ir);
}

#[test]
fn ransac_localizes_synthetic_sift_frames_accurately() {
    let scene = generate(&SynthConfig { frames: 5, seed: 3, ..SynthConfig::preset("sift").unwrap() });
    let (rows, _) = localize_all(&scene.frames, Method::Ransac);
    let s = summarize(&rows);
    assert_eq!(s.rr, 100.0);
    assert!(s.mre.unwrap() < 1.0 && s.mte.unwrap() < 0.05, "{s:?}");
}

#[test]
fn bad_frames_fail_with_a_reason_and_the_next_frame_still_localizes() {
    let scene = generate(&SynthConfig { frames: 2, seed: 5, ..SynthConfig::preset("sift").unwrap() });
    let good = scene.frames[1].clone();
    let mut localizer = Localizer::new(LocalizerParams::default()).expect("a localizer");

    let mut empty = scene.frames[0].clone();
    empty.correspondences.clear();
    assert_eq!(localizer.process(&empty).failure, Some(Failure::NoCorrespondences));

    let mut nan = scene.frames[0].clone();
    nan.correspondences[3].point.y = f64::NAN;
    assert_eq!(localizer.process(&nan).failure, Some(Failure::NonFinite { index: 3 }));

    let mut few = scene.frames[0].clone();
    few.correspondences.truncate(3);
    assert!(matches!(localizer.process(&few).failure, Some(Failure::TooFewCorrespondences { have: 3, .. })));

    let mut bad_k = scene.frames[0].clone();
    bad_k.intrinsics.fx = 0.0;
    assert_eq!(localizer.process(&bad_k).failure, Some(Failure::InvalidIntrinsics));

    // Without a prior an easy frame is still settled by the cascade's fast path; the rejector,
    // which needs the prior, says so when it has to run.
    let mut no_prior = scene.frames[0].clone();
    no_prior.depth_prior = None;
    let loc = localizer.process(&no_prior);
    assert!(loc.fast_path && loc.pose.is_some() && loc.prior_quality.is_none(), "{:?}", loc.failure);
    let mut full_path_only = LocalizerParams::default();
    full_path_only.cascade.enabled = false;
    let loc = Localizer::new(full_path_only).expect("a localizer").process(&no_prior);
    assert!(matches!(loc.failure, Some(Failure::Rejection(_))), "{:?}", loc.failure);
    assert!(loc.failure.unwrap().to_string().contains("depth prior"));

    // A prior that says nothing (all 0, all NaN, all negative) reaches the rejectors' full path
    // as a reason, not a panic.
    for value in [0.0, f32::NAN, -1.0] {
        let mut blank = scene.frames[0].clone();
        if let Some(prior) = blank.depth_prior.as_mut() {
            prior.data.iter_mut().for_each(|d| *d = value);
        }
        for method in [Method::Consistency, Method::AngleI2p] {
            let mut params = LocalizerParams { method, ..LocalizerParams::default() };
            params.cascade.enabled = false;
            let Ok(mut full) = Localizer::new(params) else { continue };
            let loc = full.process(&blank);
            assert!(loc.failure.is_some() || loc.pose.is_some(), "{value}: {:?}", loc.failure);
        }
    }

    // Garbage correspondences: no consensus is a reason, not a panic.
    let mut garbage = scene.frames[0].clone();
    let n = garbage.correspondences.len();
    for (i, c) in garbage.correspondences.iter_mut().enumerate() {
        c.point = nalgebra::Point3::new((i * 7919 % n) as f64 * 0.01, (i * 104729 % n) as f64 * -0.02, 0.5);
    }
    let _ = localizer.process(&garbage);

    let loc = localizer.process(&good);
    assert!(loc.failure.is_none() && loc.pose.is_some(), "{:?}", loc.failure);
}

/// Localizes every frame of a shared real bag; `None` (the check recorded as skipped) when it is absent.
fn real_bag_summary(name: &str, method: Method) -> Option<(angle_i2p::eval::Summary, f64)> {
    real_bag_summary_with(name, LocalizerParams { method, ..LocalizerParams::default() })
}

fn real_bag_summary_with(name: &str, params: LocalizerParams) -> Option<(angle_i2p::eval::Summary, f64)> {
    let bag = shared_bag(name)?;
    let method = params.method;
    let input = read_frames(&bag, &angle_i2p::params::TopicMap::default()).unwrap();
    let (rows, raw_ir) = localize_params(&input.frames, input.map.as_ref(), params);
    assert!((app::raw_inlier_ratio(&input).ir - raw_ir).abs() < 1e-9);
    let s = summarize(&rows);
    eprintln!("{name} {}: {s:?} (raw IR {raw_ir:.2})", method.name());
    Some((s, raw_ir))
}

/// The spine's acceptance bar on real data: the consistency rejector finds ≥ 95 % of the
/// poses of `redkitchen-hard-val` (PoseLib LO-RANSAC: 95 %, OpenCV RANSAC-1k: 45 %) with
/// twice the raw inlier ratio.
#[test]
fn consistency_rejection_on_real_hard_val() {
    let Some((s, raw_ir)) = real_bag_summary("redkitchen-hard-val", Method::Consistency) else { return };
    assert!(s.rr >= 95.0, "RR {:.1} %", s.rr);
    assert!(s.ir >= 2.0 * raw_ir, "IR {:.1} % vs raw {raw_ir:.1} %", s.ir);
}

/// Accuracy on the easy tier (issue #9): every frame registered, MRE and MTE no worse than
/// PoseLib's LO-RANSAC on `redkitchen-sift-val` (0.684°, 0.0192 m in its baseline.json).
#[test]
fn consistency_accuracy_on_real_sift_val() {
    let Some((s, _)) = real_bag_summary("redkitchen-sift-val", Method::Consistency) else { return };
    assert_eq!(s.rr, 100.0);
    assert!(s.mre.unwrap() <= 0.684 && s.mte.unwrap() <= 0.0192, "{s:?}");
}

/// The learned rejector's bars on real data (issue #3): on `redkitchen-extreme-val` RR within 5
/// points of the oracle's 88.3 % (PoseLib LO-RANSAC: 25 %); on `redkitchen-hard-val` RR ≥ 95 %
/// with at least twice the raw inlier ratio.
#[test]
fn learned_rejection_on_real_extreme_and_hard_val() {
    if onnx_runtime().is_none() {
        return;
    }
    let Some((s, raw_ir)) = real_bag_summary("redkitchen-extreme-val", Method::AngleI2p) else { return };
    assert!(s.rr >= 88.333 - 5.0, "extreme RR {:.1} %", s.rr);
    assert!(s.ir >= 3.0 * raw_ir, "extreme IR {:.1} % vs raw {raw_ir:.1} %", s.ir);
    let Some((s, raw_ir)) = real_bag_summary("redkitchen-hard-val", Method::AngleI2p) else { return };
    assert!(s.rr >= 95.0, "hard RR {:.1} %", s.rr);
    assert!(s.ir >= 2.0 * raw_ir, "hard IR {:.1} % vs raw {raw_ir:.1} %", s.ir);
}

/// Realistic priors (issue #9): with the harsh metric-like prior and with affine-invariant
/// disparity (read as `depth_kind: disparity`), the default method registers every hard-tier
/// frame and at least PoseLib + 15 points (25 % + 15) of the extreme tier's.
#[test]
fn learned_rejection_with_realistic_priors() {
    if onnx_runtime().is_none() {
        return;
    }
    let disparity = LocalizerParams { depth_kind: DepthKind::Disparity, ..LocalizerParams::default() };
    for (name, params) in [
        ("redkitchen-hard-val-harsh", LocalizerParams::default()),
        ("redkitchen-hard-val-disparity", disparity.clone()),
        ("redkitchen-extreme-val-harsh", LocalizerParams::default()),
        ("redkitchen-extreme-val-disparity", disparity),
    ] {
        let Some((s, _)) = real_bag_summary_with(name, params) else { return };
        let bar = if name.contains("hard") { 100.0 } else { 40.0 };
        assert!(s.rr >= bar, "{name}: RR {:.1} % < {bar}", s.rr);
    }
}

/// A dense matcher's frames (2500 matches, the hard tier's 15 % inliers) have more matches than
/// the spectral pass holds (`spectral.max_nodes`): it ranks them through anchors, and every
/// method that uses it registers them as well as with every match in Θ.
#[test]
fn frames_of_a_dense_matcher_localize_through_the_spectral_anchors() {
    let config = SynthConfig { frames: 3, seed: 5, correspondences: 2500, ..SynthConfig::preset("hard").unwrap() };
    let scene = generate(&config);
    assert!(scene.frames.iter().all(|f| f.correspondences.len() > LocalizerParams::default().spectral.max_nodes));
    let mut methods = vec![Method::Consistency];
    if onnx_runtime().is_some() {
        methods.push(Method::AngleI2p);
    }
    for method in methods {
        for max_nodes in [LocalizerParams::default().spectral.max_nodes, 0] {
            let mut params = LocalizerParams { method, ..LocalizerParams::default() };
            params.spectral.max_nodes = max_nodes;
            let (rows, raw_ir) = localize_params(&scene.frames, Some(&scene.map), params);
            let s = summarize(&rows);
            let what = format!("{} with max_nodes {max_nodes}", method.name());
            assert_eq!(s.rr, 100.0, "{what}: {s:?}");
            assert!(s.mre.unwrap() < 1.0 && s.ir >= 2.0 * raw_ir, "{what}: {s:?}, raw IR {raw_ir:.1} %");
        }
    }
}

/// A matcher that publishes no confidence (every score 0, or every score 1): the network reads
/// the model's typical confidence for both (`network.missing_confidence`), so the frame is
/// localized the same either way, and registered.
#[test]
fn a_matcher_without_confidence_is_read_the_same_whatever_constant_it_sends() {
    if onnx_runtime().is_none() {
        return;
    }
    let scene = generate(&SynthConfig { frames: 2, seed: 11, ..SynthConfig::preset("extreme").unwrap() });
    let with_scores = |score: f32| -> Vec<Frame> {
        let mut frames = scene.frames.clone();
        frames.iter_mut().flat_map(|f| f.correspondences.iter_mut()).for_each(|c| c.score = score);
        frames
    };
    let localize = |frames: &[Frame]| {
        let mut localizer = Localizer::new(LocalizerParams::default()).expect("a localizer");
        localizer.set_map(&scene.map);
        frames.iter().map(|f| localizer.process(f)).collect::<Vec<_>>()
    };
    let (zeros, ones) = (localize(&with_scores(0.0)), localize(&with_scores(1.0)));
    for ((zero, one), f) in zeros.iter().zip(&ones).zip(&scene.frames) {
        assert_eq!(zero.pose, one.pose);
        assert_eq!(zero.kept.len(), one.kept.len());
        let gt = f.ground_truth.as_ref().expect("ground truth");
        let (pose, depth) = (gt.pose.as_ref().expect("gt pose"), gt.depth.as_ref().expect("gt depth"));
        let errors = pose_errors(&zero.pose.expect("a pose"), pose, &f.intrinsics, depth);
        assert!(errors.registered(), "{errors:?}");
    }
}

/// With the confidence-rank model (`params/ablations/confidence_rank.yaml`: the network takes
/// the confidence's within-frame ranks and the keypoints are ranked by them), a matcher that
/// publishes the same order on another scale (here 10·s³) gets the same poses and kept sets
/// as the published scores: nothing downstream sees more than the order.
#[test]
fn the_rank_model_localizes_any_calibration_of_the_same_order_alike() {
    if onnx_runtime().is_none() {
        return;
    }
    let scene = generate(&SynthConfig { frames: 3, seed: 11, ..SynthConfig::preset("extreme").unwrap() });
    let mut recalibrated = scene.frames.clone();
    // Strictly increasing in f32 over the scores (an offset would merge the smallest cubes).
    recalibrated.iter_mut().flat_map(|f| f.correspondences.iter_mut()).for_each(|c| c.score = 10.0 * c.score.powi(3));
    let mut params = LocalizerParams::default();
    params.network.model_path = "models/ablations/confidence_rank.onnx".into();
    params.network.keypoint_ranking = angle_i2p::reject::network::KeypointRanking::SpectralMatcherRank;
    let localize = |frames: &[Frame]| {
        let mut localizer = Localizer::new(params.clone()).expect("a localizer");
        localizer.set_map(&scene.map);
        frames.iter().map(|f| localizer.process(f)).collect::<Vec<_>>()
    };
    let (published, other) = (localize(&scene.frames), localize(&recalibrated));
    for ((a, b), f) in published.iter().zip(&other).zip(&scene.frames) {
        assert_eq!(a.pose, b.pose);
        let scores = |l: &angle_i2p::pipeline::Localization| l.kept.iter().map(|c| c.score).collect::<Vec<_>>();
        assert_eq!(scores(a), scores(b));
        let gt = f.ground_truth.as_ref().expect("ground truth");
        let (pose, depth) = (gt.pose.as_ref().expect("gt pose"), gt.depth.as_ref().expect("gt depth"));
        let errors = pose_errors(&a.pose.expect("a pose"), pose, &f.intrinsics, depth);
        assert!(errors.registered(), "{errors:?}");
    }
}

/// The cascade (issue #9): frames with a clear majority of good matches end on the fast path
/// (no rejection), hard frames go on to the rejector; both are localized.
#[test]
fn easy_frames_end_on_the_fast_path_and_hard_ones_do_not() {
    let mut localizer = Localizer::new(LocalizerParams { method: Method::Consistency, ..LocalizerParams::default() })
        .expect("a localizer");
    for (preset, fast) in [("easy+close", true), ("sift", true), ("hard", false)] {
        let scene = generate(&SynthConfig { frames: 3, seed: 9, ..SynthConfig::preset(preset).unwrap() });
        localizer.set_map(&scene.map);
        for f in &scene.frames {
            let loc = localizer.process(f);
            assert_eq!(loc.fast_path, fast, "{preset}: {:?}", loc.fast_path_check);
            assert!(loc.pose.is_some(), "{preset}: {:?}", loc.failure);
            if fast {
                assert_eq!(loc.timings.geometry_ms + loc.timings.reject_ms, 0.0, "{preset}: no rejection ran");
            } else {
                assert!(loc.fast_path_check.is_some_and(|c| c.inlier_ratio < 0.3), "{preset}");
            }
        }
    }
}

/// Issue #34: a frame settles on the fast path whatever share of the view the map covers. The
/// map here shows the left 40 % of easy frames only; the matcher still pairs pixels on the right
/// with map points (the mapped part's: one in two of them is kept), so those matches are all
/// wrong, and they hold more image cells than the true ones. The right pose's inliers (33–44 % of
/// the matches) cover the part its matched map points project into, and each frame settles;
/// counted against every cell holding a match, the first frame's inliers held 0.46 of them, under
/// the bar of one half, and went the full path.
#[test]
fn a_frame_whose_map_covers_part_of_the_view_settles_on_the_fast_path() {
    let scene = generate(&SynthConfig { frames: 2, seed: 9, ..SynthConfig::preset("easy").unwrap() });
    let mut localizer = Localizer::new(LocalizerParams { method: Method::Consistency, ..LocalizerParams::default() })
        .expect("a localizer");
    localizer.set_map(&scene.map);
    for frame in &scene.frames {
        let partial = mapped_on_the_left(frame, 0.4);
        let loc = localizer.process(&partial);
        assert!(loc.fast_path, "{:?}", loc.fast_path_check);
        let gt = partial.ground_truth.as_ref().expect("ground truth");
        let (truth, depth) = (gt.pose.as_ref().expect("gt pose"), gt.depth.as_ref().expect("gt depth"));
        let errors = pose_errors(&loc.pose.expect("a pose"), truth, &partial.intrinsics, depth);
        assert!(errors.registered(), "{errors:?}");
    }
}

/// `frame` as a matcher would give it with a map of the left `share` of its view only: each
/// match on the rest pairs its pixel with a map point of the mapped part, and one in two of them
/// is kept.
fn mapped_on_the_left(frame: &Frame, share: f64) -> Frame {
    let edge = share * frame.intrinsics.width as f64;
    let mapped: Vec<_> = frame.correspondences.iter().filter(|c| c.pixel.x < edge).map(|c| c.point).collect();
    let mut partial = frame.clone();
    partial.correspondences = frame
        .correspondences
        .iter()
        .filter(|c| c.pixel.x >= edge)
        .step_by(2)
        .enumerate()
        .map(|(i, c)| Correspondence { point: mapped[(i * 7919) % mapped.len()], ..*c })
        .chain(frame.correspondences.iter().filter(|c| c.pixel.x < edge).copied())
        .collect();
    partial
}

/// A frame after one the fast path did not settle builds its geometry beside the fast path (on
/// another core); what it returns is what it returns with the two one after the other (as for a
/// localizer's first frame), whether the fast path then settles it or not.
#[test]
fn geometry_beside_the_fast_path_changes_no_result() {
    let params = LocalizerParams { method: Method::Consistency, ..LocalizerParams::default() };
    let hard = generate(&SynthConfig { frames: 2, seed: 9, ..SynthConfig::preset("hard").unwrap() });
    let sift = generate(&SynthConfig { frames: 1, seed: 9, ..SynthConfig::preset("sift").unwrap() });
    let last_of = |frames: &[&Frame], map: &MapCloud| {
        let mut localizer = Localizer::new(params.clone()).expect("a localizer");
        localizer.set_map(map);
        frames.iter().map(|f| localizer.process(f)).last().expect("a frame")
    };
    let (unsettled, next) = (&hard.frames[0], &hard.frames[1]);
    assert!(!last_of(&[unsettled], &hard.map).fast_path);
    for (frame, map, settles) in [(next, &hard.map, false), (&sift.frames[0], &sift.map, true)] {
        let alone = last_of(&[frame], map);
        let beside = last_of(&[unsettled, frame], map);
        assert_eq!(beside.fast_path, settles);
        assert!(alone.pose.is_some());
        assert_eq!(alone.pose, beside.pose);
        assert_eq!(alone.kept, beside.kept);
        assert_eq!(alone.num_inliers, beside.num_inliers);
        assert_eq!(alone.scale_shift, beside.scale_shift);
        assert_eq!(alone.fast_path_check, beside.fast_path_check);
    }
}

/// `replay` tells its caller, frame by frame, whether the frame registered (the progress bar's
/// running RR); over the bag that is `eval`'s RR.
#[test]
fn replay_reports_each_frames_registration_as_it_goes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let bag = common::manifest().join("bags/synth-extreme");
    let params = LocalizerParams { method: Method::Ransac, ..LocalizerParams::default() };
    let mut localizer = Localizer::new(params.clone()).expect("a localizer");
    let (mut seen, mut registered) = (0usize, 0usize);
    let defaults = angle_i2p::params::AppParams::default();
    app::replay(&bag, &out, &mut localizer, app::BagEdge::of(&defaults), |p| {
        assert_eq!(p.index, seen);
        seen += 1;
        registered += usize::from(p.registered.expect("the bag has ground truth"));
    })
    .unwrap();
    let run = app::evaluate_bags(&bag, &[out], &defaults).unwrap();
    assert_eq!(seen, 20);
    assert!((100.0 * registered as f64 / seen as f64 - run.evaluations[0].summary.rr).abs() < 1e-9);
}

/// The cascade's last step (issue #9, "never worse than plain LO-RANSAC"): when a prior that
/// has nothing to do with the scene misleads rejection and PnP on the kept set finds no
/// consensus, a plain LO-RANSAC on every correspondence still localizes the frame; with the
/// step off, the same frames have no pose.
#[test]
fn a_frame_the_rejection_guided_path_leaves_without_a_pose_gets_plain_lo_ransacs() {
    let scene = generate(&SynthConfig { frames: 4, seed: 11, ..SynthConfig::preset("hard").unwrap() });
    let mut lcg = 0x9E37_79B9_7F4A_7C15u64;
    let mut noise = move || {
        lcg = lcg.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        0.5 + 4.0 * (lcg >> 40) as f32 / (1u64 << 24) as f32
    };
    let mut frames = scene.frames.clone();
    for f in &mut frames {
        let prior = f.depth_prior.as_mut().expect("synth frames carry a prior");
        prior.data.iter_mut().for_each(|d| *d = noise());
    }
    let run = |last_resort_iterations: usize| {
        let mut params = LocalizerParams { method: Method::Consistency, ..LocalizerParams::default() };
        params.cascade.last_resort_iterations = last_resort_iterations;
        // Ten (misled) picks: too few for a consensus of six among them.
        params.spectral.keep_ratio = 0.02;
        params.spectral.min_keep = 10;
        let mut localizer = Localizer::new(params).expect("a localizer");
        localizer.set_map(&scene.map);
        frames.iter().map(|f| localizer.process(f)).collect::<Vec<_>>()
    };
    let (with, without) = (run(10_000), run(0));
    let rescued: Vec<_> = with.iter().zip(&without).filter(|(w, _)| w.last_resort).collect();
    assert!(
        !rescued.is_empty(),
        "no frame needed the last resort: {:?}",
        without.iter().map(|l| &l.failure).collect::<Vec<_>>()
    );
    for (w, wo) in rescued {
        assert!(matches!(wo.failure, Some(Failure::Pnp(_))), "{:?}", wo.failure);
        let f = frames.iter().find(|f| f.stamp == w.stamp).expect("the frame");
        let gt = f.ground_truth.as_ref().and_then(|g| g.pose.as_ref()).expect("gt pose");
        let pose = w.pose.expect("a pose from the last resort");
        assert!(pose.rotation.angle_to(&gt.rotation).to_degrees() < 2.0, "{pose:?}");
        assert!(!w.fast_path && w.failure.is_none());
    }
}

/// An `/initialpose`-like gate reaches every path of the cascade: around the truth the frames
/// localize as without it; far from it, no pose outside is returned (the fast path settles, the
/// rejection-guided PnP and the last resort publish inside the gate only), and the sure pose the
/// plain search finds outside contradicts the gate.
#[test]
fn a_pose_gate_steers_every_path_of_the_cascade() {
    use angle_i2p::pnp::PoseGate;
    use nalgebra::{Translation3, Vector3};
    for preset in ["sift", "hard"] {
        let scene = generate(&SynthConfig { frames: 2, seed: 13, ..SynthConfig::preset(preset).unwrap() });
        let mut localizer = Localizer::new(LocalizerParams::default()).expect("a localizer");
        localizer.set_map(&scene.map);
        for f in &scene.frames {
            let truth = *f.ground_truth.as_ref().and_then(|g| g.pose.as_ref()).expect("gt pose");
            let near = PoseGate { centre: truth, radius_m: 0.5, max_angle_rad: 0.2 };
            localizer.set_pose_gate(Some(near.clone()));
            let loc = localizer.process(f);
            let pose = loc.pose.unwrap_or_else(|| panic!("{preset}: {:?}", loc.failure));
            assert!(near.check(&pose).is_ok() && pose.rotation.angle_to(&truth.rotation) < 0.03, "{preset}");
            let away = Translation3::from(truth.translation.vector + Vector3::new(5.0, 0.0, 0.0));
            let far = PoseGate { centre: nalgebra::Isometry3::from_parts(away, truth.rotation), ..near };
            localizer.set_pose_gate(Some(far.clone()));
            let loc = localizer.process(f);
            assert!(loc.pose.is_none_or(|p| far.check(&p).is_ok()), "{preset}: a pose outside the gate");
            // The plain search finds the true pose outside it, sure: the gate is contradicted
            // and nothing inside it is published (#38).
            assert!(
                loc.pose.is_none() && matches!(loc.failure, Some(Failure::GateContradicted { .. })),
                "{preset}: {:?}",
                loc.failure
            );
        }
        localizer.set_pose_gate(None);
    }
}

/// Rotation error (degrees) of frame `index` of `scene`, localized alone with the default
/// parameters changed by `change`, and the model trained on rooms only: the scenarios below
/// are frames where its kept sets fail in the way each step of the last choice is for (the
/// shipped model, trained on a wider mix, keeps most of their true matches).
fn last_choice_error(
    scene: &angle_i2p::synth::SynthScene,
    index: usize,
    change: impl FnOnce(&mut LocalizerParams),
) -> f64 {
    let frame = &scene.frames[index];
    let gt = frame.ground_truth.as_ref().and_then(|g| g.pose.as_ref()).expect("gt pose");
    let mut params = LocalizerParams::default();
    params.network.model_path = "models/ablations/rooms_only.onnx".into();
    // The pose the search reaches, published or not (a wrong one is held back as unsure).
    params.cascade.publish_nfa = 0.0;
    change(&mut params);
    let mut localizer = Localizer::new(params).expect("a localizer");
    localizer.set_map(&scene.map);
    let pose = localizer.process(frame).pose.expect("a pose");
    pose.rotation.angle_to(&gt.rotation).to_degrees()
}

/// The last choice on every correspondence (issue #9): at close range with a harsh prior the
/// kept set of a frame can hold only a few true matches that a wrong pose explains as well,
/// and the prior prefers it; the matches rejection left out support the true pose, which the
/// verifier had as its next candidate. With the step off, the frame's pose is tens of degrees
/// off; with it, within a few.
#[test]
fn the_rejected_matches_settle_between_the_verifiers_candidates() {
    if onnx_runtime().is_none() {
        return;
    }
    let scene = generate(&SynthConfig { frames: 20, seed: 7, ..SynthConfig::preset("extreme+close+harsh").unwrap() });
    let with = last_choice_error(&scene, 11, |_| ());
    // The kept set alone: neither the verifier's next candidates nor the plain search's pose.
    let without = last_choice_error(&scene, 11, |p| {
        p.final_refine.alternatives = 0;
        p.cascade.confirm_nfa = 0.0;
    });
    assert!(without > 10.0, "the kept set alone: {without}°");
    assert!(with < 3.0, "with the rejected matches: {with}°");
}

/// The plain search's pose is a candidate of the last choice too: on a close-range hard frame
/// whose kept set holds only a wrong cluster of 9 matches (none of the verifier's candidates is
/// near the truth, and the fast path's stages end 73° off too), the guided pose is not sure, the
/// plain search goes on over every match and finds the true pose, which explains 50-odd of
/// them; it replaces the guided one whether or not the verifier's alternatives are weighed.
#[test]
fn the_plain_searchs_pose_is_a_candidate_of_the_last_choice() {
    if onnx_runtime().is_none() {
        return;
    }
    let scene = generate(&SynthConfig { frames: 100, seed: 11, ..SynthConfig::preset("hard+close").unwrap() });
    let with = last_choice_error(&scene, 65, |_| ());
    let without_alternatives = last_choice_error(&scene, 65, |p| p.final_refine.alternatives = 0);
    let without = last_choice_error(&scene, 65, |p| p.cascade.confirm_nfa = 0.0);
    assert!(without > 10.0, "the kept set and the fast path's stages: {without}°");
    assert!(with < 2.0, "with the plain search gone on: {with}°");
    assert!(without_alternatives < 2.0, "without the verifier's alternatives: {without_alternatives}°");
}

/// Two robust passes keep the frames a third search once rescued (#34): a search over every
/// match in the network's order ran beside the guided one, and saved a close-range hard frame
/// whose kept set lost most true matches (PnP's pose there mirrored across their plane, 8°
/// off) and a building frame whose fast path had settled in a wrong basin 4° off. With the
/// plain search on one PROSAC schedule over its whole budget and the guided search alone,
/// both stay right.
#[test]
fn two_robust_passes_keep_the_frames_a_third_search_once_rescued() {
    if onnx_runtime().is_none() {
        return;
    }
    let close = generate(&SynthConfig { frames: 100, seed: 15, ..SynthConfig::preset("hard+close").unwrap() });
    let error = last_choice_error(&close, 73, |_| ());
    assert!(error < 1.5, "close range, the kept set's mirror pose: {error}°");
    let building = generate(&SynthConfig { frames: 40, seed: 32, ..SynthConfig::preset("building").unwrap() });
    let error = last_choice_error(&building, 20, |_| ());
    assert!(error < 1.0, "a building, the fast path's wrong basin: {error}°");
}

/// The last refinement takes every match within PnP's threshold under a loss scaled to the
/// frame's noise (issue #9): on a building frame whose pose came half a degree off, least
/// squares, on the matches within a few σ̂ of it or on all within the threshold alike, stays there
/// (the matches near it agree with it); the Cauchy loss at 2σ̂ over all of them pulls it to the
/// truth. (Frame 33 of seed 32 was such a frame before the building's map normals came from
/// planar cells; the network's kept set there now leads PnP near the truth by itself.)
#[test]
fn in_a_building_the_last_refinement_weighs_every_match_by_the_frames_noise() {
    if onnx_runtime().is_none() {
        return;
    }
    let scene = generate(&SynthConfig { frames: 40, seed: 31, ..SynthConfig::preset("building").unwrap() });
    let robust = last_choice_error(&scene, 34, |_| ());
    let least_squares = last_choice_error(&scene, 34, |p| p.final_refine.loss = angle_i2p::pnp::RobustLoss::Trivial);
    assert!(least_squares > 0.45, "least squares: {least_squares}°");
    assert!(robust < 0.3, "the Cauchy loss at 2σ̂: {robust}°");
}

/// With a harsh prior and least squares in the last refinement, PnP's pose on the kept set of
/// another building frame settles in a wrong basin half a degree off; a candidate of the last choice
/// next to it keeps nine in ten of its inliers, explains as many and fits every match better
/// (MSAC): the same answer, sharpened (to about a quarter of a degree), which the last choice
/// takes without the margin another answer needs. The chosen pose refined once more from a wide
/// gathering (`final_refine.widen_threshold`) leaves that basin too, without the alternatives.
/// (The default Cauchy loss of the last refinement leaves that basin by itself here; the rules
/// still guard a loss or a frame it does not.)
#[test]
fn in_a_building_the_same_answer_that_fits_better_replaces_pnps() {
    if onnx_runtime().is_none() {
        return;
    }
    let scene = generate(&SynthConfig { frames: 40, seed: 32, ..SynthConfig::preset("building+harsh").unwrap() });
    let least_squares = |p: &mut LocalizerParams| p.final_refine.loss = angle_i2p::pnp::RobustLoss::Trivial;
    let alternatives = last_choice_error(&scene, 18, |p| {
        least_squares(p);
        p.final_refine.widen_threshold = 1.0;
    });
    let widened = last_choice_error(&scene, 18, |p| {
        least_squares(p);
        p.final_refine.alternatives = 0;
    });
    let neither = last_choice_error(&scene, 18, |p| {
        least_squares(p);
        p.final_refine.alternatives = 0;
        p.final_refine.widen_threshold = 1.0;
    });
    assert!(neither > 0.4, "PnP's pose on the kept set: {neither}°");
    assert!(alternatives < 0.3, "the sharper pose next to it: {alternatives}°");
    assert!(widened < 0.3, "the pose out of its basin from the wide gathering: {widened}°");
}

/// A rejector misled on a scene it does not transfer to: it scores wrong matches high and every
/// true one last (the scores of each frame, known to the test, found by the frame's first pixel),
/// keeping a set with no true match — as the learned rejector did on an office nobody tuned on.
struct MisledRejector {
    scores: std::collections::HashMap<(u64, u64), Vec<f32>>,
}

impl MisledRejector {
    fn key(pixel: &nalgebra::Point2<f64>) -> (u64, u64) {
        (pixel.x.to_bits(), pixel.y.to_bits())
    }
}

impl angle_i2p::reject::Rejector for MisledRejector {
    fn name(&self) -> &'static str {
        "misled"
    }

    fn reject(
        &mut self,
        geometry: &angle_i2p::reject::FrameGeometry,
    ) -> Result<angle_i2p::reject::Rejection, angle_i2p::reject::RejectError> {
        let first = geometry.pixels.first().map(Self::key).unwrap_or_default();
        let scores = self.scores.get(&first).cloned().unwrap_or_else(|| vec![0.5; geometry.pixels.len()]);
        let mut kept: Vec<usize> = (0..scores.len()).filter(|&i| scores[i] >= 0.5).collect();
        kept.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
        Ok(angle_i2p::reject::Rejection { scores, kept })
    }
}

/// Never worse than plain robust PnP: a rejector that throws the true matches away orders the
/// search, but the geometry still finds the pose that every match supports. On extreme frames
/// (6 % true matches, three quarters of the wrong ones moved patch-wise) with every true match
/// scored last by the rejector (the matcher's own confidence as generated), the default
/// registers what `ransac` registers and publishes no more wrong poses (within one frame of
/// ten); without the check of unsure poses over every match (`cascade.confirm_nfa: 0`) it
/// publishes the misled set's wrong poses (2 of 10 registered).
#[test]
fn a_rejector_that_throws_the_true_matches_away_is_never_worse_than_plain_ransac() {
    let scene = generate(&SynthConfig { frames: 10, seed: 21, ..SynthConfig::preset("extreme").unwrap() });
    let frames = &scene.frames;
    let misled = || {
        let scores = frames
            .iter()
            .zip(&scene.stats)
            .filter_map(|(f, stats)| {
                let first = MisledRejector::key(&f.correspondences.first()?.pixel);
                let scores = stats
                    .labels
                    .iter()
                    .enumerate()
                    .map(|(i, label)| match label {
                        angle_i2p::synth::CorrLabel::Inlier => 0.01,
                        _ => 0.5 + 0.5 * ((i * 7919) % 1000) as f32 / 1000.0,
                    })
                    .collect();
                Some((first, scores))
            })
            .collect();
        Box::new(MisledRejector { scores })
    };
    let run = |params: LocalizerParams| {
        let mut localizer = match params.method {
            Method::Ransac => Localizer::new(params).expect("a localizer"),
            _ => Localizer::with_rejector(params, misled()),
        };
        localizer.set_map(&scene.map);
        let rows: Vec<FrameMetrics> = frames
            .iter()
            .map(|f| {
                let gt = f.ground_truth.as_ref().expect("ground truth");
                let (pose, depth) = (gt.pose.as_ref().expect("gt pose"), gt.depth.as_ref().expect("gt depth"));
                let loc = localizer.process(f);
                FrameMetrics {
                    stamp: f.stamp,
                    inlier_ratio: 0.0,
                    errors: loc.pose.map(|p| PoseErrors {
                        nees: loc.covariance.and_then(|c| nees(&p, pose, &c)),
                        ..pose_errors(&p, pose, &f.intrinsics, depth)
                    }),
                    ms: None,
                }
            })
            .collect();
        summarize(&rows)
    };
    let default = LocalizerParams { method: Method::AngleI2p, ..LocalizerParams::default() };
    let mut unchecked = default.clone();
    unchecked.cascade.confirm_nfa = 0.0;
    let ransac = run(LocalizerParams { method: Method::Ransac, ..LocalizerParams::default() });
    let (checked, unchecked) = (run(default), run(unchecked));
    eprintln!("ransac {ransac:?}\nchecked {checked:?}\nunchecked {unchecked:?}");
    // One frame in ten may differ: plain LO-RANSAC's 10 000 draws find the true pose of an
    // extreme frame with a probability, not surely (measured: ransac 10/10, checked 9/10).
    assert!(checked.rr + 10.0 >= ransac.rr, "RR {} vs ransac {}", checked.rr, ransac.rr);
    assert!(
        checked.false_pose_rate.unwrap_or(0.0) <= ransac.false_pose_rate.unwrap_or(0.0) + 10.0,
        "false poses {:?} vs ransac {:?}",
        checked.false_pose_rate,
        ransac.false_pose_rate
    );
    assert!(unchecked.rr < checked.rr, "the misled set alone registers as much: {} %", unchecked.rr);
}

/// At most two robust-estimation passes on any frame (#34), whatever path it takes: the plain
/// search over every match (the fast path's stages, then confirming or rescuing) and the guided
/// search on the kept matches; one where the fast path settles the frame, and where the cascade
/// is off the plain search starts only when the guided pose needs it.
#[test]
fn no_frame_takes_more_than_two_robust_passes() {
    let mut methods = vec![Method::Consistency];
    if onnx_runtime().is_some() {
        methods.push(Method::AngleI2p);
    }
    for preset in ["sift", "hard", "extreme", "extreme+close"] {
        let scene = generate(&SynthConfig { frames: 8, seed: 5, ..SynthConfig::preset(preset).unwrap() });
        for &method in &methods {
            for cascade in [true, false] {
                let mut params = LocalizerParams { method, ..LocalizerParams::default() };
                params.cascade.enabled = cascade;
                let mut localizer = Localizer::new(params).expect("a localizer");
                localizer.set_map(&scene.map);
                for frame in &scene.frames {
                    let loc = localizer.process(frame);
                    let case = format!("{preset}, {}, cascade {cascade}, frame {}", method.name(), frame.stamp);
                    assert!((1..=2).contains(&loc.robust_passes), "{case}: {} passes", loc.robust_passes);
                    if loc.fast_path {
                        assert_eq!(loc.robust_passes, 1, "{case}: settled by the fast path");
                    }
                    if cascade && !loc.fast_path {
                        assert_eq!(loc.robust_passes, 2, "{case}: the plain search and the guided one");
                    }
                }
            }
        }
    }
}

/// Tracking (#35): frames in stamp order are a stream, and a pose that only the prior confirms
/// is withheld when it lies off the track's prediction. On `redkitchen-extreme-val-disparity`,
/// where frames alone publish 7.4 % wrong poses (4 of 54, 11–19° off, confirmed by the prior
/// alone), the stream publishes fewer (measured 2.0 %) and registers as many frames.
#[test]
fn tracking_withholds_poses_only_the_prior_confirms_off_the_track() {
    if onnx_runtime().is_none() {
        return;
    }
    let name = "redkitchen-extreme-val-disparity";
    let tracked = LocalizerParams { depth_kind: DepthKind::Disparity, ..LocalizerParams::default() };
    assert!(tracked.tracking.enabled, "tracking is the default");
    let mut alone = tracked.clone();
    alone.tracking.enabled = false;
    let Some((alone, _)) = real_bag_summary_with(name, alone) else { return };
    let Some((tracked, _)) = real_bag_summary_with(name, tracked) else { return };
    let (fp_alone, fp_tracked) = (alone.false_pose_rate.unwrap_or(0.0), tracked.false_pose_rate.unwrap_or(0.0));
    assert!(tracked.rr >= alone.rr, "RR {:.1} % tracked vs {:.1} % alone", tracked.rr, alone.rr);
    assert!(
        fp_tracked < fp_alone && fp_tracked <= 5.0,
        "false poses {fp_tracked:.1} % tracked vs {fp_alone:.1} % alone"
    );
}

/// Tracking settles frames on the fast path (#35): once the track's prediction has proved
/// itself, a plain pose that is sure among every match, that the search is confident of and
/// that lies within the prediction's typical error skips the rejector — on the hard tier's
/// building walk, whose support (under a third of the matches) never settles a frame alone.
/// Every frame it settles registers, and so does every frame with the track's settling off.
#[test]
fn the_track_settles_hard_frames_on_the_fast_path_where_it_predicts_them() {
    let scene = generate(&SynthConfig { frames: 30, seed: 5, ..SynthConfig::preset("building").unwrap() });
    let run = |settle_gate: f64| {
        let mut params = LocalizerParams { method: Method::Consistency, ..LocalizerParams::default() };
        params.tracking.settle_gate = settle_gate;
        let mut localizer = Localizer::new(params).expect("a localizer");
        localizer.set_map(&scene.map);
        let mut on_track = 0;
        for f in &scene.frames {
            let loc = localizer.process(f);
            let gt = f.ground_truth.as_ref().expect("ground truth");
            let (pose, depth) = (gt.pose.as_ref().expect("gt pose"), gt.depth.as_ref().expect("gt depth"));
            let errors = loc.pose.map(|p| pose_errors(&p, pose, &f.intrinsics, depth));
            assert!(errors.is_some_and(|e| e.registered()), "frame {}: {errors:?} {:?}", f.stamp, loc.failure);
            assert!(!loc.fast_path_on_track || loc.fast_path, "settled on the track is settled by the fast path");
            if loc.fast_path_on_track {
                assert_eq!(loc.robust_passes, 1, "no rejector, no guided search");
                assert_eq!(loc.timings.reject_ms, 0.0);
                on_track += 1;
            }
        }
        on_track
    };
    let settled = run(LocalizerParams::default().tracking.settle_gate);
    eprintln!("{settled} of 30 frames settled on the track");
    assert!(settled >= 5, "{settled} of 30 frames settled on the track");
    assert_eq!(run(0.0), 0);
}

/// Support that wrong matches alone give a frame is none, whatever the prior says (#34: a
/// published pose is a promise). Where the map covers half the room, the matcher pairs the
/// pixels beyond it with points of the mapped half; the poses those wrong matches support render
/// depths an affine prior agrees with, and frames alone the prior confirmed some of them though
/// their support was what chance gives a frame many times over. With `cascade.prior_nfa` the
/// prior confirms only support not left to chance: no wrong pose is published, and the frames
/// the geometry supports still are (measured: RR 60 % either way, false poses 33 % → 0).
#[test]
fn the_prior_confirms_no_pose_that_chance_supports_as_well() {
    let scene = generate(&SynthConfig { frames: 20, seed: 91, ..SynthConfig::preset("sift+partial-map").unwrap() });
    let run = |prior_nfa: f64| {
        let mut params = LocalizerParams { method: Method::Consistency, ..LocalizerParams::default() };
        params.tracking.enabled = false;
        params.cascade.prior_nfa = prior_nfa;
        summarize(&localize_params(&scene.frames, Some(&scene.map), params).0)
    };
    let (bounded, unbounded) = (run(LocalizerParams::default().cascade.prior_nfa), run(0.0));
    eprintln!("prior_nfa default {bounded:?}\nprior_nfa 0 {unbounded:?}");
    assert!(unbounded.false_pose_rate.unwrap_or(0.0) > 0.0, "the prior confirmed no wrong pose");
    assert_eq!(bounded.false_pose_rate.unwrap_or(0.0), 0.0, "a wrong pose published");
    assert!(bounded.rr >= 50.0, "RR {:.1} %", bounded.rr);
    // A frame withheld so says why: the prior agreed, the support was too weak for it.
    let mut params = LocalizerParams { method: Method::Consistency, ..LocalizerParams::default() };
    params.tracking.enabled = false;
    let mut localizer = Localizer::new(params).expect("a localizer");
    localizer.set_map(&scene.map);
    let reasons: Vec<String> = scene
        .frames
        .iter()
        .filter_map(|f| match localizer.process(f).failure {
            Some(failure @ Failure::Unsure { prior_level: Some(_), .. }) => Some(failure.to_string()),
            _ => None,
        })
        .collect();
    assert!(!reasons.is_empty(), "no frame withheld for a support too weak for the prior");
    assert!(
        reasons.iter().all(|r| r.contains("too weak a support for the prior to confirm (above 2.0)")),
        "{reasons:?}"
    );
}

/// A pose the track settles is one the fast path looked for with its whole budget (#35): the
/// plain search's stopping rule (PROSAC's, on the matcher's best-ranked matches) can be met by
/// a consensus in a wrong basin next to the truth while a larger one lies among the matches
/// ranked lower. On this small-map hard frame (index 17) the search stopped after 140 draws at
/// a pose 5.2° off explaining 56 matches, 6 of them wrong, that the track settled; drawn to the
/// budget, it finds the one explaining 63 (1.25°, as the full path's).
#[test]
fn the_track_settles_no_pose_before_the_fast_path_has_drawn_its_budget() {
    let preset = SynthConfig::preset("hard+small-map+disparity").unwrap();
    let scene = generate(&SynthConfig { frames: 20, seed: 104, ..preset });
    let params =
        LocalizerParams { method: Method::Consistency, depth_kind: DepthKind::Disparity, ..LocalizerParams::default() };
    let budget = params.cascade.max_iterations;
    let mut localizer = Localizer::new(params).expect("a localizer");
    localizer.set_map(&scene.map);
    let (mut settled, mut worst_deg, mut fewest_draws) = (0, 0.0f64, usize::MAX);
    for f in &scene.frames {
        let loc = localizer.process(f);
        let gt = f.ground_truth.as_ref().expect("ground truth");
        let (pose, depth) = (gt.pose.as_ref().expect("gt pose"), gt.depth.as_ref().expect("gt depth"));
        let errors = loc.pose.map(|p| pose_errors(&p, pose, &f.intrinsics, depth)).expect("a pose");
        if loc.fast_path_on_track {
            settled += 1;
            worst_deg = worst_deg.max(errors.rotation_deg);
            fewest_draws = fewest_draws.min(loc.pnp_iterations);
        }
    }
    eprintln!(
        "{settled} of 20 frames settled on the track, the worst {worst_deg:.2}° off, {fewest_draws} draws or more"
    );
    assert!(settled >= 5, "{settled} of 20 frames settled on the track");
    assert!(worst_deg < 2.0, "a frame settled {worst_deg:.2}° off");
    assert!(fewest_draws >= budget, "a frame settled after {fewest_draws} draws");
}

/// A published covariance is a promise too (#35 item 2). On maps with their own error — the
/// shared redkitchen bags (a fused map seen through a depth-to-colour registration) and the
/// `office` preset (a map fused from keyframes with SfM-like pose errors) — the true pose lies
/// inside the published 95 % ellipsoid on at least 90 % of the frames; with the inliers' pixel
/// noise alone (`covariance.map_error_deg: 0`) it did on at most a fifth.
#[test]
fn the_published_covariance_covers_the_true_pose_on_a_map_with_its_own_error() {
    let office = generate(&SynthConfig { frames: 12, seed: 1, ..SynthConfig::preset("hard+office").unwrap() });
    let coverage = |map_error_deg: f64| {
        let mut params = LocalizerParams { method: Method::Consistency, ..LocalizerParams::default() };
        params.covariance.map_error_deg = map_error_deg;
        let (rows, _) = localize_params(&office.frames, None, params);
        let s = summarize(&rows);
        eprintln!("office, map error {map_error_deg}°: {s:?}");
        assert_eq!(s.rr, 100.0, "{s:?}");
        s.covariance_95.expect("every pose carries a covariance")
    };
    let (calibrated, pixel_noise_only) = (coverage(1.0), coverage(0.0));
    assert!(calibrated >= 90.0 && pixel_noise_only <= 20.0, "{calibrated} % vs {pixel_noise_only} %");
    for name in ["redkitchen-sift-val", "redkitchen-hard-val"] {
        let params = LocalizerParams { method: Method::Consistency, ..LocalizerParams::default() };
        let Some((s, _)) = real_bag_summary_with(name, params.clone()) else { return };
        let mut noise_only = params;
        noise_only.covariance.map_error_deg = 0.0;
        let Some((before, _)) = real_bag_summary_with(name, noise_only) else { return };
        let (now, then) = (s.covariance_95.unwrap(), before.covariance_95.unwrap());
        assert!(now >= 90.0 && then <= 20.0, "{name}: {now} % vs {then} %");
    }
}
