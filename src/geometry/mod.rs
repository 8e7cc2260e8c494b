//! Camera geometry: intrinsics, depth images, back-projection with a depth prior (eq. 2),
//! surface normals and nearest neighbours. Pure math, no I/O.

pub mod affine_fit;
pub mod align;
mod frame_geometry;
pub mod normals;
mod scale_votes;

pub use affine_fit::{fit_increasing_affine, AffineFit, AffineFitParams, AffineMap};
pub use frame_geometry::{FrameGeometry, FrameParts, GeometryScratch};
pub use normals::{pca_normal, point_cloud_normals, prior_normals};

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, Point2, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// Pinhole intrinsics of a camera image (`CameraInfo.k`), distortion-free.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

/// The widest and the narrowest field of view a pinhole camera model is taken to have: a
/// pinhole images less than 180° (a wider lens needs a fisheye model), and no lens sees less
/// than a hundredth of a degree. A focal length outside them (fx = 10⁻³⁰ from a broken driver,
/// #38) is refused where it comes in rather than failing every frame later.
const MAX_FIELD_OF_VIEW_DEG: f64 = 179.0;
const MIN_FIELD_OF_VIEW_DEG: f64 = 0.01;

/// Whether `focal_px` over an image side of `side_px` pixels gives a field of view a pinhole can
/// have ([`MAX_FIELD_OF_VIEW_DEG`], [`MIN_FIELD_OF_VIEW_DEG`]).
fn plausible_focal(focal_px: f64, side_px: u32) -> bool {
    let half_side = side_px as f64 / 2.0;
    let fov_deg = 2.0 * (half_side / focal_px).atan().to_degrees();
    focal_px > 0.0 && (MIN_FIELD_OF_VIEW_DEG..=MAX_FIELD_OF_VIEW_DEG).contains(&fov_deg)
}

/// Smallest camera depth that counts as in front of the camera: one visibility rule for PnP's
/// scoring and refinement and for every projection through [`Intrinsics::project`] (the last
/// choice's and the significance's support), so they agree on which matches a pose explains.
pub const MIN_DEPTH: f64 = 1e-9;

impl Intrinsics {
    /// The 3×3 camera matrix K.
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Projects a point in the camera frame to a pixel; `None` behind the camera (depth not
    /// above [`MIN_DEPTH`]).
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        (p.z > MIN_DEPTH).then(|| Point2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// Distance in pixels between `pixel` and the projection of the camera-frame point `p`;
    /// infinite behind the camera.
    pub fn reprojection_error(&self, p: &Point3<f64>, pixel: &Point2<f64>) -> f64 {
        self.project(p).map_or(f64::INFINITY, |px| (px - pixel).norm())
    }

    /// π⁻¹(p, d, K): the camera-frame point at depth `depth` along pixel `pixel`'s ray.
    pub fn back_project(&self, pixel: &Point2<f64>, depth: f64) -> Point3<f64> {
        Point3::new((pixel.x - self.cx) / self.fx * depth, (pixel.y - self.cy) / self.fy * depth, depth)
    }

    /// The unit bearing of a pixel's ray.
    pub fn bearing(&self, pixel: &Point2<f64>) -> Vector3<f64> {
        Vector3::new((pixel.x - self.cx) / self.fx, (pixel.y - self.cy) / self.fy, 1.0).normalize()
    }

    /// Whether all parameters are finite and usable.
    pub fn is_valid(&self) -> bool {
        [self.fx, self.fy, self.cx, self.cy].iter().all(|v| v.is_finite())
            && self.width > 0
            && self.height > 0
            && plausible_focal(self.fx, self.width)
            && plausible_focal(self.fy, self.height)
    }
}

/// What the values of a depth prior mean. Every kind is known only up to an unknown affine map
/// in its own space ([`PriorSpace`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthKind {
    /// Values grow with distance: depth ≈ a·value + b (metric-like networks: Depth Anything
    /// metric, ZoeDepth, Metric3D, a depth sensor).
    #[default]
    Depth,
    /// 1/value is depth up to scale and shift: depth ≈ a/value + b (a network that outputs
    /// metric inverse depth, known up to scale).
    InverseDepth,
    /// Affine-invariant disparity: 1/depth ≈ a·value + b, the shift b unknown and possibly large
    /// (MiDaS, DPT, Depth Anything relative). Aligned and verified in inverse-depth space.
    #[serde(alias = "affine_disparity")]
    Disparity,
}

/// The space in which a prior is affine: depth itself, or inverse depth (disparity).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PriorSpace {
    #[default]
    Depth,
    Disparity,
}

impl DepthKind {
    /// The prior coordinate x that is affine in this kind's [`PriorSpace`]: the value itself,
    /// or its inverse for [`DepthKind::InverseDepth`].
    pub fn coordinate(self, value: f64) -> f64 {
        match self {
            DepthKind::Depth | DepthKind::Disparity => value,
            DepthKind::InverseDepth => 1.0 / value,
        }
    }

    pub fn space(self) -> PriorSpace {
        match self {
            DepthKind::Depth | DepthKind::InverseDepth => PriorSpace::Depth,
            DepthKind::Disparity => PriorSpace::Disparity,
        }
    }

