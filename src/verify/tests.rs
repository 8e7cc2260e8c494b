//! Tests of the verifier: rendering (nearest surface, splats), agreement under the prior's
//! unknown affine map, disparity priors, partial maps and the render subsample.

use super::*;
use nalgebra::{Translation3, UnitQuaternion, Vector3};

fn intrinsics() -> Intrinsics {
    Intrinsics { fx: 300.0, fy: 300.0, cx: 160.0, cy: 120.0, width: 320, height: 240 }
}

/// A box room, 6 × 4 × 3 m, sampled every 5 cm on its walls, floor and ceiling.
fn room() -> Vec<Point3<f32>> {
    let mut pts = Vec::new();
    let step = 0.05f32;
    let (sx, sy, sz) = (6.0f32, 4.0f32, 3.0f32);
    let grid = |a: f32, b: f32| {
        (0..(a / step) as i32)
            .flat_map(move |i| (0..(b / step) as i32).map(move |j| (i as f32 * step, j as f32 * step)))
    };
    for (u, v) in grid(sx, sy) {
        pts.push(Point3::new(u, v, 0.0));
        pts.push(Point3::new(u, v, sz));
    }
    for (u, v) in grid(sx, sz) {
        pts.push(Point3::new(u, 0.0, v));
        pts.push(Point3::new(u, sy, v));
    }
    for (u, v) in grid(sy, sz) {
        pts.push(Point3::new(0.0, u, v));
        pts.push(Point3::new(sx, u, v));
    }
    // A table in the room, so that views differ in more than a plane.
    for (u, v) in grid(1.0, 1.0) {
        pts.push(Point3::new(2.5 + u, 1.5 + v, 2.2));
    }
    pts
}

/// Camera-to-map pose looking from `eye` along +x with a small yaw.
fn pose(eye: [f64; 3], yaw: f64) -> Isometry3<f64> {
    // Optical frame (z forward, x right, y down) looking along map +x, down map +z.
    let base = UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(
        nalgebra::Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0),
    ));
    let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
    Isometry3::from_parts(Translation3::new(eye[0], eye[1], eye[2]), turn * base)
}

/// The prior a monocular network would give at `truth`: the map's depth, scaled and
/// shifted, at a quarter of the camera's resolution (dense: every map point, 4 px cells).
fn prior_at(truth: &Isometry3<f64>, scale: f32, shift: f32) -> DepthImage {
    let k = intrinsics();
    let dense = RenderMap::new(&room(), usize::MAX);
    let params = VerifyParams { cell_px: 4.0, ..VerifyParams::default() };
    let flat = DepthImage::new(k.width, k.height, vec![1.0; (k.width * k.height) as usize]);
    let v = PriorVerifier::new(&dense, &flat, DepthKind::Depth, &k, &params).unwrap();
    let data = v.render(truth).iter().map(|&z| if z.is_finite() { (z - shift) / scale } else { f32::NAN }).collect();
    DepthImage::new(v.cols as u32, v.rows as u32, data)
}

#[test]
fn render_sees_the_nearest_surface() {
    let map = RenderMap::new(&room(), 1_000_000);
    let k = intrinsics();
    let flat = DepthImage::new(k.width, k.height, vec![1.0; (k.width * k.height) as usize]);
    let v = PriorVerifier::new(&map, &flat, DepthKind::Depth, &k, &VerifyParams::default()).unwrap();
    // From x = 1 looking along +x, the far wall (x = 6) is 5 m away at the image centre.
    let depth = v.render(&pose([1.0, 2.0, 1.5], 0.0));
    let centre = depth[(v.rows / 2) * v.cols + v.cols / 2];
    assert!((centre - 5.0).abs() < 0.1, "{centre}");
    assert!(depth.iter().all(|z| z.is_finite()), "inside a closed room every cell sees a wall");
}

/// A sparse screen of points 0.5 m in front of the camera (4 cm apart: three 8 px cells
/// there) before the room's far wall, 5 m away.
fn screen_before_wall() -> Vec<Point3<f32>> {
    let mut pts = room();
    for i in -15..=15 {
        for j in -15..=15 {
            pts.push(Point3::new(1.5, 2.0 + 0.04 * i as f32, 1.5 + 0.04 * j as f32));
        }
    }
    pts
}

