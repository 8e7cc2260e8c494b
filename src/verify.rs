//! Pose verification against the dense depth prior: the map, rendered at a candidate pose, must
//! look like the prior up to one increasing affine map of depth (the prior is known only up to
//! scale and shift). Correspondences alone cannot tell the true pose from a wrong one that
//! explains a rigidly displaced patch of matches; the whole image's depth can, since a wrong pose
//! sees different geometry everywhere. Pure math, no I/O.

use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

use crate::geometry::{fit_increasing_affine, AffineFitParams, DepthImage, DepthKind, Intrinsics, PriorSpace};
use crate::map_index::{CulledRender, PointSlice};
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
            max_map_points: 10_000,
            cull_above_budgets: 25,
            cull_range_m: 30.0,
            render_voxel_m: 2.0,
            cell_px: 32.0,
            splat_spacings: 0.75,
            tolerance: 0.1,
            coverage_weight: 0.25,
        }
    }
}

impl VerifyParams {
    /// How PnP uses `verifier` under these parameters.
    pub fn verification<'a>(&self, verifier: &'a dyn PoseVerifier) -> Verification<'a> {
        Verification {
            verifier,
            candidates: self.candidates,
            coverage_weight: self.coverage_weight,
            min_iterations: self.min_iterations,
            check_every: self.check_every,
            accept: self.accept,
            min_view: self.min_view,
            settle_checks: self.settle_checks,
            max_iterations: self.max_iterations,
            min_trust: self.min_trust,
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
        let step = (points.len() / SPACING_SAMPLES).max(1);
        let mut gaps: Vec<f32> = points
            .iter()
            .step_by(step)
            .filter_map(|p| points.get(*tree.nearest(p, 2).get(1)?).map(|q| (q - p).norm()))
            .filter(|d| d.is_finite())
            .collect();
        if gaps.is_empty() {
            return 0.0;
        }
        let mid = gaps.len() / 2;
        *gaps.select_nth_unstable_by(mid, f32::total_cmp).1
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

/// Rendered points sampled to measure their spacing.
const SPACING_SAMPLES: usize = 1000;

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
mod tests {
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
        let data =
            v.render(truth).iter().map(|&z| if z.is_finite() { (z - shift) / scale } else { f32::NAN }).collect();
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
        let v = PriorVerifier::new(&map, &prior_at(&truth, 1.0, 0.0), DepthKind::Depth, &k, &VerifyParams::default())
            .unwrap();
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
}
