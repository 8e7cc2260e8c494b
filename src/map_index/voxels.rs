//! The map's points bucketed in cubic voxels, with a k-d tree over the voxel centres: the
//! verifier asks it for the points a candidate pose can see (voxels within range and inside
//! the view frustum), thinned evenly to a point budget, so the cost of a render follows what is
//! in view, not the size of the map.

use std::sync::OnceLock;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

use crate::geometry::Intrinsics;

/// A run of points (separate coordinate arrays, so the projection vectorises).
#[derive(Clone, Copy, Debug)]
pub struct PointSlice<'a> {
    pub x: &'a [f32],
    pub y: &'a [f32],
    pub z: &'a [f32],
}

impl PointSlice<'_> {
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// One occupied voxel: where its points sit in the grid's arrays.
#[derive(Clone, Copy, Debug)]
pub(super) struct Voxel {
    pub(super) start: usize,
    pub(super) len: usize,
}

/// What a camera can see: the pose, the image and how far it looks.
#[derive(Clone, Copy, Debug)]
pub struct View<'a> {
    /// Camera-to-map pose of the optical frame.
    pub pose: &'a Isometry3<f64>,
    pub intrinsics: &'a Intrinsics,
    /// Points farther than this from the camera are not rendered, metres.
    pub range_m: f64,
    /// Points nearer than this in front of the camera are not rendered, metres.
    pub near_m: f64,
}

/// Voxel-bucketed points; within a voxel, in an order fixed by a hash of each point's index in
/// the map, so any prefix of a voxel is an even subsample of it.
#[derive(Debug, Default)]
pub struct VoxelGrid {
    pub(super) voxel_m: f32,
    pub(super) voxels: Vec<Voxel>,
    /// Packed coordinates of each voxel, ascending (same order as `voxels`).
    pub(super) keys: Vec<u64>,
    /// Centre of each voxel, same order as `voxels` (the tree's items index it).
    centres: Vec<[f32; 3]>,
    tree: Option<ImmutableKdTree<f32, 3>>,
    pub(super) x: Vec<f32>,
    pub(super) y: Vec<f32>,
    pub(super) z: Vec<f32>,
    /// For each point of the grid, its index in the map.
    pub(super) map_index: Vec<u32>,
    /// Per voxel, a k-d tree over its points, built when a neighbour search first needs it
    /// ([`super::voxel_search`]).
    pub(super) trees: Vec<OnceLock<Option<ImmutableKdTree<f32, 3>>>>,
    /// Least and greatest voxel coordinates on each axis (empty grid: zeros).
    pub(super) cell_bounds: [[i64; 3]; 2],
}

/// The sort key of a non-finite point (above every packed key).
const NOT_A_VOXEL: u64 = u64::MAX;

/// Voxel coordinates are kept within ±2²⁰ (packed 21 bits an axis): at 1 m voxels, ±1000 km.
const KEY_LIMIT: i64 = 1 << 20;

pub(super) fn pack(ix: i64, iy: i64, iz: i64) -> u64 {
    let bits = |v: i64| (v.clamp(-KEY_LIMIT, KEY_LIMIT - 1) + KEY_LIMIT) as u64;
    (bits(ix) << 42) | (bits(iy) << 21) | bits(iz)
}

pub(super) fn unpack(key: u64) -> [i64; 3] {
    let field = |shift: u32| ((key >> shift) & ((1 << 21) - 1)) as i64 - KEY_LIMIT;
    [field(42), field(21), field(0)]
}

/// The packed coordinates of the voxel of side `voxel_m` holding `p`.
pub(super) fn key_of(p: &Point3<f32>, voxel_m: f32) -> u64 {
    let [ix, iy, iz] = cell_of(p, voxel_m);
    pack(ix, iy, iz)
}

