//! Normals of a building-scale map by planar cells: each voxel of the grid is cut into cubic
//! cells at least as wide as a correspondence's search for its map point reaches, and a cell
//! whose points lie on a plane gives that plane's normal to the queries nearest to it. A frame's
//! correspondences then find their map normals by a few lookups each instead of a nearest-point
//! search and a k-nearest-neighbour PCA per new map point (about 1.7 ms a frame on a 2 M-point
//! building, whose queries are fresh points off the surfaces every frame). Where the cells cannot
//! tell (the nearest is an edge, a corner or a sparse patch) the query takes its nearest map
//! point's normal instead ([`super::LazyNormals`]).
//!
//! A cell's normal is the PCA of its points, as a point's is of its [`super::NORMAL_NEIGHBOURS`]
//! nearest: on a plane the two agree to within the noise, so the rejector sees the same
//! geometry; the cells are only a cheaper neighbourhood.

use std::collections::HashMap;
use std::sync::OnceLock;

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use super::voxels::{floor_to_int, pack, unpack, Voxel, VoxelGrid, GRID_OFFSET};

/// A cell's least side, in the map's point spacings: the reach of a correspondence's search for
/// its map point ([`super::NORMAL_SEARCH_SPACINGS`]), so the cells next to a query's own hold
/// every point it may find; on a surface of randomly spread points such a cell holds about as
/// many as a point's normal uses.
pub const CELL_SPACINGS: f32 = super::NORMAL_SEARCH_SPACINGS;

/// A cell with fewer points gives no normal.
const MIN_CELL_POINTS: u32 = 8;

/// A cell is planar when its smallest spread (eigenvalue of the covariance) is at most this share
/// of the middle one: a plane's thickness (the map's noise) against its extent.
const MAX_FLATNESS: f64 = 0.25;

/// Per voxel of the grid, the normals of its planar cells (built on first use).
#[derive(Debug, Default)]
pub struct CellNormals {
    /// Cells per voxel side.
    per_side: i64,
    voxels: Vec<OnceLock<Vec<Cell>>>,
}

/// An occupied cell: where its points are, and their plane's normal if they are enough and lie
/// on one.
#[derive(Clone, Copy, Debug)]
struct Cell {
    number: u32,
    centroid: Point3<f32>,
    normal: Option<Vector3<f32>>,
}

/// What the cells around a query say of its normal ([`CellNormals::normal_at`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CellAnswer {
    /// The plane's normal (unit, arbitrary sign).
    Normal(Vector3<f32>),
    /// No map point within the reach asked for.
    NoPointNear,
    /// The cells cannot tell: a point's normal is needed.
    Unknown,
}

/// Sums of a cell's points (relative to its voxel's first point, in f64).
#[derive(Clone, Copy, Default)]
struct Moments {
    count: u32,
    sum: Vector3<f64>,
    outer: Matrix3<f64>,
}

