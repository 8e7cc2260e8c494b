//! Pairwise spatial consistency between the image cloud (pixels back-projected with the depth
//! prior) and the map cloud, and the alignment of the prior's unknown scale and shift.
//!
//! * [`angle_consistency`]: the paper's scale-invariant measure, eq. (5)–(7).
//! * [`distance_consistency`]: the classic length-preserving measure (the paper's ablation), on an
//!   image cloud aligned with [`estimate_scale_shift`].
//! * [`estimate_scale`]: eq. (8); [`estimate_scale_shift`] (in [`crate::align`]): scale *and*
//!   shift of the prior, which the paper lists as a limitation.
//!
//! Matrices are dense, row-major `n × n` `f32` with a zero diagonal, written into caller-owned
//! buffers so a localizer can reuse them across frames.

pub use crate::align::{estimate_scale_shift, ScaleShift, ScaleShiftParams};
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

/// Which pairwise consistency a rejector or a graph measures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PairMetric {
    /// The paper's angle consistency, eq. (5)–(7), on clouds centred on their centroids.
    #[default]
    Angle,
    /// Length consistency of the scale-and-shift-aligned (metric) image cloud, the paper's
    /// distance ablation.
    Distance,
}

/// A dense symmetric consistency matrix Θ (row-major, zero diagonal).
#[derive(Clone, Debug, Default)]
pub struct ConsistencyMatrix {
    pub n: usize,
    pub values: Vec<f32>,
}

impl ConsistencyMatrix {
    /// Resizes to `n × n`, reusing the allocation. The builders overwrite every entry, so a
    /// matrix of the same size is not cleared first (that would be one more pass over n² values).
    fn reset(&mut self, n: usize) {
        self.n = n;
        self.values.resize(n * n, 0.0);
    }

    pub fn row(&self, i: usize) -> &[f32] {
        &self.values[i * self.n..(i + 1) * self.n]
    }

    pub fn get(&self, i: usize, j: usize) -> f32 {
        self.values[i * self.n + j]
    }
}

/// Eq. (5)–(7): angle-based spatial consistency.
///
/// Both clouds are centred on their (optionally `weights`-weighted) centroids, eq. (5); for each
/// pair the cosines of the angle between centred vectors are compared, eq. (6),
/// δ_ij = ||cos α^I_ij| − |cos α^P_ij||, and θ_ij = [1 − δ²_ij / σ²_d]₊, eq. (7).
/// θ is invariant to scaling the image cloud (the monocular prior's unknown scale).
pub fn angle_consistency(
    image: &[Point3<f64>],
    map: &[Point3<f64>],
    weights: Option<&[f64]>,
    sigma_d: f64,
    out: &mut ConsistencyMatrix,
) {
    let n = image.len().min(map.len());
    out.reset(n);
    let unit_i = centred_unit_vectors(&image[..n], weights);
    let unit_p = centred_unit_vectors(&map[..n], weights);
    let inv_sigma2 = (1.0 / (sigma_d * sigma_d)) as f32;
    for i in 0..n {
        let (oi, pi) = (unit_i[i], unit_p[i]);
        out.values[i * n + i] = 0.0;
        for j in (i + 1)..n {
            let theta = angle_theta(&oi, &pi, &unit_i[j], &unit_p[j], inv_sigma2);
            out.values[i * n + j] = theta;
            out.values[j * n + i] = theta;
        }
    }
}

/// Eq. (6)–(7) for one pair of centred unit vectors: δ = ||cos α^I| − |cos α^P||, θ = [1 − δ²/σ²_d]₊.
#[inline(always)]
fn angle_theta(oi: &Vector3<f32>, pi: &Vector3<f32>, oj: &Vector3<f32>, pj: &Vector3<f32>, inv_sigma2: f32) -> f32 {
    let delta = oi.dot(oj).abs() - pi.dot(pj).abs();
    (1.0 - delta * delta * inv_sigma2).max(0.0)
}

/// Unit vectors from the (weighted) centroid, eq. (5); a point at the centroid gets zero.
fn centred_unit_vectors(points: &[Point3<f64>], weights: Option<&[f64]>) -> Vec<Vector3<f32>> {
    let c = weighted_centroid(points, weights);
    points.iter().map(|p| unit_from(p, &c)).collect()
}

/// The unit vector from `centre` to `p` (zero at the centre).
fn unit_from(p: &Point3<f64>, centre: &Point3<f64>) -> Vector3<f32> {
    let v = p - centre;
    let norm = v.norm();
    if norm > 1e-12 {
        (v / norm).cast::<f32>()
    } else {
        Vector3::zeros()
    }
}

