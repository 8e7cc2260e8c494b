//! The map, indexed once when it is set and queried per frame, so that what a frame costs
//! follows what it uses, not the size of the map:
//!
//! * a voxel grid with a k-d tree over its voxels ([`VoxelGrid`]), from which the verifier takes
//!   the points a candidate pose can see — within range, in the frustum, thinned evenly to its
//!   point budget ([`render_map`]);
//! * a search for the map points nearest to a point (the map point of a correspondence, and the
//!   neighbourhood of its normal), and the points' normals. On a map of up to
//!   [`ONE_TREE_MAX_POINTS`] it is one k-d tree over every point, built at load beside the grid,
//!   and every normal computed at load (a frame then only looks its points up); on a larger one
//!   it is the grid's per-voxel trees, each built when a search first reaches it
//!   ([`VoxelGrid::nearest_k`]), and a normal comes from the planar cell nearest to the query
//!   ([`CellNormals`], solved per voxel on first use) or, where the cells cannot tell (edges,
//!   corners), is computed for the nearest point when a frame first needs it and cached
//!   ([`LazyNormals`]), so loading a building's millions of points builds no tree over all of
//!   them and solves none of their normals. How far a correspondence looks for its normal
//!   follows the map's [`MapScale`], not how it is searched. A replay builds a building's trees
//!   and cells before its first frame ([`MapIndex::prepare_searches`]); a node, beside its
//!   first frames ([`swap`]).
//!
//! Built in parallel (the tree and the grid side by side, the grid's sort and gather, all on
//! rayon's pool), behind an `Arc`: one index serves every localizer (camera) that uses the map, and a
//! new map can be indexed on another thread while frames go on against the old one ([`swap`]).

mod cell_normals;
mod normals;
pub mod swap;
mod voxel_search;
mod voxels;

#[cfg(test)]
mod tests;

use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

use crate::geometry::{Intrinsics, PointIndex};

pub use cell_normals::{CellAnswer, CellNormals, CELL_SPACINGS};
pub use normals::{point_normal, LazyNormals, NearestPoints};
pub use voxels::{PointSlice, View, VoxelGrid};

/// Neighbours of a map point that define its normal (the learned rejector's n^P).
pub const NORMAL_NEIGHBOURS: usize = 16;

/// On a building-scale map ([`MapScale::Building`]), a correspondence takes the normal of the nearest map
/// point within this many of the map's point spacings, or none (in open space, off every
/// surface). Unbounded, the search for a point off the surfaces visits every map point around it:
/// its cost would grow with the map's density. In spacings, not metres, so a sparse map (points
/// 30 cm apart) searches as far, in points, as a dense one (2 cm).
pub const NORMAL_SEARCH_SPACINGS: f32 = 8.0;

/// A map of at most this many points gets one k-d tree over all of them and every normal
/// computed at load (a frame then only looks its points up); a larger one searches per-voxel
/// trees built on first use and computes a normal when a frame first needs it ([`LazyNormals`]:
/// at 5 M points all of them took ~38 s).
pub const ONE_TREE_MAX_POINTS: usize = 1_000_000;

/// How the map is bucketed for culling, and from what size it is treated as a building.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexSettings {
    /// Side of a culling voxel, metres.
    pub voxel_m: f32,
    /// A map of more points than this is [`MapScale::Building`].
    pub building_above_points: usize,
    /// A map of at most this many points gets one tree and its normals at load
    /// ([`ONE_TREE_MAX_POINTS`]).
    pub one_tree_max_points: usize,
    /// Whether a larger map's normals come from its planar cells where it has them
    /// ([`CellNormals`]; otherwise every one is a point's, solved on first use).
    pub cell_normals: bool,
}

