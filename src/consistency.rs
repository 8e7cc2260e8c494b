//! Pairwise spatial consistency between the image cloud (pixels back-projected with the depth
//! prior) and the map cloud, and the alignment of the prior's unknown scale and shift.
//!
//! * [`angle_consistency`]: the paper's scale-invariant measure, eq. (5)–(7).
//! * [`distance_consistency`]: the classic length-preserving measure (the paper's ablation), on an
//!   image cloud aligned with [`estimate_scale_shift`].
//! * [`estimate_scale`]: eq. (8); [`estimate_scale_shift`]: scale *and* shift of the prior, which
//!   the paper lists as a limitation.
//!
//! Matrices are dense, row-major `n × n` `f32` with a zero diagonal, written into caller-owned
//! buffers so a localizer can reuse them across frames.

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

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
            let cos_i = oi.dot(&unit_i[j]).abs();
            let cos_p = pi.dot(&unit_p[j]).abs();
            let delta = cos_i - cos_p;
            let theta = (1.0 - delta * delta * inv_sigma2).max(0.0);
            out.values[i * n + j] = theta;
            out.values[j * n + i] = theta;
        }
    }
}

/// Unit vectors from the (weighted) centroid, eq. (5); a point at the centroid gets zero.
fn centred_unit_vectors(points: &[Point3<f64>], weights: Option<&[f64]>) -> Vec<Vector3<f32>> {
    let c = weighted_centroid(points, weights);
    points
        .iter()
        .map(|p| {
            let v = p - c;
            let norm = v.norm();
            if norm > 1e-12 {
                (v / norm).cast::<f32>()
            } else {
                Vector3::zeros()
            }
        })
        .collect()
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
    let img = Soa::new(&image[..n]);
    let mp = Soa::new(&map[..n]);
    let (sa, sr) = (sigma_abs as f32, sigma_rel as f32);
    // Whole rows (each pair twice) keep the inner loop branch-free and vectorisable.
    for (i, row) in out.values.chunks_exact_mut(n).enumerate() {
        let (ix, iy, iz) = (img.x[i], img.y[i], img.z[i]);
        let (mx, my, mz) = (mp.x[i], mp.y[i], mp.z[i]);
        for j in 0..n {
            let d_img = ((img.x[j] - ix).powi(2) + (img.y[j] - iy).powi(2) + (img.z[j] - iz).powi(2)).sqrt();
            let d_map = ((mp.x[j] - mx).powi(2) + (mp.y[j] - my).powi(2) + (mp.z[j] - mz).powi(2)).sqrt();
            let delta = (d_img - d_map) / (sa + sr * d_map);
            row[j] = (1.0 - delta * delta).max(0.0);
        }
        row[i] = 0.0;
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

/// Affine alignment of the depth prior: metric depth ≈ `scale`·prior + `shift` (prior in
/// depth units, i.e. after inverting an inverse-depth prior).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScaleShift {
    pub scale: f64,
    pub shift: f64,
    /// How many sampled pairs agreed with the estimate (a confidence, not a probability).
    pub support: usize,
}

impl ScaleShift {
    pub const IDENTITY: Self = Self { scale: 1.0, shift: 0.0, support: 0 };

    pub fn depth(&self, prior_depth: f64) -> f64 {
        self.scale * prior_depth + self.shift
    }
}

/// Parameters of [`estimate_scale_shift`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScaleShiftParams {
    /// Neighbours per correspondence in the image, whose pairs vote (local pairs keep their
    /// length even inside a wrongly placed but rigid patch).
    pub local_neighbours: usize,
    /// At most this many local pairs in all (fewer neighbours each for large frames).
    pub max_local_pairs: usize,
    /// Random global pairs that vote as well.
    pub global_pairs: usize,
    /// Shifts tried, as a fraction of the median prior depth: −range..=range.
    pub shift_range: f64,
    /// Coarse grid of shifts, then `fine_steps` on each side of the best between its neighbours.
    pub shift_steps: usize,
    pub fine_steps: usize,
    /// Width of the voting window on log(scale).
    pub log_scale_window: f64,
    /// Pairs shorter than this on the map (metres) do not vote.
    pub min_pair_length: f64,
    /// Gauss–Newton refinement rounds on the agreeing pairs.
    pub refine_iterations: usize,
    pub seed: u64,
}