    /// A depth that grows with the true one, before any alignment (identity scale, no shift).
    pub fn unaligned_depth(self, value: f64) -> f64 {
        let x = self.coordinate(value);
        match self.space() {
            PriorSpace::Depth => x,
            PriorSpace::Disparity => 1.0 / x,
        }
    }
}

impl PriorSpace {
    /// What a depth `z` is in this space (the quantity the prior coordinate is affine in).
    pub fn of_depth(self, z: f64) -> f64 {
        match self {
            PriorSpace::Depth => z,
            PriorSpace::Disparity => 1.0 / z,
        }
    }
}

/// A single-channel depth image, row-major; non-finite or non-positive values are unknown.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl DepthImage {
    pub fn new(width: u32, height: u32, data: Vec<f32>) -> Self {
        debug_assert_eq!(data.len(), width as usize * height as usize);
        Self { width, height, data }
    }

    /// The value at integer pixel (u, v), if inside and known.
    pub fn at(&self, u: i64, v: i64) -> Option<f32> {
        if u < 0 || v < 0 || u >= self.width as i64 || v >= self.height as i64 {
            return None;
        }
        let d = self.data[v as usize * self.width as usize + u as usize];
        (d.is_finite() && d > 0.0).then_some(d)
    }

    /// Value at a pixel of a camera image of size `camera_width`×`camera_height`, rescaled to
    /// this image's resolution and interpolated bilinearly over the known neighbours.
    pub fn sample(&self, pixel: &Point2<f64>, camera_width: u32, camera_height: u32) -> Option<f64> {
        let sx = self.width as f64 / camera_width as f64;
        let sy = self.height as f64 / camera_height as f64;
        // Pixel centres map to pixel centres across resolutions.
        let x = (pixel.x + 0.5) * sx - 0.5;
        let y = (pixel.y + 0.5) * sy - 0.5;
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
        let (x0, y0) = (x.floor() as i64, y.floor() as i64);
        let (ax, ay) = (x - x0 as f64, y - y0 as f64);
        let mut sum = 0.0;
        let mut weight = 0.0;
        for (du, dv, w) in
            [(0, 0, (1.0 - ax) * (1.0 - ay)), (1, 0, ax * (1.0 - ay)), (0, 1, (1.0 - ax) * ay), (1, 1, ax * ay)]
        {
            if let Some(d) = self.at(x0 + du, y0 + dv) {
                sum += w * d as f64;
                weight += w;
            }
        }
        (weight > 1e-9).then(|| sum / weight)
    }
}

/// Eq. (2): back-projects each pixel with the prior's depth, `o_i = π⁻¹(p_i, d_i, K)`.
/// Returns `None` for a pixel where the prior is unknown.
pub fn back_project_with_prior(
    intrinsics: &Intrinsics,
    prior: &DepthImage,
    kind: DepthKind,
    pixels: impl IntoIterator<Item = Point2<f64>>,
) -> Vec<Option<Point3<f64>>> {
    pixels
        .into_iter()
        .map(|p| {
            let value = prior.sample(&p, intrinsics.width, intrinsics.height)?;
            let depth = kind.unaligned_depth(value);
            (depth.is_finite() && depth > 0.0).then(|| intrinsics.back_project(&p, depth))
        })
        .collect()
}

/// Centroid of a point set (eq. 5); the origin for an empty set.
pub fn centroid(points: &[Point3<f64>]) -> Point3<f64> {
    if points.is_empty() {
        return Point3::origin();
    }
    let sum = points.iter().fold(Vector3::zeros(), |acc, p| acc + p.coords);
    Point3::from(sum / points.len() as f64)
}

/// Points sampled (evenly) to measure a cloud's point spacing.
const SPACING_SAMPLES: usize = 1000;

