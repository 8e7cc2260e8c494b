//! Pose verification against the dense depth prior: the map, rendered at a candidate pose, must
//! look like the prior up to one increasing affine map of depth (the prior is known only up to
//! scale and shift). Correspondences alone cannot tell the true pose from a wrong one that
//! explains a rigidly displaced patch of matches; the whole image's depth can, since a wrong pose
//! sees different geometry everywhere. Pure math, no I/O.

use std::sync::Arc;

use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

use crate::geometry::{fit_increasing_affine, AffineFitParams, DepthImage, DepthKind, Intrinsics, PriorSpace};
use crate::map_index::{CulledRender, IndexSettings, MapIndex, MapScale, PointSlice};
use crate::pnp::{Agreement, PoseVerifier, Verification};
use crate::rng::splitmix64_hash;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VerifyParams {
    /// Verify the best RANSAC hypotheses against the prior (needs a map and a depth prior).
    pub enabled: bool,
    /// Distinct hypotheses kept for verification (see `PnpParams::candidates`).
    pub candidates: usize,
    /// Hypotheses RANSAC draws at least when verifying, and between two verifications of its
    /// candidates while none agrees with the prior in `accept` of what the map covers in view
    /// (at least `min_view` of the image) …
    pub min_iterations: usize,
    /// … verified again every this many hypotheses …
    pub check_every: usize,
    pub accept: f64,
    pub min_view: f64,
    /// … and the choice changed in the last `settle_checks` verifications …
    pub settle_checks: usize,
    /// … up to this many hypotheses.
    pub max_iterations: usize,
    /// A frame whose best candidate agrees with the prior in less than this share of what it
    /// sees has an unreliable prior: the pose is chosen on geometry alone.
    pub min_trust: f64,
    /// Where plain RANSAC would stop, a best hypothesis the prior does not confirm (its
    /// agreement under `min_trust`) but whose geometry explains at least this share of the
    /// correspondences PnP sees is taken on geometry alone, without the verifier's further
    /// sampling: a realistic prior that never reaches `accept` does not cost every frame
    /// `min_iterations`. 0: off.
    pub settle_support: f64,
    /// Map points rendered, at most (an even subsample of the map, or of what is in view).
    pub max_map_points: usize,
    /// A map of more points than this many render budgets (`max_map_points`) is culled per
    /// candidate pose: only its points in the view frustum within `cull_range_m` are rendered,
    /// thinned to the budget ([`crate::map_index::MapScale`]); a smaller map renders an even
    /// subsample of all of it.
    pub cull_above_budgets: usize,
    /// How far from the camera a culled render takes map points, m.
    pub cull_range_m: f64,
    /// Side of the voxels the map is culled by, m.
    pub render_voxel_m: f64,
    /// Side of the render's image cells, pixels.
    pub cell_px: f64,
    /// Each rendered point covers a square this many of the rendered points' spacings wide (the
    /// median nearest-neighbour distance, measured on the map when it is set), so a near surface
    /// hides what lies behind it even where its points are farther apart than a cell; 0: each
    /// point fills one cell. Larger closes more gaps and blurs more edges.
    pub splat_spacings: f64,
    /// A cell agrees when |z − (a·prior + b)| < tolerance·z.
    pub tolerance: f64,
    /// Weight of the image coverage (cells of inliers over the best candidate's) beside the
    /// prior agreement in choosing among the candidates.
    pub coverage_weight: f64,
    /// Candidates covering fewer cells than this share of the best one's are left out of the
    /// choice and of the trust (see [`Verification::min_support_share`]).
    pub min_support_share: f64,
}

impl Default for VerifyParams {
    fn default() -> Self {
        Self {
            enabled: true,
            candidates: 12,
            min_iterations: 1000,
            check_every: 500,
            accept: 0.7,
            min_view: 0.25,
            settle_checks: 2,
            max_iterations: 10_000,
            min_trust: 0.7,
            settle_support: 0.3,
            max_map_points: 10_000,
            cull_above_budgets: 25,
            cull_range_m: 30.0,
            render_voxel_m: 2.0,
            cell_px: 32.0,
            splat_spacings: 0.75,
            tolerance: 0.1,
            coverage_weight: 1.0,
            min_support_share: 0.5,
        }
    }
}