/// How a map is rendered and how far its normals are looked for, from its size against the
/// render budget (how it is searched follows [`ONE_TREE_MAX_POINTS`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapScale {
    /// A map a render budget covers well (a room): normals looked up without bound,
    /// verification renders an even subsample of the whole map.
    Room,
    /// A map of many render budgets (a building): normals looked up within
    /// [`NORMAL_SEARCH_SPACINGS`] point spacings, verification renders the points in view at
    /// each candidate pose.
    Building,
}

impl Default for IndexSettings {
    /// What the default verification asks for (`VerifyParams::index_settings` in `verify`, which
    /// a test there checks against this: 2 m culling voxels, a building above 25 render budgets
    /// of 10 000 points).
    fn default() -> Self {
        Self {
            voxel_m: 2.0,
            building_above_points: 250_000,
            one_tree_max_points: ONE_TREE_MAX_POINTS,
            cell_normals: true,
        }
    }
}

/// The map points' normals (the learned rejector's n^P).
enum MapNormals {
    /// Every point's, computed at load (a map of at most [`ONE_TREE_MAX_POINTS`]), as its
    /// frames would otherwise solve most of theirs anew.
    Eager(Vec<Vector3<f32>>),
    /// Computed when a frame first needs them, and kept: a larger map.
    Lazy(LazyNormals),
}

/// The indexed map (see the module doc).
pub struct MapIndex {
    points: Vec<Point3<f32>>,
    /// One k-d tree over every point (a map of up to [`ONE_TREE_MAX_POINTS`]; a larger one
    /// searches the grid's per-voxel trees).
    tree: Option<PointIndex>,
    scale: MapScale,
    normals: MapNormals,
    grid: VoxelGrid,
    /// Diagonal of the finite points' bounding box, metres (0 for fewer than two points).
    extent_m: f64,
    /// How far a correspondence looks for its map point's normal (`None`: unbounded).
    normal_search_m: Option<f32>,
    /// A map searched per voxel: the normals of its planar cells.
    cells: Option<CellNormals>,
}

impl MapIndex {
    /// Indexes `points` with the default settings.
    pub fn new(points: Vec<Point3<f32>>) -> Self {
        Self::build(points, &IndexSettings::default())
    }

    /// Indexes `points`: a map of up to [`ONE_TREE_MAX_POINTS`] gets the point tree beside the
    /// voxel grid, then every normal; a larger one the grid alone (its trees come per voxel, and
    /// its normals, on use).
    pub fn build(points: Vec<Point3<f32>>, settings: &IndexSettings) -> Self {
        let scale = if points.len() > settings.building_above_points { MapScale::Building } else { MapScale::Room };
        // Side by side on rayon's pool, not on a thread of its own: a pool thread waiting on
        // another thread that needs the pool (the grid's parallel sort) would wait forever on
        // a one-thread pool (one CPU, or RAYON_NUM_THREADS=1).
        let ((tree, extent_m), grid) = rayon::join(
            || {
                let tree = (points.len() <= settings.one_tree_max_points).then(|| PointIndex::new(&points));
                (tree, bounding_diagonal(&points))
            },
            || VoxelGrid::new(&points, settings.voxel_m),
        );
        let spacing = (scale == MapScale::Building).then(|| point_spacing(&points, &grid));
        let normal_search_m = spacing.map(|s| NORMAL_SEARCH_SPACINGS * s);
        // Cells stand in for the normals a map searched per voxel would solve per point; they
        // answer within the building-scale search's reach.
        let cells =
            spacing.filter(|_| tree.is_none() && settings.cell_normals).and_then(|s| CellNormals::new(&grid, s));
        let normals = MapNormals::Lazy(LazyNormals::default());
        let mut index = Self { points, tree, scale, normals, grid, extent_m, normal_search_m, cells };
        if index.tree.is_some() {
            index.normals = MapNormals::Eager(index.eager_normals());
        }
        index
    }

