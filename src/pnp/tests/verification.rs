//! Robust PnP guided by a [`PoseVerifier`]: choosing among the candidates, stopping early on
//! an easy frame, and leaving a clear frame to geometry when the verifier confirms nothing.

use super::*;

/// A verifier that agrees with poses near `truth` (as the dense prior does with the true pose).
struct NearPose {
    truth: Isometry3<f64>,
    calls: std::sync::atomic::AtomicUsize,
}

impl PoseVerifier for NearPose {
    fn verify(&self, pose: &Isometry3<f64>) -> Agreement {
        self.calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let (rot, trans) = pose_error(pose, &self.truth);
        let share = (1.0 - 5.0 * rot - trans).max(0.0);
        Agreement { agreeing: (share * 1000.0).round() as usize, in_view: 1000, cells: 1000 }
    }
}

/// 8 true matches spread over the image, and a wrong pose that explains 24 others over more
/// cells: coverage alone (and the prior depths, which agree with it) pick the wrong pose; a
/// verifier that knows better gets the true one from the pool of candidates.
#[test]
fn a_verifier_chooses_among_the_candidates() {
    let mut rng = WyRand::new(5);
    let pose = random_pose(&mut rng);
    let intr = k();
    let (mut px, mut pw) = visible(&mut rng, &pose, 8, 0.3);
    let wrong = random_pose(&mut rng);
    let (wrong_px, wrong_pw) = visible(&mut rng, &wrong, 24, 0.3);
    px.extend(wrong_px);
    pw.extend(wrong_pw);
    let (random_px, random_pw) = random_pixel_matches(&mut rng, &pose, 40);
    px.extend(random_px);
    pw.extend(random_pw);
    let params = PnpParams::default();
    let plain = ransac(&intr, &px, &pw, None, &params, 2).expect("a pose");
    assert!(pose_error(&plain.pose, &wrong).0 < 0.01, "without a verifier the larger wrong set wins");

    let verifier = NearPose { truth: pose, calls: Default::default() };
    let verification = Verification {
        verifier: &verifier,
        candidates: 8,
        coverage_weight: 0.25,
        min_support_share: 0.0,
        min_iterations: 500,
        check_every: 500,
        accept: 0.9,
        min_view: 0.25,
        settle_checks: 0,
        max_iterations: 5000,
        min_trust: 0.0,
        settle_support: 0.0,
    };
    let guidance = Guidance { verification: Some(verification), ..Guidance::default() };
    let verified = ransac_guided(&intr, &px, &pw, &guidance, &params, 2).expect("a pose");
    let (rot, trans) = pose_error(&verified.pose, &pose);
    assert!(rot < 0.01 && trans < 0.05, "{rot} rad, {trans} m off");
    assert!(verified.inliers[..8].iter().all(|&f| f) && verified.inliers[8..32].iter().all(|&f| !f));
    assert!(verified.iterations >= 500, "the verifier's minimum is drawn: {}", verified.iterations);
    let calls = verifier.calls.load(std::sync::atomic::Ordering::Relaxed);
    assert!(calls > 1 && calls <= 8 * (5000 / 500 + 1), "{calls} verifications");

    // A verifier that agrees with no candidate (an unreliable prior) is not trusted: the pose is
    // chosen on geometry alone, as without it.
    let far = NearPose { truth: random_pose(&mut WyRand::new(77)), calls: Default::default() };
    let untrusted = Verification { verifier: &far, min_trust: 0.5, ..verification };
    let guidance_far = Guidance { verification: Some(untrusted), ..Guidance::default() };
    let geometric = ransac_guided(&intr, &px, &pw, &guidance_far, &params, 2).expect("a pose");
    assert!(pose_error(&geometric.pose, &wrong).0 < 0.01, "an untrusted verifier leaves geometry's choice");

    // No coverage scoring: no pool, the verifier is never asked.
    let unscored = PnpParams { coverage_cell_px: 0.0, ..params };
    let idle = NearPose { truth: pose, calls: Default::default() };
    let guidance = Guidance { verification: Some(Verification { verifier: &idle, ..verification }), ..guidance };
    ransac_guided(&intr, &px, &pw, &guidance, &unscored, 2).expect("a pose");
    assert_eq!(idle.calls.load(std::sync::atomic::Ordering::Relaxed), 0);
}