impl VerifyParams {
    /// The map index's culling voxels and building threshold these parameters ask for: a map of
    /// more than `cull_above_budgets` render budgets (`max_map_points`) is a building.
    pub fn index_settings(&self) -> IndexSettings {
        IndexSettings {
            voxel_m: self.render_voxel_m as f32,
            building_above_points: self.max_map_points.saturating_mul(self.cull_above_budgets),
            ..IndexSettings::default()
        }
    }

    /// How PnP uses `verifier` under these parameters.
    pub fn verification<'a>(&self, verifier: &'a dyn PoseVerifier) -> Verification<'a> {
        Verification {
            verifier,
            candidates: self.candidates,
            coverage_weight: self.coverage_weight,
            min_support_share: self.min_support_share,
            min_iterations: self.min_iterations,
            check_every: self.check_every,
            accept: self.accept,
            min_view: self.min_view,
            settle_checks: self.settle_checks,
            max_iterations: self.max_iterations,
            min_trust: self.min_trust,
            settle_support: self.settle_support,
        }
    }
}

/// The map points a verifier renders: an even subsample of the map, fixed when the map is set,
/// or (a map larger than the render range) the points in view at each pose, culled from the
/// map's index.
#[derive(Clone, Debug, Default)]
pub struct RenderMap {
    /// Coordinates in separate arrays, so the projection vectorises.
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    /// The typical distance between neighbouring rendered points, metres (0: unknown).
    spacing_m: f32,
    culled: Option<CulledRender>,
}

impl RenderMap {
    /// The render map for `index` under `params`: on a room-scale map, an even subsample of the
    /// whole map (every point of it may be in view); on a building-scale one, the culled view of
    /// the index (the points in view at each candidate pose, at the budget's density).
    pub fn of_index(index: &Arc<MapIndex>, params: &VerifyParams) -> RenderMap {
        match index.scale() {
            MapScale::Room => RenderMap::new(index.points(), params.max_map_points),
            MapScale::Building => RenderMap::culled(CulledRender {
                index: Arc::clone(index),
                budget: params.max_map_points,
                range_m: params.cull_range_m,
            }),
        }
    }

    /// About `max_points` of the finite `points`, each kept with the same probability by a
    /// hash of its index (deterministic, and blind to the order the map was stored in).
    pub fn new(points: &[Point3<f32>], max_points: usize) -> Self {
        let keep = (max_points as f64 / points.len().max(1) as f64).min(1.0);
        let threshold = (keep * u32::MAX as f64) as u64;
        let kept = |i: usize| keep >= 1.0 || (splitmix64_hash(i as u64) >> 32) < threshold;
        let mut map = Self::default();
        for (_, p) in points.iter().enumerate().filter(|&(i, p)| kept(i) && p.iter().all(|v| v.is_finite())) {
            map.x.push(p.x);
            map.y.push(p.y);
            map.z.push(p.z);
        }
        map.spacing_m = map.point_spacing();
        map
    }

    /// The median distance from an even sample of the points to their nearest other point.
    fn point_spacing(&self) -> f32 {
        let points: Vec<Point3<f32>> =
            self.x.iter().zip(&self.y).zip(&self.z).map(|((&x, &y), &z)| Point3::new(x, y, z)).collect();
        let tree = crate::geometry::PointIndex::new(&points);
        crate::geometry::median_point_gap(points.len(), |i| {
            let p = points.get(i)?;
            points.get(*tree.nearest(p, 2).get(1)?).map(|q| (q - p).norm())
        })
    }

    /// Renders what `culled` finds in view at each pose.
    pub fn culled(culled: CulledRender) -> Self {
        Self { culled: Some(culled), ..Self::default() }
    }

    pub fn len(&self) -> usize {
        self.culled.as_ref().map_or(self.x.len(), |c| c.index.grid().len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The points to project at the camera-to-map `pose`.
    fn slices(&self, pose: &Isometry3<f64>, intrinsics: &Intrinsics) -> Vec<PointSlice<'_>> {
        match &self.culled {
            Some(c) => c.slices(pose, intrinsics, NEAR_M as f64),
            None => vec![PointSlice { x: &self.x, y: &self.y, z: &self.z }],
        }
    }
}

/// A splat covers at most this many cells on each side of its centre.
const MAX_SPLAT_CELLS: f32 = 8.0;

/// Map points nearer than this in front of the camera are not rendered, metres.
const NEAR_M: f32 = 0.05;

/// Render cells a verifier allocates at most (a 32 768-px-wide image in 32 px cells, squared).
const MAX_CELLS: usize = 1 << 20;

/// One frame's verifier: the prior sampled at the centres of the image cells, and the map.
pub struct PriorVerifier<'a> {
    map: &'a RenderMap,
    intrinsics: Intrinsics,
    cell_px: f64,
    cols: usize,
    rows: usize,
    /// Prior coordinate per cell (affine in `space`); NaN where unknown.
    prior: Vec<f32>,
    space: PriorSpace,
    tolerance: f32,
    /// Diameter of a rendered point's disc, metres (0: one cell).
    splat_m: f32,
}

