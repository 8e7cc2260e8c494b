//! The index against brute force on small maps.

use std::sync::Arc;

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::*;
use crate::geometry::point_cloud_normals;

fn intrinsics() -> Intrinsics {
    Intrinsics { fx: 300.0, fy: 300.0, cx: 160.0, cy: 120.0, width: 320, height: 240 }
}

/// A number in [0, 1) drawn from `key`.
fn uniform(key: u64) -> f32 {
    (splitmix(key) >> 11) as f32 / (1u64 << 53) as f32
}

/// Points on the floor, a wall and in the air of a 40 × 30 × 3 m box, spaced irregularly.
fn cloud(n: usize) -> Vec<Point3<f32>> {
    (0..n as u64)
        .map(|i| {
            let r = |salt: u64| uniform(i * 7 + salt);
            match i % 3 {
                0 => Point3::new(40.0 * r(1), 30.0 * r(2), 0.0),
                1 => Point3::new(40.0 * r(3), 0.0, 3.0 * r(4)),
                _ => Point3::new(40.0 * r(5), 30.0 * r(6), 3.0 * r(7)),
            }
        })
        .collect()
}

/// Camera at `eye` looking along map `forward` (horizontal), image y down.
fn looking(eye: [f64; 3], yaw: f64) -> Isometry3<f64> {
    let forward = Vector3::new(yaw.cos(), yaw.sin(), 0.0);
    let right = forward.cross(&Vector3::z());
    let down = forward.cross(&right);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[right, down, forward]));
    Isometry3::from_parts(Translation3::new(eye[0], eye[1], eye[2]), UnitQuaternion::from_rotation_matrix(&r))
}

/// Whether `p` projects into the image, in front of the near plane and within range.
fn in_view(p: &Point3<f32>, pose: &Isometry3<f64>, k: &Intrinsics, range: f64) -> bool {
    let q = pose.inverse() * p.cast::<f64>();
    let Some(px) = k.project(&q) else { return false };
    q.z > 0.05
        && (q.coords.norm() <= range)
        && px.x >= 0.0
        && px.y >= 0.0
        && px.x < k.width as f64
        && px.y < k.height as f64
}

fn flatten(slices: &[PointSlice]) -> Vec<Point3<f32>> {
    slices.iter().flat_map(|s| (0..s.len()).map(|i| Point3::new(s.x[i], s.y[i], s.z[i]))).collect()
}

fn sorted(mut v: Vec<Point3<f32>>) -> Vec<[u32; 3]> {
    let mut keys: Vec<[u32; 3]> = v.drain(..).map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]).collect();
    keys.sort_unstable();
    keys
}

#[test]
fn culling_keeps_exactly_the_points_in_view_when_the_budget_allows() {
    let points = cloud(30_000);
    let index = MapIndex::build(points.clone(), &IndexSettings { voxel_m: 1.5, ..IndexSettings::default() });
    let k = intrinsics();
    for (eye, yaw, range) in
        [([5.0, 15.0, 1.5], 0.0, 12.0), ([20.0, 25.0, 2.0], -1.2, 30.0), ([38.0, 2.0, 1.0], 2.5, 8.0)]
    {
        let pose = looking(eye, yaw);
        let view = View { pose: &pose, intrinsics: &k, range_m: range, near_m: 0.05 };
        let culled = flatten(&index.visible(&view, usize::MAX));
        let exact: Vec<_> = points.iter().copied().filter(|p| in_view(p, &pose, &k, range)).collect();
        let culled_in_view: Vec<_> = culled.iter().copied().filter(|p| in_view(p, &pose, &k, range)).collect();
        assert!(!exact.is_empty());
        assert_eq!(sorted(culled_in_view), sorted(exact.clone()), "no point in view is culled");
        // The cull's whole point: far fewer candidates than the map.
        assert!(culled.len() < points.len() / 2, "{} of {}", culled.len(), points.len());
        // Everything the cull hands out lies near the view: within range plus a voxel.
        let reach = range + 1.5 * 3f64.sqrt();
        let eye = Point3::from(pose.translation.vector);
        assert!(culled.iter().all(|p| (p.cast::<f64>() - eye).norm() <= reach));
    }
}