/// How far, in voxels, the grid's faces sit off the world's whole coordinates (the golden
/// ratio's fraction, so that no multiple of a half or a quarter voxel falls within a tenth of one of a face). Maps
/// put floors at z = 0 and walls at round coordinates: on faces at whole multiples of the voxel,
/// every point of such a surface would have half its neighbours in the next voxel, and nearly
/// every neighbour search there would span two.
pub(super) const GRID_OFFSET: f32 = 0.381_966;

/// The integer coordinates of the voxel of side `voxel_m` holding `p`.
pub(super) fn cell_of(p: &Point3<f32>, voxel_m: f32) -> [i64; 3] {
    let cell = |v: f32| floor_to_int(v / voxel_m + GRID_OFFSET);
    [cell(p.x), cell(p.y), cell(p.z)]
}

/// `t.floor() as i64`, without the call to the C library's `floorf` that the baseline x86-64
/// target makes for `floor` (it showed in profiles of the grid's build at 5 M points): the cast
/// truncates towards zero (saturating), one less below zero where that truncated.
pub(super) fn floor_to_int(t: f32) -> i64 {
    let truncated = t as i64;
    if (truncated as f32) > t {
        truncated.saturating_sub(1)
    } else {
        truncated
    }
}

/// Least and greatest coordinates on each axis of the voxels `keys` (zeros when none).
fn cell_bounds(keys: &[u64]) -> [[i64; 3]; 2] {
    let mut cells = keys.iter().map(|&k| unpack(k));
    let Some(first) = cells.next() else { return [[0; 3]; 2] };
    cells.fold([first, first], |[mut lo, mut hi], c| {
        for a in 0..3 {
            lo[a] = lo[a].min(c[a]);
            hi[a] = hi[a].max(c[a]);
        }
        [lo, hi]
    })
}

impl VoxelGrid {
    /// Buckets the finite `points` into voxels of side `voxel_m` (sorted and gathered in
    /// parallel).
    pub fn new(points: &[Point3<f32>], voxel_m: f32) -> Self {
        let voxel_m = if voxel_m.is_finite() && voxel_m > 0.0 { voxel_m } else { 1.0 };
        // (voxel key, hash of the index in the high half | index in the low half): unique
        // keys, so the unstable sort is deterministic. A non-finite point gets a key no voxel
        // has (packed keys use 63 bits): sorted last, then cut off.
        let mut order: Vec<(u64, u64)> = Vec::new();
        points
            .par_iter()
            .enumerate()
            .map(|(i, p)| {
                let key = if p.iter().all(|v| v.is_finite()) { key_of(p, voxel_m) } else { NOT_A_VOXEL };
                (key, (super::splitmix(i as u64) & !0xFFFF_FFFF) | i as u64)
            })
            .collect_into_vec(&mut order);
        order.par_sort_unstable();
        let finite = order.partition_point(|&(key, _)| key != NOT_A_VOXEL);
        order.truncate(finite);
        let mut grid = Self { voxel_m, ..Self::default() };
        for (at, &(key, _)) in order.iter().enumerate() {
            if grid.keys.last() != Some(&key) {
                let [ix, iy, iz] = unpack(key);
                let centre = |c: i64| (c as f32 + 0.5 - GRID_OFFSET) * voxel_m;
                grid.keys.push(key);
                grid.voxels.push(Voxel { start: at, len: 0 });
                grid.centres.push([centre(ix), centre(iy), centre(iz)]);
            }
            if let Some(v) = grid.voxels.last_mut() {
                v.len += 1;
            }
        }
        // The map index is in the low half of the tag (the map holds fewer than 2³² points).
        grid.map_index = order.par_iter().map(|&(_, tagged)| tagged as u32).collect();
        drop(order);
        let gathered: Vec<Point3<f32>> = grid.map_index.par_iter().map(|&i| points[i as usize]).collect();
        grid.x = gathered.par_iter().map(|p| p.x).collect();
        grid.y = gathered.par_iter().map(|p| p.y).collect();
        grid.z = gathered.par_iter().map(|p| p.z).collect();
        grid.trees = grid.voxels.iter().map(|_| OnceLock::new()).collect();
        grid.cell_bounds = cell_bounds(&grid.keys);
        grid.tree = if grid.centres.is_empty() { None } else { ImmutableKdTree::new_from_slice(&grid.centres).ok() };
        grid
    }