impl<'a> PriorVerifier<'a> {
    /// `None` when there is nothing to verify with (empty map, invalid cell size or a prior that
    /// is unknown almost everywhere).
    pub fn new(
        map: &'a RenderMap,
        prior: &DepthImage,
        kind: DepthKind,
        intrinsics: &Intrinsics,
        params: &VerifyParams,
    ) -> Option<Self> {
        if map.is_empty() || !(params.cell_px.is_finite() && params.cell_px >= 1.0) || !intrinsics.is_valid() {
            return None;
        }
        let cols = (intrinsics.width as f64 / params.cell_px).ceil() as usize;
        let rows = (intrinsics.height as f64 / params.cell_px).ceil() as usize;
        if cols.saturating_mul(rows) > MAX_CELLS {
            // An image this large never reaches the core through the input limits; refuse it here
            // too rather than allocate for it.
            return None;
        }
        let mut known = 0;
        let mut cells = Vec::with_capacity(rows * cols);
        for r in 0..rows {
            for c in 0..cols {
                let centre = nalgebra::Point2::new(
                    ((c as f64 + 0.5) * params.cell_px).min(intrinsics.width as f64 - 1.0),
                    ((r as f64 + 0.5) * params.cell_px).min(intrinsics.height as f64 - 1.0),
                );
                let d = prior.sample(&centre, intrinsics.width, intrinsics.height).map(|v| kind.coordinate(v));
                match d {
                    Some(d) if d.is_finite() && d > 0.0 => {
                        known += 1;
                        cells.push(d as f32);
                    }
                    _ => cells.push(f32::NAN),
                }
            }
        }
        (known * 4 >= cells.len()).then_some(Self {
            map,
            intrinsics: *intrinsics,
            cell_px: params.cell_px,
            cols,
            rows,
            prior: cells,
            space: kind.space(),
            tolerance: params.tolerance as f32,
            splat_m: (params.splat_spacings.max(0.0) as f32) * map.spacing_m,
        })
    }

    /// The nearest map depth in each image cell at the camera-to-map `pose` (∞ where the map
    /// is not seen).
    pub fn render(&self, pose: &Isometry3<f64>) -> Vec<f32> {
        let to_cam = pose.inverse();
        let r = to_cam.rotation.to_rotation_matrix().into_inner().cast::<f32>();
        let t = to_cam.translation.vector.cast::<f32>();
        let k = &self.intrinsics;
        let inv_cell = 1.0 / self.cell_px as f32;
        let (fx, fy) = (k.fx as f32 * inv_cell, k.fy as f32 * inv_cell);
        let (cx, cy) = (k.cx as f32 * inv_cell, k.cy as f32 * inv_cell);
        let (w, h) = (k.width as f32 * inv_cell, k.height as f32 * inv_cell);
        let mut depth = vec![f32::INFINITY; self.rows * self.cols];
        let cols = self.cols as u32;
        let (r0, r1, r2) =
            ([r[(0, 0)], r[(0, 1)], r[(0, 2)]], [r[(1, 0)], r[(1, 1)], r[(1, 2)]], [r[(2, 0)], r[(2, 1)], r[(2, 2)]]);
        // In blocks: a branch-free pass that projects (vectorised), then the scatter.
        const BLOCK: usize = 256;
        let mut cell = [u32::MAX; BLOCK];
        let mut zs = [0f32; BLOCK];
        // Half the splat's width in cells is `splat / z`.
        let splat = 0.5 * fx * self.splat_m;
        let mut halves = [0f32; BLOCK];
        let mut uvs = [(0f32, 0f32); BLOCK];
        let slices = self.map.slices(pose, k);
        let blocks = slices.iter().flat_map(|m| (0..m.len()).step_by(BLOCK).map(move |start| (m, start)));
        for (map, start) in blocks {
            let end = (start + BLOCK).min(map.len());
            let (xs, ys, zm) = (&map.x[start..end], &map.y[start..end], &map.z[start..end]);
            let points = xs.iter().zip(ys).zip(zm);
            let out = cell.iter_mut().zip(zs.iter_mut()).zip(halves.iter_mut()).zip(uvs.iter_mut());
            for ((((c, z), half), uv), ((&px, &py), &pz)) in out.zip(points) {
                let x = r0[0] * px + r0[1] * py + r0[2] * pz + t.x;
                let y = r1[0] * px + r1[1] * py + r1[2] * pz + t.y;
                let cz = r2[0] * px + r2[1] * py + r2[2] * pz + t.z;
                let iz = 1.0 / cz;
                let (u, v) = (fx * x * iz + cx, fy * y * iz + cy);
                let visible = cz > NEAR_M && u >= 0.0 && v >= 0.0 && u < w && v < h;
                *c = if visible { v as u32 * cols + u as u32 } else { u32::MAX };
                *z = cz;
                *half = splat * iz;
                *uv = (u, v);
            }
            let n = xs.len();
            for (((&c, &z), &half), &(u, v)) in cell[..n].iter().zip(&zs[..n]).zip(&halves[..n]).zip(&uvs[..n]) {
                if half < 0.5 {
                    if let Some(d) = depth.get_mut(c as usize) {
                        if z < *d {
                            *d = z;
                        }
                    }
                } else if c != u32::MAX {
                    self.splat(&mut depth, u, v, half.min(MAX_SPLAT_CELLS), z);
                }
            }
        }
        depth
    }