#[test]
fn a_budget_thins_every_voxel_evenly() {
    let points = cloud(60_000);
    let index = MapIndex::build(points, &IndexSettings { voxel_m: 2.0, ..IndexSettings::default() });
    let k = intrinsics();
    let pose = looking([5.0, 15.0, 1.5], 0.0);
    let view = View { pose: &pose, intrinsics: &k, range_m: 40.0, near_m: 0.05 };
    let all = index.visible(&view, usize::MAX);
    let total: usize = all.iter().map(|s| s.len()).sum();
    let thinned = index.visible(&view, total / 4);
    assert_eq!(all.len(), thinned.len(), "every voxel keeps a share");
    let kept: usize = thinned.iter().map(|s| s.len()).sum();
    assert!(kept >= total / 4 && kept < total / 4 + thinned.len() + 1, "{kept} of {total}");
    // The kept part of a voxel is spread over it, not its first corner.
    let (big, big_thin) = all.iter().zip(&thinned).max_by_key(|(a, _)| a.len()).unwrap();
    let mean = |s: &PointSlice| s.x.iter().sum::<f32>() / s.len() as f32;
    assert!((mean(big) - mean(big_thin)).abs() < 0.3, "{} vs {}", mean(big), mean(big_thin));
}

#[test]
fn lazy_normals_equal_the_eager_ones_bit_for_bit() {
    let points = cloud(5_000);
    let room = MapIndex::new(points.clone());
    let eager = point_cloud_normals(&PointIndex::new(&points), &points, NORMAL_NEIGHBOURS);
    assert_eq!(room.eager_normals(), eager);
    assert_eq!(room.cached_normals(), points.len(), "a room's normals are all computed at load");
    assert!(!room.searches_per_voxel(), "one tree over every point: no voxel trees to build ahead");
    let queries: Vec<Point3<f64>> = points.iter().step_by(7).map(|p| p.cast::<f64>()).collect();
    let looked_up = room.nearest_normals(&queries);
    for (q, n) in queries.iter().zip(&looked_up) {
        let i = room.nearest(&q.cast()).unwrap();
        assert_eq!(n.unwrap(), eager[i]);
    }
    // A map too large to compute them all at load computes only what is asked for, the same
    // values, and serves them again from its cache.
    let building = lazy_building(points.clone());
    assert!(building.searches_per_voxel());
    assert_eq!(building.cached_normals(), 0);
    let lazy = building.nearest_normals(&queries);
    assert_eq!(lazy, looked_up);
    assert_eq!(building.cached_normals(), queries.len(), "only what was asked for is computed");
    assert_eq!(building.nearest_normals(&queries), lazy);
    assert!(MapIndex::new(Vec::new()).nearest_normals(&queries).iter().all(Option::is_none));
}

/// Indexed as a building whatever its size.
fn building(points: Vec<Point3<f32>>) -> MapIndex {
    MapIndex::build(points, &IndexSettings { building_above_points: 0, ..IndexSettings::default() })
}

/// A building searched by per-voxel trees, whose normals are computed when first asked for (as
/// a map too large for one tree), each a point's (no planar cells).
fn lazy_building(points: Vec<Point3<f32>>) -> MapIndex {
    let settings = IndexSettings {
        building_above_points: 0,
        one_tree_max_points: 0,
        cell_normals: false,
        ..IndexSettings::default()
    };
    MapIndex::build(points, &settings)
}

/// [`lazy_building`] with its normals from planar cells where they tell.
fn cellular_building(points: Vec<Point3<f32>>) -> MapIndex {
    let settings = IndexSettings { building_above_points: 0, one_tree_max_points: 0, ..IndexSettings::default() };
    MapIndex::build(points, &settings)
}

#[test]
fn the_per_voxel_search_finds_what_one_tree_over_the_map_finds() {
    let points = cloud(20_000);
    let whole = PointIndex::new(&points);
    // Small voxels (many of them, most neighbourhoods crossing faces) and large ones.
    for voxel_m in [0.7, 3.0] {
        let settings = IndexSettings { voxel_m, building_above_points: 0, one_tree_max_points: 0, cell_normals: false };
        let index = MapIndex::build(points.clone(), &settings);
        assert!(index.tree.is_none(), "a building builds no tree over every point");
        let on_map = points.iter().step_by(97).copied();
        let off_map = [Point3::new(20.0, 15.0, 1.5), Point3::new(-30.0, 90.0, 40.0), Point3::new(40.0, 30.0, 3.0)];
        for q in on_map.chain(off_map) {
            for k in [1, 2, NORMAL_NEIGHBOURS, 200] {
                assert_eq!(index.grid().nearest_k(&q, k), whole.nearest(&q, k), "{k} nearest to {q:?}");
            }
            for radius in [0.05, 0.5, 5.0] {
                assert_eq!(index.grid().nearest_within(&q, radius), whole.nearest_within(&q, radius), "{q:?} {radius}");
            }
        }
    }
    let index = building(points.clone());
    assert!(index.grid().nearest_k(&Point3::new(f32::NAN, 0.0, 0.0), 3).is_empty());
    assert_eq!(index.grid().nearest_k(&Point3::origin(), 50_000).len(), points.len(), "at most the map");
    assert!(building(Vec::new()).grid().nearest_k(&Point3::origin(), 3).is_empty());
}