fn weighted_centroid(points: &[Point3<f64>], weights: Option<&[f64]>) -> Point3<f64> {
    let mut sum = Vector3::zeros();
    let mut total = 0.0;
    for (k, p) in points.iter().enumerate() {
        let w = weights.map_or(1.0, |w| w[k]);
        sum += p.coords * w;
        total += w;
    }
    if total > 0.0 {
        Point3::from(sum / total)
    } else {
        Point3::origin()
    }
}

/// Distance-based spatial consistency: θ_ij = [1 − (|‖o_i − o_j‖ − ‖q_i − q_j‖| / σ_ij)²]₊
/// with σ_ij = `sigma_abs` + `sigma_rel`·‖q_i − q_j‖ (a monocular prior's error grows with
/// distance). Needs an image cloud in metres, see [`estimate_scale_shift`].
pub fn distance_consistency(
    image: &[Point3<f64>],
    map: &[Point3<f64>],
    sigma_abs: f64,
    sigma_rel: f64,
    out: &mut ConsistencyMatrix,
) {
    let n = image.len().min(map.len());
    out.reset(n);
    if n == 0 {
        // No pair (e.g. no correspondence has a usable prior depth): an empty matrix.
        return;
    }
    let img = Soa::new(&image[..n]);
    let mp = Soa::new(&map[..n]);
    let (sa, sr) = (sigma_abs as f32, sigma_rel as f32);
    // Whole rows (each pair twice) keep the inner loop branch-free and vectorisable.
    for (i, row) in out.values.chunks_exact_mut(n).enumerate() {
        distance_row([img.x[i], img.y[i], img.z[i]], [mp.x[i], mp.y[i], mp.z[i]], &img, &mp, sa, sr, row);
        row[i] = 0.0;
    }
}

/// The distance θ of one correspondence (its image and map point) with every point of `img`
/// and `mp`, into `row` (as long as they are): whole rows keep the loop branch-free and
/// vectorisable.
#[inline(always)]
fn distance_row(i: [f32; 3], m: [f32; 3], img: &Soa, mp: &Soa, sa: f32, sr: f32, row: &mut [f32]) {
    for (j, theta) in row.iter_mut().enumerate() {
        let d_img = ((img.x[j] - i[0]).powi(2) + (img.y[j] - i[1]).powi(2) + (img.z[j] - i[2]).powi(2)).sqrt();
        let d_map = ((mp.x[j] - m[0]).powi(2) + (mp.y[j] - m[1]).powi(2) + (mp.z[j] - m[2]).powi(2)).sqrt();
        let delta = (d_img - d_map) / (sa + sr * d_map);
        *theta = (1.0 - delta * delta).max(0.0);
    }
}

/// Θ's rows against a fixed set of anchor correspondences: the block between any
/// correspondence and the anchors, which extends a leading eigenvector found on the anchors
/// alone to every correspondence (the Nyström extension), at n·m pairs instead of n².
pub struct AnchorRows {
    kind: AnchorKind,
    len: usize,
}

enum AnchorKind {
    /// The anchors' aligned image and map points, with the tolerance of [`distance_consistency`].
    Distance { image: Soa, map: Soa, sigma_abs: f32, sigma_rel: f32 },
    /// The anchors' centroids, their unit vectors from them and 1/σ²_d, as [`angle_consistency`]
    /// builds them.
    Angle { centres: [Point3<f64>; 2], image: Vec<Vector3<f32>>, map: Vec<Vector3<f32>>, inv_sigma2: f32 },
}

impl AnchorRows {
    /// The anchors of [`distance_consistency`] with the same tolerance.
    pub fn distance(image: &[Point3<f64>], map: &[Point3<f64>], sigma_abs: f64, sigma_rel: f64) -> Self {
        let n = image.len().min(map.len());
        let kind = AnchorKind::Distance {
            image: Soa::new(&image[..n]),
            map: Soa::new(&map[..n]),
            sigma_abs: sigma_abs as f32,
            sigma_rel: sigma_rel as f32,
        };
        Self { kind, len: n }
    }