/// The voxels one query has looked up (at most the 8 its 27 neighbouring cells span).
#[derive(Default)]
struct VoxelCache<'a> {
    entries: [(u64, Option<&'a [Cell]>); 8],
    len: usize,
}

impl<'a> VoxelCache<'a> {
    /// The cells of the voxel `key`, by `lookup` the first time it is asked.
    fn get(&mut self, key: u64, lookup: impl FnOnce(u64) -> Option<&'a [Cell]>) -> Option<&'a [Cell]> {
        if let Some((_, cells)) = self.entries[..self.len].iter().find(|(k, _)| *k == key) {
            return *cells;
        }
        let cells = lookup(key);
        if let Some(slot) = self.entries.get_mut(self.len) {
            *slot = (key, cells);
            self.len += 1;
        }
        cells
    }
}

impl CellNormals {
    /// Cells of at least `CELL_SPACINGS · spacing` (a whole number of them, at most 1024, per
    /// voxel side); `None` for a spacing that gives no such cells.
    pub fn new(grid: &VoxelGrid, spacing: f32) -> Option<Self> {
        let side = CELL_SPACINGS * spacing;
        if !(side > 0.0 && side.is_finite()) {
            return None;
        }
        // Whole cells a voxel side, each at least `side` wide (a query's reach stays within the
        // cells next to its own); at most 1024 keeps a cell's number within 30 bits.
        let per_side = (grid.voxel_m / side).floor();
        if !(1.0..=1024.0).contains(&per_side) {
            return None;
        }
        Some(Self { per_side: per_side as i64, voxels: grid.voxels.iter().map(|_| OnceLock::new()).collect() })
    }

    /// The normal at `q` from the cells around it (its own and the 26 next to it, which hold
    /// every map point within `reach` of it: a cell is at least that wide). The cell whose
    /// points' centroid is nearest to `q` answers when it is planar and that centroid lies within
    /// `reach`; no map point in any of them means none within `reach`. Otherwise (an edge, a
    /// corner, a sparse patch) the cells cannot tell, and the caller takes a point's normal.
    pub fn normal_at(&self, grid: &VoxelGrid, q: &Point3<f32>, reach: f32) -> CellAnswer {
        if !q.iter().all(|v| v.is_finite()) {
            return CellAnswer::NoPointNear;
        }
        let centre = self.global_cell(grid, q);
        // Per axis, the voxel and the cell within it of the three neighbouring cells.
        let n = self.per_side;
        let axes: [[(i64, i64); 3]; 3] = std::array::from_fn(|a| {
            std::array::from_fn(|d| {
                ((centre[a] + d as i64 - 1).div_euclid(n), (centre[a] + d as i64 - 1).rem_euclid(n))
            })
        });
        // The 27 cells lie in at most 8 voxels, most often one: each is looked up once.
        let mut voxels = VoxelCache::default();
        let mut nearest: Option<(f32, &Cell)> = None;
        for &(vx, i) in &axes[0] {
            for &(vy, j) in &axes[1] {
                for &(vz, k) in &axes[2] {
                    let Some(cells) = voxels.get(pack(vx, vy, vz), |key| self.voxel_by_key(grid, key)) else {
                        continue;
                    };
                    let Some(number) = self.number([i, j, k]) else { continue };
                    let Some(cell) =
                        cells.binary_search_by_key(&number, |c| c.number).ok().and_then(|at| cells.get(at))
                    else {
                        continue;
                    };
                    let d2 = (cell.centroid - q).norm_squared();
                    if nearest.is_none_or(|(best, _)| d2 < best) {
                        nearest = Some((d2, cell));
                    }
                }
            }
        }
        match nearest {
            None => CellAnswer::NoPointNear,
            Some((d2, Cell { normal: Some(normal), .. })) if d2 <= reach * reach => CellAnswer::Normal(*normal),
            Some(_) => CellAnswer::Unknown,
        }
    }

    /// The occupied cells of the voxel with `key`, if the grid holds it.
    fn voxel_by_key(&self, grid: &VoxelGrid, key: u64) -> Option<&[Cell]> {
        let v = grid.keys.binary_search(&key).ok()?;
        self.voxel(grid, v).map(Vec::as_slice)
    }

    /// Every voxel's cells, in parallel (a replay, before its first frame).
    pub fn build_all(&self, grid: &VoxelGrid) {
        (0..self.voxels.len()).into_par_iter().for_each(|v| {
            self.voxel(grid, v);
        });
    }

    /// Solves the voxels' cells not solved yet, one voxel after another, for as long as
    /// `wanted` says (a node's indexing thread, beside its frames).
    pub fn build_while(&self, grid: &VoxelGrid, wanted: &dyn Fn() -> bool) {
        for v in 0..self.voxels.len() {
            if !wanted() {
                return;
            }
            self.voxel(grid, v);
        }
    }

    /// Voxel `v`'s occupied cells, by cell number.
    fn voxel(&self, grid: &VoxelGrid, v: usize) -> Option<&Vec<Cell>> {
        Some(self.voxels.get(v)?.get_or_init(|| self.solve_voxel(grid, v).unwrap_or_default()))
    }

    fn solve_voxel(&self, grid: &VoxelGrid, v: usize) -> Option<Vec<Cell>> {
        let Voxel { start, len } = *grid.voxels.get(v)?;
        let voxel_cell = unpack(*grid.keys.get(v)?);
        let (xs, ys, zs) =
            (grid.x.get(start..start + len)?, grid.y.get(start..start + len)?, grid.z.get(start..start + len)?);
        let origin = Vector3::new(*xs.first()? as f64, *ys.first()? as f64, *zs.first()? as f64);
        let mut cells: HashMap<u32, Moments> = HashMap::new();
        for ((&x, &y), &z) in xs.iter().zip(ys).zip(zs) {
            let p = Point3::new(x, y, z);
            let Some(cell) = self.cell_number(grid, &p, voxel_cell) else { continue };
            let d = Vector3::new(x as f64, y as f64, z as f64) - origin;
            let m = cells.entry(cell).or_default();
            m.count += 1;
            m.sum += d;
            m.outer += d * d.transpose();
        }
        let mut solved: Vec<Cell> = cells
            .into_iter()
            .map(|(number, m)| {
                let centroid = Point3::from(origin + m.sum / m.count as f64).cast();
                Cell { number, centroid, normal: plane_normal(&m) }
            })
            .collect();
        solved.sort_unstable_by_key(|c| c.number);
        Some(solved)
    }

    /// The global cell coordinates of `p` (cells counted from the grid's origin, as the voxels
    /// are: [`super::voxels::cell_of`] at a `per_side`-th of the voxel side).
    fn global_cell(&self, grid: &VoxelGrid, p: &Point3<f32>) -> [i64; 3] {
        let n = self.per_side as f32;
        let global = |v: f32| floor_to_int((v / grid.voxel_m + GRID_OFFSET) * n);
        [global(p.x), global(p.y), global(p.z)]
    }

    /// The number of the cell holding `p` within the voxel at `voxel_cell` (clamped into it,
    /// where rounding puts `p` on the far face).
    fn cell_number(&self, grid: &VoxelGrid, p: &Point3<f32>, voxel_cell: [i64; 3]) -> Option<u32> {
        let n = self.per_side;
        let g = self.global_cell(grid, p);
        self.number(std::array::from_fn(|axis| (g[axis] - voxel_cell[axis] * n).clamp(0, n - 1)))
    }

    /// The number of the cell at `local` coordinates (each in 0..per_side) within its voxel.
    fn number(&self, [i, j, k]: [i64; 3]) -> Option<u32> {
        let n = self.per_side;
        u32::try_from((i * n + j) * n + k).ok()
    }
}

/// The normal of a planar cell: the covariance's eigenvector of least spread, when that spread is
/// small against the next one; `None` for a sparse or non-planar cell.
fn plane_normal(m: &Moments) -> Option<Vector3<f32>> {
    if m.count < MIN_CELL_POINTS {
        return None;
    }
    let n = m.count as f64;
    let mean = m.sum / n;
    let cov = m.outer / n - mean * mean.transpose();
    let eig = SymmetricEigen::new(cov);
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let (least, middle) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]]);
    if !(middle > 0.0 && least <= MAX_FLATNESS * middle) {
        return None;
    }
    let normal: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned();
    normal.iter().all(|v| v.is_finite()).then(|| normal.normalize().cast())
}