    /// Writes depth `z` into the cells that the square of half-side `half` (cells) around
    /// `(u, v)` (cell units, inside the image) overlaps, where nothing nearer was seen.
    fn splat(&self, depth: &mut [f32], u: f32, v: f32, half: f32, z: f32) {
        let span = |centre: f32, len: usize| {
            let first = (centre - half).floor().max(0.0) as usize;
            let last = ((centre + half).floor().max(0.0) as usize).min(len.saturating_sub(1));
            first..=last
        };
        for r in span(v, self.rows) {
            for c in span(u, self.cols) {
                if let Some(d) = depth.get_mut(r * self.cols + c) {
                    if z < *d {
                        *d = z;
                    }
                }
            }
        }
    }

    /// The image cells in which the map rendered at `pose` agrees with the prior under the best
    /// increasing affine map in the prior's space (depth ≈ a·x + b, or 1/depth ≈ a·x + b for a
    /// disparity prior; robust fit: the map agreed on by the most cells among candidates through
    /// two cells each), and the cells where both are known.
    pub fn agreement(&self, pose: &Isometry3<f64>) -> Agreement {
        let depth = self.render(pose);
        let space = self.space;
        let pairs: Vec<(f32, f32)> = self
            .prior
            .iter()
            .zip(&depth)
            .filter(|(d, z)| d.is_finite() && z.is_finite())
            .map(|(&d, &z)| (d, space.of_depth(z as f64) as f32))
            .collect();
        Agreement { agreeing: best_affine_count(&pairs, self.tolerance), in_view: pairs.len(), cells: self.prior.len() }
    }
}

impl PoseVerifier for PriorVerifier<'_> {
    fn verify(&self, pose: &Isometry3<f64>) -> Agreement {
        self.agreement(pose)
    }
}

/// How the verifier fits the prior to the rendered depths: 64 candidate maps through two cells
/// each, spread over the cells, counted on every cell.
const CELL_FIT: AffineFitParams<f32> = AffineFitParams {
    candidates: 64,
    exhaustive_when_few: false,
    seed: 0x2545_F491_4F6C_DD1D,
    adaptive_after: None,
    max_counted: usize::MAX,
    min_gap_abs: 0.0,
    min_gap_rel: 1e-6,
};

/// The most (prior, depth) pairs that one increasing affine map `z ≈ a·d + b` puts within
/// `tolerance`·z ([`fit_increasing_affine`]).
fn best_affine_count(pairs: &[(f32, f32)], tolerance: f32) -> usize {
    fit_increasing_affine(pairs, tolerance, &CELL_FIT).map_or(0, |fit| fit.agreeing)
}

#[cfg(test)]
mod tests;