/// An easy frame: the best hypothesis verifies at once, so sampling stops where plain RANSAC
/// stops and only that candidate is verified.
#[test]
fn an_easy_frame_is_verified_once() {
    let (pose, px, pw, _) = scenario(21, 200, 0.3);
    let params = PnpParams::default();
    let plain = ransac(&k(), &px, &pw, None, &params, 4).expect("a pose");
    let verifier = NearPose { truth: pose, calls: Default::default() };
    let verification = Verification {
        verifier: &verifier,
        candidates: 8,
        coverage_weight: 0.25,
        min_support_share: 0.0,
        min_iterations: 1000,
        check_every: 1000,
        accept: 0.9,
        min_view: 0.25,
        settle_checks: 0,
        max_iterations: 10_000,
        min_trust: 0.0,
        settle_support: 0.0,
    };
    let guidance = Guidance { verification: Some(verification), ..Guidance::default() };
    let verified = ransac_guided(&k(), &px, &pw, &guidance, &params, 4).expect("a pose");
    assert_eq!(verifier.calls.load(std::sync::atomic::Ordering::Relaxed), 1);
    assert_eq!(verified.iterations, plain.iterations);
    assert!(pose_error(&verified.pose, &pose).0 < 0.01);
}

/// A prior that confirms nothing (a harsh monocular prior on a clear frame) does not hold a frame
/// whose geometry is unambiguous: its best hypothesis, explaining 70 % of the matches, is taken
/// where plain RANSAC stops; with the step off the verifier's minimum is drawn first.
#[test]
fn an_unreliable_prior_leaves_a_clear_frame_to_geometry() {
    let (pose, px, pw, _) = scenario(21, 200, 0.3);
    let params = PnpParams::default();
    let plain = ransac(&k(), &px, &pw, None, &params, 4).expect("a pose");
    let far = NearPose { truth: random_pose(&mut WyRand::new(77)), calls: Default::default() };
    // The shipped verification: 1000 hypotheses at least, trust and settling from 0.7 and 0.3.
    let verification = crate::verify::VerifyParams::default().verification(&far);
    let guidance = Guidance { verification: Some(verification), ..Guidance::default() };
    let settled = ransac_guided(&k(), &px, &pw, &guidance, &params, 4).expect("a pose");
    assert_eq!(settled.iterations, plain.iterations);
    assert_eq!(far.calls.load(std::sync::atomic::Ordering::Relaxed), 1);
    assert!(pose_error(&settled.pose, &pose).0 < 0.01);

    let off = Verification { settle_support: 0.0, ..verification };
    let guidance = Guidance { verification: Some(off), ..Guidance::default() };
    let sampled = ransac_guided(&k(), &px, &pw, &guidance, &params, 4).expect("a pose");
    assert!(sampled.iterations >= 1000, "{} hypotheses", sampled.iterations);
    assert!(pose_error(&sampled.pose, &pose).0 < 0.01);
}

/// A verifier that agrees with every pose in this share (a prior that cannot tell a pose a few
/// degrees off from the true one).
struct AgreesWithAll(f64);

impl PoseVerifier for AgreesWithAll {
    fn verify(&self, _: &Isometry3<f64>) -> Agreement {
        Agreement { agreeing: (self.0 * 1000.0).round() as usize, in_view: 1000, cells: 1000 }
    }
}