#[test]
fn splats_let_a_sparse_near_surface_hide_what_lies_behind_it() {
    let k = intrinsics();
    let flat = DepthImage::new(k.width, k.height, vec![1.0; (k.width * k.height) as usize]);
    let map = RenderMap::new(&screen_before_wall(), usize::MAX);
    let at = pose([1.0, 2.0, 1.5], 0.0);
    let near_share = |splat_spacings: f64| {
        let params = VerifyParams { cell_px: 8.0, splat_spacings, ..VerifyParams::default() };
        let v = PriorVerifier::new(&map, &flat, DepthKind::Depth, &k, &params).unwrap();
        let depth = v.render(&at);
        depth.iter().filter(|&&z| z < 1.0).count() as f64 / depth.len() as f64
    };
    // The screen fills the view. Points alone leave most cells to the wall behind it; splats
    // one spacing wide (the room's 5 cm, measured on the map) close the gaps.
    let (points, splats) = (near_share(0.0), near_share(1.0));
    assert!(points < 0.3, "{points}");
    assert!(splats > 0.9, "{splats}");
}

#[test]
fn far_points_still_fill_one_cell_with_splats_on() {
    // The room seen from 1 m: a 5 cm spacing spans under a 32 px cell, so splats change nothing.
    let map = RenderMap::new(&room(), 1_000_000);
    let k = intrinsics();
    let flat = DepthImage::new(k.width, k.height, vec![1.0; (k.width * k.height) as usize]);
    let render = |splat_spacings| {
        let params = VerifyParams { splat_spacings, ..VerifyParams::default() };
        PriorVerifier::new(&map, &flat, DepthKind::Depth, &k, &params).unwrap().render(&pose([1.0, 2.0, 1.5], 0.3))
    };
    assert_eq!(render(0.0), render(1.0));
}

#[test]
fn the_true_pose_agrees_and_wrong_poses_do_not_whatever_the_prior_scale() {
    let map = RenderMap::new(&room(), 40_000);
    let k = intrinsics();
    let truth = pose([1.0, 1.2, 1.4], 0.3);
    for (scale, shift) in [(1.0, 0.0), (0.4, -0.5), (2.5, 0.8)] {
        let prior = prior_at(&truth, scale, shift);
        let v = PriorVerifier::new(&map, &prior, DepthKind::Depth, &k, &VerifyParams::default()).unwrap();
        let good = v.agreement(&truth).share();

        assert!(good > 0.9, "scale {scale}: true pose agrees in {good}");
        let slightly_off = v.agreement(&pose([1.02, 1.21, 1.4], 0.31)).share();
        assert!(slightly_off > 0.7, "a pose near the truth still agrees: {slightly_off}");
        // Sideways, turned, elsewhere (not straight ahead towards a wall: that changes depth
        // by a constant, which an affine-ambiguous prior cannot tell).
        let wrong_poses = [
            pose([1.0, 2.8, 1.4], 0.3),
            pose([1.0, 1.2, 1.4], 1.2),
            pose([1.0, 1.2, 1.4], 0.6),
            pose([4.5, 1.0, 2.0], -0.8),
            pose([2.0, 2.0, 2.0], 0.0),
        ];
        for wrong in wrong_poses {
            let bad = v.agreement(&wrong).share();
            assert!(bad < good - 0.25, "wrong pose {wrong}: {bad} vs true {good}");
        }
    }
}

#[test]
fn inverse_depth_priors_are_inverted() {
    let map = RenderMap::new(&room(), 40_000);
    let k = intrinsics();
    let truth = pose([1.5, 2.0, 1.0], -0.2);
    let depth = prior_at(&truth, 1.0, 0.0);
    let inverse = DepthImage::new(depth.width, depth.height, depth.data.iter().map(|d| 1.0 / d).collect());
    let v = PriorVerifier::new(&map, &inverse, DepthKind::InverseDepth, &k, &VerifyParams::default()).unwrap();
    assert!(v.agreement(&truth).share() > 0.9);
}

#[test]
fn affine_disparity_priors_are_verified_in_inverse_depth() {
    let map = RenderMap::new(&room(), 40_000);
    let k = intrinsics();
    let truth = pose([1.5, 2.0, 1.0], -0.2);
    let depth = prior_at(&truth, 1.0, 0.0);
    // prior = 2/z + 0.5: not affine in depth, nor after inverting.
    let disparity = DepthImage::new(depth.width, depth.height, depth.data.iter().map(|d| 2.0 / d + 0.5).collect());
    let params = VerifyParams::default();
    let v = PriorVerifier::new(&map, &disparity, DepthKind::Disparity, &k, &params).unwrap();
    let good = v.agreement(&truth);
    assert!(good.share() > 0.9, "{good:?}");
    let bad = v.agreement(&pose([1.0, 1.2, 1.4], 1.2));
    assert!(bad.share() < good.share() - 0.25, "{bad:?} vs {good:?}");
}