impl Default for ScaleShiftParams {
    fn default() -> Self {
        Self {
            local_neighbours: 10,
            max_local_pairs: 4000,
            global_pairs: 4000,
            shift_range: 0.6,
            shift_steps: 9,
            fine_steps: 3,
            log_scale_window: 0.06,
            min_pair_length: 0.05,
            refine_iterations: 5,
            seed: 0x5eed,
        }
    }
}

/// Estimates scale and shift of a depth prior from putative correspondences, robust to a
/// large share of outliers: for each candidate shift t, every voting pair (i, j) proposes the
/// scale ‖q_i − q_j‖ / ‖(d_i + t)b_i − (d_j + t)b_j‖ (b = the pixel's ray with z = 1, d = prior
/// depth); the shift whose proposals agree most (densest window of log-scale) wins, then a
/// Gauss–Newton fit of (s, t) on the agreeing pairs refines it.
///
/// `rays[i]` is pixel i's ray scaled to z = 1, `prior_depth[i]` its prior depth, `pixel_pairs`
/// the local pairs (e.g. image-space kNN). Returns `None` when nothing agrees.
pub fn estimate_scale_shift(
    rays: &[Vector3<f64>],
    prior_depth: &[f64],
    map: &[Point3<f64>],
    local_pairs: &[(u32, u32)],
    params: &ScaleShiftParams,
) -> Option<ScaleShift> {
    let n = rays.len().min(prior_depth.len()).min(map.len());
    if n < 3 {
        return None;
    }
    let mut pairs: Vec<(u32, u32)> =
        local_pairs.iter().copied().filter(|&(i, j)| i != j && (i as usize) < n && (j as usize) < n).collect();
    let mut rng = SplitMix64(params.seed);
    for _ in 0..params.global_pairs {
        let i = rng.below(n) as u32;
        let j = rng.below(n) as u32;
        if i != j {
            pairs.push((i, j));
        }
    }
    let map_len: Vec<f64> = pairs.iter().map(|&(i, j)| (map[i as usize] - map[j as usize]).norm()).collect();
    let median_depth = median(prior_depth[..n].iter().copied().filter(|d| d.is_finite() && *d > 0.0).collect())?;

    // Per pair, the image length under shift t is ‖a + t·b‖ with a = r_i d_i − r_j d_j and
    // b = r_i − r_j: precompute |a|², a·b, |b|² once, so each shift costs a few flops a pair.
    let coefficients: Vec<PairTerms> = pairs
        .iter()
        .zip(&map_len)
        .filter(|(_, &len)| len >= params.min_pair_length)
        .map(|(&(i, j), &len)| {
            let (i, j) = (i as usize, j as usize);
            let a = rays[i] * prior_depth[i] - rays[j] * prior_depth[j];
            let b = rays[i] - rays[j];
            PairTerms {
                aa: a.norm_squared() as f32,
                ab: a.dot(&b) as f32,
                bb: b.norm_squared() as f32,
                log_map_len2: (len * len).ln() as f32,
                min_depth: prior_depth[i].min(prior_depth[j]) as f32,
            }
        })
        .collect();

    // Coarse-to-fine search over the shift: a coarse grid, then a fine one around its best.
    let mut votes = ScaleVotes::new(params.log_scale_window);
    let mut vote = |t: f64| -> Option<(usize, f64, f64)> {
        votes.clear();
        let tf = t as f32;
        for c in &coefficients {
            let img_len2 = c.aa + tf * (2.0 * c.ab + tf * c.bb);
            if c.min_depth + tf > 0.0 && img_len2 > 1e-18 {
                // log(scale) = ½·(log ‖q_i − q_j‖² − log ‖o_i − o_j‖²)
                votes.add(0.5 * (c.log_map_len2 - img_len2.ln()) as f64);
            }
        }
        votes.densest().map(|(count, log_scale)| (count, log_scale.exp(), t))
    };
    let steps = params.shift_steps.max(1);
    let range = params.shift_range * median_depth;
    let step = if steps > 1 { 2.0 * range / (steps - 1) as f64 } else { 0.0 };
    let better = |a: Option<(usize, f64, f64)>, b: Option<(usize, f64, f64)>| match (a, b) {
        (Some(x), Some(y)) => Some(if y.0 > x.0 { y } else { x }),
        (x, y) => x.or(y),
    };
    let mut best = None;
    for k in 0..steps {
        best = better(best, vote(-range + step * k as f64));
    }
    if let Some((_, _, centre)) = best {
        for k in 1..=params.fine_steps {
            let offset = step * k as f64 / (params.fine_steps + 1) as f64;
            best = better(best, vote(centre - offset));
            best = better(best, vote(centre + offset));
        }
    }
    let (votes, scale, t) = best?;
    let mut estimate = ScaleShift { scale, shift: scale * t, support: votes };
    refine_scale_shift(rays, prior_depth, &pairs, &map_len, params, &mut estimate);
    (estimate.scale.is_finite() && estimate.scale > 0.0 && estimate.shift.is_finite()).then_some(estimate)
}