#[test]
fn a_buildings_lazy_normals_are_the_rooms() {
    let points = cloud(5_000);
    let room = MapIndex::new(points.clone());
    let building = lazy_building(points.clone());
    assert_eq!(building.eager_normals(), room.eager_normals());
    let queries: Vec<Point3<f64>> = points.iter().step_by(11).map(|p| p.cast::<f64>()).collect();
    assert_eq!(building.nearest_normals(&queries), room.nearest_normals(&queries));
}

#[test]
fn on_a_building_normals_are_looked_up_near_the_surfaces_only() {
    let index = building(cloud(5_000));
    let on_floor = Point3::new(20.0, 15.0, 0.0);
    let floor_point = index.points()[index.nearest(&on_floor.cast()).unwrap()];
    let near = floor_point.cast::<f64>() + Vector3::new(0.0, 0.0, 0.1);
    let far_above = Point3::new(20.0, 15.0, 40.0);
    let normals = index.nearest_normals(&[near, far_above]);
    assert!(normals[0].is_some(), "a point 10 cm off the floor has its normal");
    assert!(normals[1].is_none(), "a point 37 m above everything has none");
}

#[test]
fn the_bounded_normal_search_scales_with_the_maps_point_spacing() {
    // The same wide cloud at 3× the size (points 3× further apart): a point 1.5 m off the floor
    // (0.5 m at the original size) still finds the floor's normal, and open space still none.
    let sparse: Vec<Point3<f32>> = cloud(5_000).iter().map(|p| Point3::from(p.coords * 3.0)).collect();
    let index = building(sparse);
    let on_floor = Point3::new(60.0, 45.0, 0.0);
    let floor_point = index.points()[index.nearest(&on_floor.cast()).unwrap()];
    let near = floor_point.cast::<f64>() + Vector3::new(0.0, 0.0, 1.5);
    let far_above = Point3::new(60.0, 45.0, 120.0);
    let normals = index.nearest_normals(&[near, far_above]);
    assert!(normals[0].is_some(), "a point 1.5 m off a sparse floor has its normal");
    assert!(normals[1].is_none(), "a point far above everything has none");
}

#[test]
fn the_background_build_hands_over_the_index() {
    let map = Arc::new(crate::frame::MapCloud { frame_id: "map".into(), points: cloud(2_000) });
    let mut background = swap::BackgroundIndex::default();
    assert!(background.ready().is_none() && background.wait().is_none());
    background.start(Arc::clone(&map), IndexSettings::default());
    assert!(background.is_pending());
    let done = background.wait().unwrap();
    assert_eq!(done.index.len(), 2_000);
    assert!(Arc::ptr_eq(&done.map, &map));
    assert!(!background.is_pending());
}

#[test]
fn the_voxel_of_a_coordinate_is_its_floor() {
    let values =
        [0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 2.999_999, -2.000_001, 1e7 + 0.5, -1e7 - 0.5, 3e9, -3e9, 1e30, -1e30];
    for t in
        values.into_iter().chain([f32::INFINITY, f32::NEG_INFINITY, f32::NAN, f32::MIN_POSITIVE, -f32::MIN_POSITIVE])
    {
        assert_eq!(voxels::floor_to_int(t), t.floor() as i64, "{t}");
    }
}

#[test]
fn a_buildings_voxel_trees_can_be_built_ahead_of_the_frames() {
    let index = lazy_building(cloud(20_000));
    assert_eq!(index.grid().built_trees(), 0, "loading builds none");
    index.nearest_normals(&[Point3::new(20.0, 15.0, 0.0)]);
    let after_a_search = index.grid().built_trees();
    assert!(after_a_search >= 1 && after_a_search < index.grid().voxel_count());
    assert_eq!(index.grid().build_trees_while(|| false), 0, "stops when no longer wanted");
    let rest = index.grid().build_trees_while(|| true);
    assert_eq!(rest + after_a_search, index.grid().voxel_count());
    assert_eq!(index.grid().built_trees(), index.grid().voxel_count());
}