    /// The anchors of [`angle_consistency`], centred on their (`weights`-weighted) centroids.
    pub fn angle(image: &[Point3<f64>], map: &[Point3<f64>], weights: Option<&[f64]>, sigma_d: f64) -> Self {
        let n = image.len().min(map.len());
        let centres = [weighted_centroid(&image[..n], weights), weighted_centroid(&map[..n], weights)];
        let units = |points: &[Point3<f64>], centre| points[..n].iter().map(|p| unit_from(p, centre)).collect();
        let kind = AnchorKind::Angle {
            image: units(image, &centres[0]),
            map: units(map, &centres[1]),
            centres,
            inv_sigma2: (1.0 / (sigma_d * sigma_d)) as f32,
        };
        Self { kind, len: n }
    }

    /// How many anchors.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// θ between the correspondence (`image`, `map`) and each anchor, into `row` (resized to
    /// [`AnchorRows::len`]); the same values the square builders give the anchors' own pairs.
    pub fn row(&self, image: &Point3<f64>, map: &Point3<f64>, row: &mut Vec<f32>) {
        row.resize(self.len, 0.0);
        match &self.kind {
            AnchorKind::Distance { image: img, map: mp, sigma_abs, sigma_rel } => {
                let i = [image.x as f32, image.y as f32, image.z as f32];
                let m = [map.x as f32, map.y as f32, map.z as f32];
                distance_row(i, m, img, mp, *sigma_abs, *sigma_rel, row);
            }
            AnchorKind::Angle { centres, image: ui, map: up, inv_sigma2 } => {
                let (oi, pi) = (unit_from(image, &centres[0]), unit_from(map, &centres[1]));
                for (j, theta) in row.iter_mut().enumerate() {
                    *theta = angle_theta(&oi, &pi, &ui[j], &up[j], *inv_sigma2);
                }
            }
        }
    }
}

/// Coordinates as separate `f32` arrays (structure of arrays), for vectorised pair loops.
struct Soa {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
}

impl Soa {
    fn new(points: &[Point3<f64>]) -> Self {
        Self {
            x: points.iter().map(|p| p.x as f32).collect(),
            y: points.iter().map(|p| p.y as f32).collect(),
            z: points.iter().map(|p| p.z as f32).collect(),
        }
    }
}