#[test]
fn a_map_covering_part_of_the_view_is_judged_on_what_it_covers() {
    // Only the left half of the room's points: the true pose explains all it sees.
    let half: Vec<_> = room().into_iter().filter(|p| p.y < 2.0).collect();
    let map = RenderMap::new(&half, 40_000);
    let k = intrinsics();
    let truth = pose([1.0, 1.2, 1.4], 0.3);
    let v =
        PriorVerifier::new(&map, &prior_at(&truth, 1.0, 0.0), DepthKind::Depth, &k, &VerifyParams::default()).unwrap();
    let a = v.agreement(&truth);
    assert!(a.in_view < a.cells, "{a:?}");
    // Over the whole image it could never be accepted (0.7); over what it sees it is (only
    // cells on the map's border, half floor half missing wall, disagree).
    assert!(a.share() < 0.5, "{a:?}");
    assert!(a.in_view_share(0.25) > 0.75, "{a:?}");
}

#[test]
fn nothing_to_verify_with_is_none() {
    let k = intrinsics();
    let unknown = DepthImage::new(k.width, k.height, vec![f32::NAN; (k.width * k.height) as usize]);
    let map = RenderMap::new(&room(), 1000);
    assert!(PriorVerifier::new(&map, &unknown, DepthKind::Depth, &k, &VerifyParams::default()).is_none());
    let known = DepthImage::new(k.width, k.height, vec![1.0; (k.width * k.height) as usize]);
    let empty = RenderMap::new(&[], 1000);
    assert!(PriorVerifier::new(&empty, &known, DepthKind::Depth, &k, &VerifyParams::default()).is_none());
    let nan_map = RenderMap::new(&[Point3::new(f32::NAN, 0.0, 0.0)], 1000);
    assert!(nan_map.is_empty());
}

#[test]
fn render_map_subsamples_evenly() {
    let pts: Vec<Point3<f32>> = (0..1000).map(|i| Point3::new(i as f32, 0.0, 0.0)).collect();
    let map = RenderMap::new(&pts, 300);
    assert!((250..350).contains(&map.len()), "{}", map.len());
    // Spread over the whole cloud, not a prefix or a stride.
    let mean = map.x.iter().sum::<f32>() / map.len() as f32;
    assert!((mean - 500.0).abs() < 60.0, "{mean}");
    assert_eq!(RenderMap::new(&pts, 5000).len(), 1000);
}

/// Any cloud of `n` points over a 50 × 30 × 3 m box (the scale follows the count alone).
fn spread_cloud(n: usize) -> Vec<Point3<f32>> {
    (0..n)
        .map(|i| {
            let f = i as f32;
            Point3::new((f * 0.618_034).fract() * 50.0, (f * 0.414_214).fract() * 30.0, (i % 7) as f32 * 0.4)
        })
        .collect()
}

#[test]
fn the_scale_follows_the_point_count_against_the_render_budget() {
    let params = VerifyParams { max_map_points: 1_000, cull_above_budgets: 4, ..VerifyParams::default() };
    let settings = params.index_settings();
    assert_eq!(MapIndex::build(spread_cloud(4_000), &settings).scale(), MapScale::Room);
    assert_eq!(MapIndex::build(spread_cloud(4_001), &settings).scale(), MapScale::Building);
    // The index's own default is what the default verification asks for.
    assert_eq!(VerifyParams::default().index_settings(), IndexSettings::default());
    // Every map of the shared val bags (66 k–203 k points) stays a room at the defaults.
    assert!(IndexSettings::default().building_above_points >= 203_000);
}

#[test]
fn a_room_scale_map_renders_as_before() {
    // Whatever its width (here 50 m): a map the render budget covers renders all of it.
    let points = spread_cloud(20_000);
    let params = VerifyParams::default();
    let index = Arc::new(MapIndex::new(points.clone()));
    assert_eq!(index.scale(), MapScale::Room);
    let flat = RenderMap::new(&points, params.max_map_points);
    let chosen = RenderMap::of_index(&index, &params);
    assert_eq!(format!("{chosen:?}"), format!("{flat:?}"), "the room-scale render map is today's");
    let params = VerifyParams { max_map_points: 1_000, cull_above_budgets: 10, ..params };
    let big = Arc::new(MapIndex::build(points, &params.index_settings()));
    assert_eq!(big.scale(), MapScale::Building);
    assert_eq!(RenderMap::of_index(&big, &params).len(), 20_000, "a building is culled from the whole index");
}