    /// Points in the grid.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    pub fn voxel_count(&self) -> usize {
        self.voxels.len()
    }

    /// Every point, as one slice.
    pub fn all(&self) -> PointSlice<'_> {
        PointSlice { x: &self.x, y: &self.y, z: &self.z }
    }

    /// The points of the voxels `view` may see, each voxel thinned to the same share so that
    /// about `budget` points come back (all of them when fewer are in view). Conservative: a
    /// voxel is left out only when no point of it can be in the image within range.
    pub fn visible(&self, view: &View, budget: usize) -> Vec<PointSlice<'_>> {
        let in_view = self.voxels_in_view(view);
        let total: usize = in_view.iter().map(|&v| self.voxels[v].len).sum();
        let keep = if total <= budget { 1.0 } else { budget as f64 / total as f64 };
        in_view
            .into_iter()
            .map(|v| {
                let Voxel { start, len } = self.voxels[v];
                let take = ((len as f64 * keep).ceil() as usize).min(len);
                let end = start + take;
                PointSlice { x: &self.x[start..end], y: &self.y[start..end], z: &self.z[start..end] }
            })
            .collect()
    }

    /// Indices of the voxels whose bounding sphere reaches inside `view`'s range and frustum,
    /// in the grid's order (so the render does not depend on the tree's traversal).
    fn voxels_in_view(&self, view: &View) -> Vec<usize> {
        let Some(tree) = &self.tree else { return Vec::new() };
        let radius = self.voxel_m as f64 * 3f64.sqrt() / 2.0;
        let frustum = Frustum::new(view);
        let eye = view.pose.translation.vector;
        let reach = (view.range_m + radius) as f32;
        let found = tree
            .query(&[eye.x as f32, eye.y as f32, eye.z as f32])
            .within::<SquaredEuclidean<f32>>(reach * reach)
            .unsorted()
            .execute();
        let mut in_view: Vec<usize> = found
            .into_iter()
            .map(|n| n.item as usize)
            .filter(|&v| {
                let c = self.centres[v];
                frustum.reaches(&Point3::new(c[0] as f64, c[1] as f64, c[2] as f64), radius)
            })
            .collect();
        in_view.sort_unstable();
        in_view
    }
}

/// The view frustum as planes through the camera centre (and the near plane), in the map frame.
struct Frustum {
    /// Unit inward normals and offsets: a point p is inside when n·p + d ≥ 0 for all.
    planes: [(Vector3<f64>, f64); 5],
}

impl Frustum {
    fn new(view: &View) -> Self {
        let k = view.intrinsics;
        let (w, h) = (k.width as f64, k.height as f64);
        // Camera-frame inward normals of u ≥ 0, u ≤ w, v ≥ 0, v ≤ h (u = fx·x/z + cx) and z ≥ near.
        let camera = [
            Vector3::new(k.fx, 0.0, k.cx),
            Vector3::new(-k.fx, 0.0, w - k.cx),
            Vector3::new(0.0, k.fy, k.cy),
            Vector3::new(0.0, -k.fy, h - k.cy),
        ];
        let rotation = view.pose.rotation;
        let eye = view.pose.translation.vector;
        let through_eye = |n: Vector3<f64>| {
            let n = rotation * n.normalize();
            (n, -n.dot(&eye))
        };
        let forward = rotation * Vector3::z();
        Self {
            planes: [
                through_eye(camera[0]),
                through_eye(camera[1]),
                through_eye(camera[2]),
                through_eye(camera[3]),
                (forward, -forward.dot(&eye) - view.near_m),
            ],
        }
    }

    /// Whether a sphere may have a point inside (true for every sphere that does).
    fn reaches(&self, centre: &Point3<f64>, radius: f64) -> bool {
        self.planes.iter().all(|(n, d)| n.dot(&centre.coords) + d >= -radius)
    }
}