/// Gauss–Newton on (s, t) minimising Σ (‖(s d_i + t) b_i − (s d_j + t) b_j‖ − ‖q_i − q_j‖)² over
/// the pairs that agree with the current estimate (relative residual below the vote window).
fn refine_scale_shift(
    rays: &[Vector3<f64>],
    prior_depth: &[f64],
    pairs: &[(u32, u32)],
    map_len: &[f64],
    params: &ScaleShiftParams,
    est: &mut ScaleShift,
) {
    let tol = params.log_scale_window;
    for _ in 0..params.refine_iterations {
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut used = 0usize;
        for (p, &(i, j)) in pairs.iter().enumerate() {
            let (i, j) = (i as usize, j as usize);
            if map_len[p] < params.min_pair_length {
                continue;
            }
            let (zi, zj) = (est.depth(prior_depth[i]), est.depth(prior_depth[j]));
            if zi <= 0.0 || zj <= 0.0 {
                continue;
            }
            let diff = rays[i] * zi - rays[j] * zj;
            let len = diff.norm();
            if len < 1e-9 {
                continue;
            }
            let r = len - map_len[p];
            if r.abs() > tol * map_len[p] {
                continue;
            }
            let js = diff.dot(&(rays[i] * prior_depth[i] - rays[j] * prior_depth[j])) / len;
            let jt = diff.dot(&(rays[i] - rays[j])) / len;
            a11 += js * js;
            a12 += js * jt;
            a22 += jt * jt;
            b1 += js * r;
            b2 += jt * r;
            used += 1;
        }
        let det = a11 * a22 - a12 * a12;
        if used < 3 || det.abs() < 1e-12 {
            break;
        }
        let ds = (a22 * b1 - a12 * b2) / det;
        let dt = (a11 * b2 - a12 * b1) / det;
        est.scale -= ds;
        est.shift -= dt;
        est.support = used;
        if ds.abs() < 1e-6 * est.scale.abs() && dt.abs() < 1e-6 {
            break;
        }
    }
}

/// Shift-independent terms of one voting pair.
struct PairTerms {
    aa: f32,
    ab: f32,
    bb: f32,
    log_map_len2: f32,
    min_depth: f32,
}

/// Votes on log(scale) in a fine histogram; the densest window of the vote width wins.
struct ScaleVotes {
    bins: Vec<u32>,
    /// Bins per vote window.
    window: usize,
    bin_width: f64,
}