/// What a replay does before its first frame: every tree at once, and the searches answer as
/// when the trees come on use.
#[test]
fn a_buildings_voxel_trees_can_all_be_built_at_load() {
    let (eager, lazy) = (lazy_building(cloud(20_000)), lazy_building(cloud(20_000)));
    eager.grid().build_all_trees();
    assert_eq!(eager.grid().built_trees(), eager.grid().voxel_count());
    let queries: Vec<Point3<f64>> = (0..50).map(|i| Point3::new(0.7 * i as f64, 15.0 - 0.3 * i as f64, 0.1)).collect();
    assert_eq!(eager.nearest_normals(&queries), lazy.nearest_normals(&queries));
    assert_eq!(eager.grid().build_trees_while(|| true), 0, "none left to build");
}

/// A floor and a wall meeting at x = 10 (a corner along the y axis), densely and randomly
/// sampled, as a building's surfaces are.
fn floor_and_wall(n: usize) -> Vec<Point3<f32>> {
    (0..n as u64)
        .map(|i| {
            let r = |salt: u64| uniform(i * 5 + salt);
            match i % 2 {
                0 => Point3::new(10.0 * r(1), 10.0 * r(2), 0.0),
                _ => Point3::new(10.0, 10.0 * r(3), 3.0 * r(4)),
            }
        })
        .collect()
}

#[test]
fn planar_cells_give_their_planes_normal_and_defer_at_edges() {
    let points = floor_and_wall(200_000);
    let (cells, exact) = (cellular_building(points.clone()), lazy_building(points));
    // On the floor, away from the wall: the floor's normal, as the points' own.
    let on_floor: Vec<Point3<f64>> =
        (0..40).map(|i| Point3::new(1.0 + 0.2 * i as f64, 2.0 + 0.13 * i as f64, 0.004)).collect();
    for (by_cell, by_point) in cells.nearest_normals(&on_floor).iter().zip(exact.nearest_normals(&on_floor)) {
        let (by_cell, by_point) = (by_cell.unwrap(), by_point.unwrap());
        assert!(by_cell.z.abs() > 0.999, "{by_cell:?}");
        assert!(by_cell.dot(&by_point).abs() > 0.99, "{by_cell:?} against {by_point:?}");
    }
    // Where floor and wall meet, the cell across the edge is not planar: the normal is that of a
    // planar cell next to it (the wall's or the floor's) or else a point's, exactly.
    let at_corner: Vec<Point3<f64>> = (0..40).map(|i| Point3::new(9.97, 0.5 + 0.23 * i as f64, 0.03)).collect();
    let by_points = exact.nearest_normals(&at_corner);
    let mut per_point = 0;
    for (by_cell, by_point) in cells.nearest_normals(&at_corner).iter().zip(&by_points) {
        let by_cell = by_cell.unwrap();
        if Some(by_cell) == *by_point {
            per_point += 1;
        } else {
            assert!(by_cell.x.abs() > 0.999 || by_cell.z.abs() > 0.999, "{by_cell:?}: neither plane's normal");
        }
    }
    assert!(per_point > 0, "some of the edge's normals are solved per point");
    assert!(cells.cached_normals() <= per_point, "only those solved per point");
}

/// The cells say "no point near" only where the search by points finds none within its reach.
#[test]
fn cells_find_nothing_only_where_no_point_is_near() {
    let points = floor_and_wall(100_000);
    let (cells, exact) = (cellular_building(points.clone()), lazy_building(points));
    let r = |i: u64, salt: u64| f64::from(uniform(i * 3 + salt));
    // Around the surfaces, from on them to well off them.
    let queries: Vec<Point3<f64>> =
        (0..3_000).map(|i| Point3::new(12.0 * r(i, 1) - 1.0, 10.0 * r(i, 2), 0.4 * r(i, 3) - 0.05)).collect();
    let (by_cells, by_points) = (cells.nearest_normals(&queries), exact.nearest_normals(&queries));
    let none = by_cells.iter().filter(|n| n.is_none()).count();
    assert!(none > 100 && none < queries.len() - 100, "both kinds of query: {none} without a normal");
    for ((q, by_cell), by_point) in queries.iter().zip(&by_cells).zip(&by_points) {
        if by_cell.is_none() {
            assert!(by_point.is_none(), "{q:?}: a point within reach, but the cells found none");
        }
    }
    let not_finite = [Point3::new(f64::NAN, 1.0, 0.0), Point3::new(1.0, f64::INFINITY, 0.0)];
    assert_eq!(cells.nearest_normals(&not_finite), vec![None, None]);
}