/// The network ranks a wrong cluster first and the true matches after it: PROSAC's top-ranked
/// prefix is the cluster, plain RANSAC's rule stops on it within the first hundred samples and a
/// prior that agrees with any pose would accept it there. The early check waits until uniform
/// sampling would have found a larger consensus (at most half the verifier's minimum), by when
/// the prefix holds the true matches and their pose leads.
#[test]
fn the_early_check_waits_for_the_prefix_to_grow() {
    for seed in 0..8 {
        let mut rng = WyRand::new(100 + seed);
        let pose = random_pose(&mut rng);
        let wrong = random_pose(&mut rng);
        let (mut px, mut pw) = visible(&mut rng, &wrong, 14, 0.3);
        let (true_px, true_pw) = visible(&mut rng, &pose, 40, 0.5);
        px.extend(true_px);
        pw.extend(true_pw);
        let (random_px, random_pw) = random_pixel_matches(&mut rng, &pose, 20);
        px.extend(random_px);
        pw.extend(random_pw);
        // Scores fall with the index: the wrong cluster, then the true matches, then noise.
        let scores: Vec<f32> = (0..px.len()).map(|i| 1.0 - i as f32 / px.len() as f32).collect();
        let verifier = AgreesWithAll(0.75);
        let verification = crate::verify::VerifyParams::default().verification(&verifier);
        let guidance = Guidance { scores: Some(&scores), verification: Some(verification), ..Guidance::default() };
        let solved = ransac_guided(&k(), &px, &pw, &guidance, &PnpParams::default(), seed).expect("a pose");
        let (rot, trans) = pose_error(&solved.pose, &pose);
        assert!(rot < 0.01 && trans < 0.1, "seed {seed}: {rot} rad, {trans} m off");
        assert!(solved.iterations <= 500, "seed {seed}: settled early, {} hypotheses", solved.iterations);
    }
}

/// A verifier that agrees less with poses near `truth` than with any other (a weak prior, as at
/// close range, where a pose looking elsewhere can match it better than the true one).
struct PrefersWrongPoses {
    truth: Isometry3<f64>,
}

impl PoseVerifier for PrefersWrongPoses {
    fn verify(&self, pose: &Isometry3<f64>) -> Agreement {
        let near = pose_error(pose, &self.truth).0 < 0.05;
        Agreement { agreeing: if near { 450 } else { 900 }, in_view: 1000, cells: 1000 }
    }
}

/// 40 true matches among 60 random ones: every other candidate of the pool is a minimal sample
/// of wrong matches explaining itself and a few more. However much a weak prior prefers them,
/// they are not chosen, nor do they make the prior trusted.
#[test]
fn a_minimal_sample_pose_is_never_chosen_by_the_prior() {
    for seed in 0..4 {
        let mut rng = WyRand::new(300 + seed);
        let pose = random_pose(&mut rng);
        let (mut px, mut pw) = visible(&mut rng, &pose, 40, 0.5);
        let (random_px, random_pw) = random_pixel_matches(&mut rng, &pose, 60);
        px.extend(random_px);
        pw.extend(random_pw);
        let verifier = PrefersWrongPoses { truth: pose };
        // Geometry alone would settle a frame this clear where plain RANSAC stops: off, so that
        // the pool is verified and chosen from.
        let verification =
            Verification { settle_support: 0.0, ..crate::verify::VerifyParams::default().verification(&verifier) };
        let guidance = Guidance { verification: Some(verification), ..Guidance::default() };
        let solved = ransac_guided(&k(), &px, &pw, &guidance, &PnpParams::default(), seed).expect("a pose");
        let (rot, trans) = pose_error(&solved.pose, &pose);
        assert!(rot < 0.01 && trans < 0.1, "seed {seed}: {rot} rad, {trans} m off");

        let unfiltered = Verification { min_support_share: 0.0, coverage_weight: 0.25, ..verification };
        let guidance = Guidance { verification: Some(unfiltered), ..Guidance::default() };
        // Without the share a minimal sample wins: a wrong pose, or one too weak to return.
        let wrong = match ransac_guided(&k(), &px, &pw, &guidance, &PnpParams::default(), seed) {
            Ok(solved) => pose_error(&solved.pose, &pose).0 > 0.05,
            Err(e) => matches!(e, PnpError::NoConsensus { .. }),
        };
        assert!(wrong, "seed {seed}: without the share the prior's choice is a minimal sample");
    }
}