/// A cloud's typical point spacing: the median, over an even sample of its `len` points, of
/// `gap(i)` — the distance from point `i` to its nearest other point (`None`: no neighbour).
/// 0 when no sampled point has one.
pub fn median_point_gap(len: usize, gap: impl Fn(usize) -> Option<f32> + Sync) -> f32 {
    use rayon::prelude::*;
    let step = (len / SPACING_SAMPLES).max(1);
    let samples: Vec<usize> = (0..len).step_by(step).collect();
    let mut gaps: Vec<f32> = samples.par_iter().filter_map(|&i| gap(i)).filter(|d| d.is_finite()).collect();
    if gaps.is_empty() {
        return 0.0;
    }
    let mid = gaps.len() / 2;
    *gaps.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// A k-d tree over 3D points for k-nearest-neighbour queries.
pub struct PointIndex {
    tree: Option<ImmutableKdTree<f32, 3>>,
    len: usize,
}

impl PointIndex {
    pub fn new(points: &[Point3<f32>]) -> Self {
        let entries: Vec<[f32; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        // An empty set gets no tree and answers no neighbours.
        let tree = if entries.is_empty() { None } else { ImmutableKdTree::new_from_slice(&entries).ok() };
        Self { tree, len: points.len() }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The index of the point nearest to `query` (`None` when empty).
    pub fn nearest_one(&self, query: &Point3<f32>) -> Option<usize> {
        let tree = self.tree.as_ref()?;
        Some(tree.query(&[query.x, query.y, query.z]).nearest_one::<SquaredEuclidean<f32>>().execute().item as usize)
    }

    /// The index of the point nearest to `query` if one lies within `radius` (its cost follows
    /// the points within `radius`, not the map's density farther out).
    pub fn nearest_within(&self, query: &Point3<f32>, radius: f32) -> Option<usize> {
        let tree = self.tree.as_ref()?;
        let one = std::num::NonZero::new(1)?;
        let found = tree
            .query(&[query.x, query.y, query.z])
            .nearest_n::<SquaredEuclidean<f32>>(one)
            .within(radius * radius)
            .execute();
        found.first().map(|n| n.item as usize)
    }

    /// Indices of the `k` nearest points to `query`, nearest first.
    pub fn nearest(&self, query: &Point3<f32>, k: usize) -> Vec<usize> {
        let k = k.min(self.len);
        let (Some(k), Some(tree)) = (std::num::NonZero::new(k), &self.tree) else { return Vec::new() };
        tree.query(&[query.x, query.y, query.z])
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .execute()
            .into_iter()
            .map(|n| n.item as usize)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn k() -> Intrinsics {
        Intrinsics { fx: 525.0, fy: 525.0, cx: 320.0, cy: 240.0, width: 640, height: 480 }
    }

    /// Intrinsics a pinhole can have are valid; a focal length that makes the view 180° wide or
    /// wider (fx = 10⁻³⁰ from a broken driver, #38) or a hair's breadth narrow is not.
    #[test]
    fn intrinsics_need_a_pinholes_field_of_view() {
        assert!(k().is_valid());
        let wide = Intrinsics { fx: 250.0, fy: 190.0, ..k() };
        assert!(wide.is_valid(), "a 104° wide-angle");
        let tele = Intrinsics { fx: 60_000.0, fy: 60_000.0, ..k() };
        assert!(tele.is_valid(), "a 0.6° telephoto");
        for fx in [1e-30, 0.0, -525.0, 1.0, 1e9, f64::NAN] {
            assert!(!Intrinsics { fx, ..k() }.is_valid(), "fx {fx}");
            assert!(!Intrinsics { fy: fx, ..k() }.is_valid(), "fy {fx}");
        }
        assert!(!Intrinsics { width: 0, ..k() }.is_valid());
    }

    #[test]
    fn project_inverts_back_project() {
        let px = Point2::new(100.25, 333.5);
        let p = k().back_project(&px, 2.5);
        let q = k().project(&p).unwrap();
        assert!((q - px).norm() < 1e-9);
        assert!((p.z - 2.5).abs() < 1e-12);
    }

    #[test]
    fn half_resolution_prior_samples_constant_and_ramp() {
        // Prior at half resolution whose value is its own column index.
        let (w, h) = (320u32, 240u32);
        let data = (0..h).flat_map(|_| (0..w).map(|u| u as f32 + 1.0)).collect();
        let prior = DepthImage::new(w, h, data);
        // Camera pixel 201 (centre 201.5) → prior x = 201.5/2 - 0.5 = 100.25 → value 101.25.
        let d = prior.sample(&Point2::new(201.0, 100.0), 640, 480).unwrap();
        assert!((d - 101.25).abs() < 1e-9, "{d}");
    }

    #[test]
    fn unknown_prior_pixels_are_skipped() {
        let prior = DepthImage::new(2, 1, vec![f32::NAN, 0.0]);
        assert!(prior.sample(&Point2::new(0.0, 0.0), 2, 1).is_none());
    }

    #[test]
    fn pca_normal_of_plane() {
        let pts: Vec<_> = (0..5).flat_map(|i| (0..5).map(move |j| Point3::new(i as f64, j as f64, 3.0))).collect();
        let n = pca_normal(&pts, &Point3::origin()).unwrap();
        assert!((n - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-9);
    }

    #[test]
    fn knn_finds_nearest_first() {
        let pts: Vec<_> = (0..100).map(|i| Point3::new(i as f32, 0.0, 0.0)).collect();
        let idx = PointIndex::new(&pts);
        assert_eq!(idx.nearest(&Point3::new(41.2, 0.0, 0.0), 3), vec![41, 42, 40]);
        assert_eq!(idx.nearest_one(&Point3::new(41.7, 0.0, 0.0)), Some(42));
        assert_eq!(PointIndex::new(&[]).nearest_one(&Point3::origin()), None);
    }

    #[test]
    fn prior_normals_of_fronto_parallel_wall_face_camera() {
        let prior = DepthImage::new(64, 48, vec![2.0; 64 * 48]);
        let intr = Intrinsics { fx: 50.0, fy: 50.0, cx: 32.0, cy: 24.0, width: 64, height: 48 };
        let n = prior_normals(&intr, &prior, DepthKind::Depth, &[Point2::new(30.0, 20.0)], |d| d);
        assert!((n[0] - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-9, "{:?}", n[0]);
    }
}