    /// The map's points, in the order they were given.
    pub fn points(&self) -> &[Point3<f32>] {
        &self.points
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Whether searches go through the grid's per-voxel trees (built on first use, or ahead of
    /// the frames by [`VoxelGrid::build_trees_while`]): a map with no tree over every point.
    pub fn searches_per_voxel(&self) -> bool {
        self.tree.is_none()
    }

    /// How the map is indexed and rendered.
    pub fn scale(&self) -> MapScale {
        self.scale
    }

    /// Diagonal of the map's bounding box, metres.
    pub fn extent_m(&self) -> f64 {
        self.extent_m
    }

    pub fn grid(&self) -> &VoxelGrid {
        &self.grid
    }

    /// The index of the map point nearest to `query` (`None` for an empty map).
    pub fn nearest(&self, query: &Point3<f32>) -> Option<usize> {
        match &self.tree {
            Some(tree) => tree.nearest_one(query),
            None => self.grid.nearest_k(query, 1).first().copied(),
        }
    }

    /// The index of the map point nearest to `query` within `radius`, if any.
    fn nearest_within(&self, query: &Point3<f32>, radius: f32) -> Option<usize> {
        match &self.tree {
            Some(tree) => tree.nearest_within(query, radius),
            None => self.grid.nearest_within(query, radius),
        }
    }

    /// The search for the k nearest map points (the normals' neighbourhoods).
    fn search(&self) -> &dyn NearestPoints {
        match &self.tree {
            Some(tree) => tree,
            None => &self.grid,
        }
    }

    /// For each query, the normal (arbitrary sign, unit or zero when degenerate) of the planar
    /// cell nearest to it ([`CellNormals::normal_at`], a building searched per voxel) or else of
    /// the map point nearest to it (on a building-scale map, within [`NORMAL_SEARCH_SPACINGS`] point
    /// spacings); `None` for an empty map or nothing near. Computed on first use and cached.
    pub fn nearest_normals(&self, queries: &[Point3<f64>]) -> Vec<Option<Vector3<f32>>> {
        let (Some(cells), Some(reach)) = (&self.cells, self.normal_search_m) else {
            return self.point_normals(queries);
        };
        let from_cells: Vec<CellAnswer> =
            queries.par_iter().map(|q| cells.normal_at(&self.grid, &q.cast::<f32>(), reach)).collect();
        let unknown: Vec<Point3<f64>> =
            queries.iter().zip(&from_cells).filter(|(_, a)| **a == CellAnswer::Unknown).map(|(q, _)| *q).collect();
        let mut by_points = self.point_normals(&unknown).into_iter();
        from_cells
            .into_iter()
            .map(|answer| match answer {
                CellAnswer::Normal(normal) => Some(normal),
                CellAnswer::NoPointNear => None,
                CellAnswer::Unknown => by_points.next().flatten(),
            })
            .collect()
    }

    /// [`MapIndex::nearest_normals`] by the map points alone (no cells).
    fn point_normals(&self, queries: &[Point3<f64>]) -> Vec<Option<Vector3<f32>>> {
        let nearest_one = |q: &Point3<f64>| match self.normal_search_m {
            None => self.nearest(&q.cast::<f32>()),
            Some(radius) => self.nearest_within(&q.cast::<f32>(), radius),
        };
        // In parallel: on a building, the first searches near a place build its voxels' trees.
        let nearest: Vec<Option<usize>> = queries.par_iter().map(nearest_one).collect();
        let which: Vec<usize> = nearest.iter().flatten().copied().collect();
        let normals = match &self.normals {
            MapNormals::Eager(all) => {
                which.iter().map(|&i| all.get(i).copied().unwrap_or_else(Vector3::zeros)).collect()
            }
            MapNormals::Lazy(lazy) => lazy.get(self.search(), &self.points, NORMAL_NEIGHBOURS, &which),
        };
        let mut normals = normals.into_iter();
        nearest.iter().map(|n| n.and_then(|_| normals.next())).collect()
    }

    /// The normal of every point, computed now (in parallel): what a room keeps from load, and
    /// what a building's lazy normals stand in for.
    pub fn eager_normals(&self) -> Vec<Vector3<f32>> {
        let search = self.search();
        self.points
            .par_iter()
            .map_init(Vec::new, |neighbours, p| point_normal(search, &self.points, p, NORMAL_NEIGHBOURS, neighbours))
            .collect()
    }

    /// Builds now what a building-scale map's searches would build on first use (the per-voxel
    /// trees, the planar cells' normals), in parallel: for a caller that indexes a map before its
    /// first frame (a replay), so that no frame pays for them.
    pub fn prepare_searches(&self) {
        if self.searches_per_voxel() {
            self.grid.build_all_trees();
        }
        if let Some(cells) = &self.cells {
            cells.build_all(&self.grid);
        }
    }

    /// [`MapIndex::prepare_searches`] one voxel after another on the caller's thread, for as
    /// long as `wanted` says: what a node's indexing thread goes on with beside the frames.
    pub fn prepare_searches_while(&self, wanted: impl Fn() -> bool) {
        if self.searches_per_voxel() {
            self.grid.build_trees_while(&wanted);
        }
        if let Some(cells) = &self.cells {
            cells.build_while(&self.grid, &wanted);
        }
    }

    /// Normals computed so far (a room's: all of them, at load).
    pub fn cached_normals(&self) -> usize {
        match &self.normals {
            MapNormals::Eager(all) => all.len(),
            MapNormals::Lazy(lazy) => lazy.cached(),
        }
    }

    /// The points a camera at `view` may see, thinned evenly to about `budget` ([`VoxelGrid::visible`]).
    pub fn visible(&self, view: &View, budget: usize) -> Vec<PointSlice<'_>> {
        self.grid.visible(view, budget)
    }
}