/// Eq. (8): s_est = (1/N) Σ ‖o_i − o_c‖ / ‖p_i − p_c‖, the mean ratio of distances to the
/// centroids. Returns the factor that maps the *map* cloud's size onto the image cloud's,
/// as in the paper; the image cloud in map units is `o / s_est`.
pub fn estimate_scale(image: &[Point3<f64>], map: &[Point3<f64>]) -> Option<f64> {
    let n = image.len().min(map.len());
    if n < 2 {
        return None;
    }
    let (oc, pc) = (weighted_centroid(&image[..n], None), weighted_centroid(&map[..n], None));
    let (mut sum, mut count) = (0.0, 0usize);
    for (o, p) in image[..n].iter().zip(&map[..n]) {
        let lp = (p - pc).norm();
        if lp > 1e-9 {
            sum += (o - oc).norm() / lp;
            count += 1;
        }
    }
    (count > 0 && sum > 0.0).then(|| sum / count as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use proptest::prelude::*;

    fn cloud(seed: u64, n: usize) -> Vec<Point3<f64>> {
        let mut rng = SplitMix64(seed);
        let mut u = || rng.next_u64() as f64 / u64::MAX as f64;
        (0..n).map(|_| Point3::new(u() * 4.0 - 2.0, u() * 3.0 - 1.5, 1.0 + u() * 4.0)).collect()
    }

    #[test]
    fn a_reused_matrix_equals_a_fresh_one() {
        let (a, b) = (cloud(1, 40), cloud(2, 40));
        for build in [
            |x: &[Point3<f64>], y: &[Point3<f64>], m: &mut ConsistencyMatrix| angle_consistency(x, y, None, 0.2, m),
            |x: &[Point3<f64>], y: &[Point3<f64>], m: &mut ConsistencyMatrix| distance_consistency(x, y, 0.05, 0.1, m),
        ] {
            let mut reused = ConsistencyMatrix { n: 40, values: vec![7.0; 40 * 40] };
            build(&a, &b, &mut reused);
            let mut fresh = ConsistencyMatrix::default();
            build(&a, &b, &mut fresh);
            assert_eq!(reused.values, fresh.values);
            assert!((0..40).all(|i| reused.get(i, i) == 0.0));
        }
    }

    #[test]
    fn anchor_rows_are_the_square_matrix_rows() {
        let (image, map) = (cloud(4, 30), cloud(5, 30));
        let weights: Vec<f64> = (0..30).map(|i| 0.5 + (i % 3) as f64).collect();
        let same_rows = |anchors: AnchorRows, square: &ConsistencyMatrix| {
            assert_eq!(anchors.len(), 30);
            let mut row = Vec::new();
            for i in 0..30 {
                anchors.row(&image[i], &map[i], &mut row);
                // Off the diagonal the same numbers; on it the pair with itself (θ = 1).
                assert_eq!(row[i], 1.0);
                row[i] = 0.0;
                assert_eq!(row.as_slice(), square.row(i), "row {i}");
            }
        };
        let mut square = ConsistencyMatrix::default();
        distance_consistency(&image, &map, 0.05, 0.1, &mut square);
        same_rows(AnchorRows::distance(&image, &map, 0.05, 0.1), &square);
        angle_consistency(&image, &map, Some(&weights), 0.2, &mut square);
        same_rows(AnchorRows::angle(&image, &map, Some(&weights), 0.2), &square);
    }

    fn pose() -> Isometry3<f64> {
        Isometry3::from_parts(Translation3::new(0.3, -1.2, 2.0), UnitQuaternion::from_euler_angles(0.3, -0.5, 1.1))
    }

    proptest! {
        #[test]
        fn angle_theta_is_invariant_to_scaling_the_image_cloud(seed in 0u64..1000, scale in 0.05f64..20.0) {
            let map = cloud(seed, 30);
            let image: Vec<_> = map.iter().map(|p| pose().inverse_transform_point(p)).collect();
            let scaled: Vec<_> = image.iter().map(|p| Point3::from(p.coords * scale)).collect();
            let (mut a, mut b) = (ConsistencyMatrix::default(), ConsistencyMatrix::default());
            angle_consistency(&image, &map, None, 0.1, &mut a);
            angle_consistency(&scaled, &map, None, 0.1, &mut b);
            for (x, y) in a.values.iter().zip(&b.values) {
                prop_assert!((x - y).abs() < 1e-4);
            }
        }
    }

    #[test]
    fn angle_theta_is_one_for_a_rigid_copy_and_low_for_a_shuffled_one() {
        let map = cloud(7, 40);
        let image: Vec<_> = map.iter().map(|p| pose().inverse_transform_point(p)).collect();
        let mut m = ConsistencyMatrix::default();
        angle_consistency(&image, &map, None, 0.1, &mut m);
        let off_diag: f32 =
            (0..40).flat_map(|i| (0..40).filter(move |&j| j != i).map(move |j| (i, j))).map(|(i, j)| m.get(i, j)).sum();
        assert!((off_diag / (40.0 * 39.0) - 1.0).abs() < 1e-4);
        let mut shuffled = image.clone();
        shuffled.reverse();
        angle_consistency(&shuffled, &map, None, 0.1, &mut m);
        let mean: f32 = m.values.iter().sum::<f32>() / (40.0 * 39.0);
        assert!(mean < 0.6, "{mean}");
    }

    #[test]
    fn distance_theta_separates_inliers_from_outliers() {
        let map = cloud(3, 50);
        let mut image: Vec<_> = map.iter().map(|p| pose().inverse_transform_point(p)).collect();
        for p in image.iter_mut().skip(40) {
            *p = Point3::new(-p.y, p.x + 1.0, p.z * 0.5);
        }
        let mut m = ConsistencyMatrix::default();
        distance_consistency(&image, &map, 0.02, 0.05, &mut m);
        assert_eq!(m.get(0, 1), 1.0);
        let outlier_support: f32 = m.row(45).iter().sum();
        let inlier_support: f32 = m.row(5).iter().sum();
        assert!(inlier_support > 3.0 * outlier_support, "{inlier_support} vs {outlier_support}");
    }

    #[test]
    fn empty_clouds_give_an_empty_matrix() {
        let mut m = ConsistencyMatrix::default();
        distance_consistency(&[], &[], 0.05, 0.1, &mut m);
        angle_consistency(&[], &[], None, 0.2, &mut m);
        assert!(m.values.is_empty());
    }

    #[test]
    fn eq8_scale_recovers_a_known_scale() {
        let map = cloud(11, 60);
        let image: Vec<_> = map.iter().map(|p| Point3::from(pose().inverse_transform_point(p).coords * 0.37)).collect();
        let s = estimate_scale(&image, &map).unwrap();
        assert!((s - 0.37).abs() < 1e-9, "{s}");
    }
}