impl ScaleVotes {
    /// log-scales outside ±`LOG_RANGE` (a factor of ~55) do not vote.
    const LOG_RANGE: f64 = 4.0;
    const BINS_PER_WINDOW: usize = 4;

    fn new(window: f64) -> Self {
        let bin_width = window.max(1e-4) / Self::BINS_PER_WINDOW as f64;
        let n = (2.0 * Self::LOG_RANGE / bin_width).ceil() as usize + 1;
        Self { bins: vec![0; n], window: Self::BINS_PER_WINDOW, bin_width }
    }

    fn clear(&mut self) {
        self.bins.fill(0);
    }

    fn add(&mut self, log_scale: f64) {
        let k = (log_scale + Self::LOG_RANGE) / self.bin_width;
        if k >= 0.0 && (k as usize) < self.bins.len() {
            self.bins[k as usize] += 1;
        }
    }

    /// (votes, centre log-scale) of the densest window.
    fn densest(&self) -> Option<(usize, f64)> {
        let mut count: u32 = self.bins[..self.window.min(self.bins.len())].iter().sum();
        let (mut best, mut best_start) = (count, 0);
        for start in 1..=self.bins.len().saturating_sub(self.window) {
            count = count + self.bins[start + self.window - 1] - self.bins[start - 1];
            if count > best {
                best = count;
                best_start = start;
            }
        }
        (best > 0)
            .then(|| (best as usize, (best_start as f64 + self.window as f64 / 2.0) * self.bin_width - Self::LOG_RANGE))
    }
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

/// A tiny deterministic generator for pair sampling (SplitMix64).
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        ((self.next() >> 11) as f64 / (1u64 << 53) as f64 * n as f64) as usize % n.max(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use proptest::prelude::*;

    fn cloud(seed: u64, n: usize) -> Vec<Point3<f64>> {
        let mut rng = SplitMix64(seed);
        let mut u = || rng.next() as f64 / u64::MAX as f64;
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
    fn eq8_scale_recovers_a_known_scale() {
        let map = cloud(11, 60);
        let image: Vec<_> = map.iter().map(|p| Point3::from(pose().inverse_transform_point(p).coords * 0.37)).collect();
        let s = estimate_scale(&image, &map).unwrap();
        assert!((s - 0.37).abs() < 1e-9, "{s}");
    }

    #[test]
    fn scale_and_shift_are_recovered_with_outliers() {
        // Camera-frame points; prior depth d = (z − t)/s.
        let (s_true, t_true) = (1.7, 0.45);
        let cam = cloud(5, 300);
        let map: Vec<_> = cam.iter().map(|p| pose().transform_point(p)).collect();
        let rays: Vec<_> = cam.iter().map(|p| p.coords / p.z).collect();
        let mut prior: Vec<_> = cam.iter().map(|p| (p.z - t_true) / s_true).collect();
        // 60 % outliers: random wrong depths.
        let mut rng = SplitMix64(99);
        for d in prior.iter_mut().take(180) {
            *d = 0.2 + 3.0 * rng.next() as f64 / u64::MAX as f64;
        }
        let est = estimate_scale_shift(&rays, &prior, &map, &[], &ScaleShiftParams::default()).unwrap();
        assert!((est.scale - s_true).abs() < 0.02 * s_true, "{est:?}");
        assert!((est.shift - t_true).abs() < 0.03, "{est:?}");
    }

    #[test]
    fn scale_votes_find_the_mode() {
        let mut votes = ScaleVotes::new(0.06);
        for v in [0.0, 0.5, 0.51, 0.52, 0.53, -2.0, 9.0] {
            votes.add(v);
        }
        let (count, centre) = votes.densest().unwrap();
        assert_eq!(count, 4);
        assert!((centre - 0.515).abs() < 0.03, "{centre}");
    }
}