impl std::fmt::Debug for MapIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MapIndex")
            .field("points", &self.points.len())
            .field("voxels", &self.grid.voxel_count())
            .field("extent_m", &self.extent_m)
            .finish()
    }
}

/// A render source that culls the map per candidate pose.
#[derive(Clone, Debug)]
pub struct CulledRender {
    pub index: Arc<MapIndex>,
    /// Points rendered at most per pose (about).
    pub budget: usize,
    pub range_m: f64,
}

impl CulledRender {
    /// The points to render at the camera-to-map `pose`.
    pub fn slices(&self, pose: &Isometry3<f64>, intrinsics: &Intrinsics, near_m: f64) -> Vec<PointSlice<'_>> {
        let view = View { pose, intrinsics, range_m: self.range_m, near_m };
        self.index.visible(&view, self.budget)
    }
}

/// The map's typical point spacing: the median distance from an even sample of its points to
/// their nearest other point in the same voxel (metres; 0 for fewer than two points).
fn point_spacing(points: &[Point3<f32>], grid: &VoxelGrid) -> f32 {
    crate::geometry::median_point_gap(points.len(), |i| grid.gap_in_voxel(i, points.get(i)?))
}

/// Diagonal of the bounding box of the finite points (0 when fewer than two).
fn bounding_diagonal(points: &[Point3<f32>]) -> f64 {
    let empty = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    let (lo, hi) = points
        .par_iter()
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .fold(
            || empty,
            |(mut lo, mut hi), p| {
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
                (lo, hi)
            },
        )
        .reduce(
            || empty,
            |(a_lo, a_hi), (b_lo, b_hi)| {
                let mut lo = a_lo;
                let mut hi = a_hi;
                for a in 0..3 {
                    lo[a] = lo[a].min(b_lo[a]);
                    hi[a] = hi[a].max(b_hi[a]);
                }
                (lo, hi)
            },
        );
    if lo[0] > hi[0] {
        return 0.0;
    }
    (0..3).map(|a| (hi[a] as f64 - lo[a] as f64).powi(2)).sum::<f64>().sqrt()
}

/// SplitMix64's finaliser: a well-mixed hash of an integer.
pub(crate) fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}
