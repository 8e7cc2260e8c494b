//! Putative 2D–3D correspondences of one frame: true inliers, uniform outliers and
//! patch-wise outliers moved by one rigid motion per patch (as `patch_outliers` in
//! `make_rgbd_bags.py`), with matcher-like scores.

use nalgebra::{Isometry3, Point2, Point3, UnitQuaternion, Vector3};
use rand::rngs::StdRng;
use rand::RngExt;
use rand_distr::{Beta, Distribution};

use super::drift::MapDrift;
use super::{gaussian3, lift_pixel, Render, Scene, SynthConfig};
use crate::frame::{Correspondence, MapCloud};
use crate::geometry::{Intrinsics, PointIndex};

/// How a correspondence was made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CorrLabel {
    /// The true surface point of the pixel (plus noise).
    Inlier,
    /// A wrong point: a near miss (the true point displaced by 8–30 cm), another visible
    /// surface point or a random map point.
    Outlier,
    /// Moved with patch `patch` by that patch's rigid motion; `base_inlier` says whether
    /// the point was a true one before moving.
    Patch { patch: u32, base_inlier: bool },
}

pub(crate) struct CorrInputs<'a> {
    pub scene: &'a Scene,
    pub config: &'a SynthConfig,
    pub intrinsics: &'a Intrinsics,
    pub pose: &'a Isometry3<f64>,
    pub render: &'a Render,
    pub map: &'a MapCloud,
    pub index: Option<&'a PointIndex>,
}

pub(crate) struct Generated {
    pub correspondences: Vec<Correspondence>,
    pub labels: Vec<CorrLabel>,
    pub patches: usize,
}

struct Candidate {
    pixel: Point2<f64>,
    /// The point an inlier gets (true surface point, maybe snapped, plus noise).
    inlier_point: Point3<f64>,
    /// Whether `inlier_point` passes the ground-truth inlier test at `pixel`.
    inlier_ok: bool,
    /// Whether the pixel sees a solid that repeats identically along x (an office's cubicles).
    repeated: bool,
    /// Whether the map holds its surface point ([`SynthConfig::mapped_share`]): else it can only
    /// be a wrong match, to a point of the mapped part.
    mapped: bool,
}

/// A uniform index below `len` (> 0).
fn pick(rng: &mut StdRng, len: usize) -> usize {
    ((rng.random::<f64>() * len as f64) as usize).min(len.saturating_sub(1))
}

fn shuffle<T>(items: &mut [T], rng: &mut StdRng) {
    for i in (1..items.len()).rev() {
        let j = pick(rng, i + 1);
        items.swap(i, j);
    }
}

/// Scores like 1 − Lowe ratio: overlapping, inliers slightly higher.
struct Scores {
    inlier: Option<Beta<f64>>,
    outlier: Option<Beta<f64>>,
}

impl Scores {
    fn new() -> Self {
        Self { inlier: Beta::new(3.0, 5.0).ok(), outlier: Beta::new(1.6, 5.0).ok() }
    }

    fn sample(&self, inlier: bool, rng: &mut StdRng) -> f32 {
        let d = if inlier { &self.inlier } else { &self.outlier };
        let s = match d {
            Some(d) => d.sample(rng),
            None => rng.random::<f64>(),
        };
        s.clamp(0.0, 1.0) as f32
    }
}

impl CorrInputs<'_> {
    /// `pixel` lifted with the ground-truth depth and pose.
    fn lift(&self, pixel: &Point2<f64>) -> Option<Point3<f64>> {
        lift_pixel(self.intrinsics, self.pose, &self.render.depth, pixel)
    }

    fn image_size(&self) -> (f64, f64) {
        (self.intrinsics.width as f64, self.intrinsics.height as f64)
    }
}

/// Which patch each candidate was moved with, and each patch's members.
struct PatchAssignment {
    patch_of: Vec<Option<usize>>,
    patches: Vec<Vec<usize>>,
}

/// The candidates chosen as inliers among the unmoved ones, and the inlier ratio the moved ones
/// get before moving.
struct InlierChoice {
    is_inlier: Vec<bool>,
    base_ratio: f64,
}

pub(crate) fn correspondences(inp: &CorrInputs, rng: &mut StdRng) -> Generated {
    let cands = candidates(inp, rng);
    let assignment = assign_patches(&cands, inp.config, rng);
    let choice = choose_inliers(&cands, &assignment.patch_of, inp.config, rng);
    let (mut correspondences, labels) = points_and_scores(inp, &cands, &assignment.patch_of, &choice, rng);
    move_patches(inp, &assignment.patches, &mut correspondences, rng);
    Generated { correspondences, labels, patches: assignment.patches.len() }
}

/// 1. Pixels with their true surface points; each must be able to be a ground-truth inlier
///    (keeps pixels off depth edges and grazing spots where noise breaks the test). Keypoints
///    crowd feature-rich spots: a share of them comes from a few blobs.
fn candidates(inp: &CorrInputs, rng: &mut StdRng) -> Vec<Candidate> {
    let c = inp.config;
    let (w, h) = inp.image_size();
    let blobs: Vec<Point2<f64>> = (0..c.keypoint_blobs)
        .map(|_| Point2::new(rng.random::<f64>() * (w - 1.0), rng.random::<f64>() * (h - 1.0)))
        .collect();
    let mut cands: Vec<Candidate> = Vec::with_capacity(c.correspondences);
    for _ in 0..c.correspondences {
        let mut best: Option<Candidate> = None;
        for _ in 0..50 {
            let Some(cand) = draw_candidate(inp, &blobs, rng) else { continue };
            if cand.inlier_ok {
                best = Some(cand);
                break;
            }
            best.get_or_insert(cand);
        }
        if let Some(b) = best {
            cands.push(b);
        }
    }
    cands
}

/// One try at a candidate: a keypoint pixel (in a blob or anywhere), its surface point seen
/// from the camera, the pixel with the matcher's noise and the map point an inlier gets;
/// `None` when the ray hits nothing.
fn draw_candidate(inp: &CorrInputs, blobs: &[Point2<f64>], rng: &mut StdRng) -> Option<Candidate> {
    let (c, k) = (inp.config, inp.intrinsics);
    let (w, h) = inp.image_size();
    let truth_px = if !blobs.is_empty() && rng.random::<f64>() < c.keypoint_clustering {
        let b = blobs[pick(rng, blobs.len())];
        let d = gaussian3(rng, 0.08 * w.min(h));
        Point2::new((b.x + d.x).clamp(0.0, w - 1.0), (b.y + d.y).clamp(0.0, h - 1.0))
    } else {
        Point2::new(rng.random::<f64>() * (w - 1.0), rng.random::<f64>() * (h - 1.0))
    };
    let origin = Point3::from(inp.pose.translation.vector);
    let dir = inp.pose.rotation * Vector3::new((truth_px.x - k.cx) / k.fx, (truth_px.y - k.cy) / k.fy, 1.0);
    let hit = inp.scene.cast(&origin, &dir)?;
    let truth = origin + dir * hit.toi;
    // The fused map holds the true point where its keyframe's pose error put it.
    let mapped = MapDrift::of(c).apply(&truth);
    let noise = gaussian3(rng, 1.0);
    let pixel = Point2::new(
        (truth_px.x + noise.x * c.pixel_noise_px).clamp(0.0, w - 1.0),
        (truth_px.y + noise.y * c.pixel_noise_px).clamp(0.0, h - 1.0),
    );
    let snapped = inp
        .index
        .and_then(|index| {
            let q = Point3::new(mapped.x as f32, mapped.y as f32, mapped.z as f32);
            index.nearest(&q, 1).first().and_then(|&i| inp.map.points.get(i)).map(|p| p.cast::<f64>())
        })
        .unwrap_or(mapped);
    let inlier_point = snapped + gaussian3(rng, c.map_noise_m);
    let mapped = c.is_mapped(&truth);
    let inlier_ok = mapped && inp.lift(&pixel).is_some_and(|l| (l - inlier_point).norm() < 0.9 * c.inlier_threshold_m);
    Some(Candidate { pixel, inlier_point, inlier_ok, repeated: inp.scene.is_repeated(&hit), mapped })
}

/// 2. Patches, exactly as `patch_outliers`: a random correspondence's pixel, all not yet moved
///    correspondences within the radius, until the requested share is moved.
fn assign_patches(cands: &[Candidate], c: &SynthConfig, rng: &mut StdRng) -> PatchAssignment {
    let m = cands.len();
    let target = (c.patch_outlier_fraction * m as f64) as usize;
    let mut patch_of: Vec<Option<usize>> = vec![None; m];
    let mut patches: Vec<Vec<usize>> = Vec::new();
    let mut moved = 0;
    let mut guard = 0;
    while moved < target && m > 0 && guard < 100 * m + 100 {
        guard += 1;
        let centre = cands[pick(rng, m)].pixel;
        let sel: Vec<usize> =
            (0..m).filter(|&j| patch_of[j].is_none() && (cands[j].pixel - centre).norm() < c.patch_radius_px).collect();
        if sel.is_empty() {
            continue;
        }
        for &j in &sel {
            patch_of[j] = Some(patches.len());
        }
        moved += sel.len();
        patches.push(sel);
    }
    PatchAssignment { patch_of, patches }
}

/// 3. Inliers among the unmoved so that the overall ratio hits the configured one.
fn choose_inliers(cands: &[Candidate], patch_of: &[Option<usize>], c: &SynthConfig, rng: &mut StdRng) -> InlierChoice {
    let m = cands.len();
    let unmoved: Vec<usize> = (0..m).filter(|&j| patch_of[j].is_none()).collect();
    let mut eligible: Vec<usize> = unmoved.iter().copied().filter(|&j| cands[j].inlier_ok).collect();
    shuffle(&mut eligible, rng);
    let k = ((c.inlier_ratio * m as f64).round() as usize).min(eligible.len());
    let mut is_inlier = vec![false; m];
    for &j in &eligible[..k] {
        is_inlier[j] = true;
    }
    // Moved points were inliers before moving as often as the unmoved are (the matcher's
    // raw ratio), as when the real bags' patches were moved.
    let base_ratio = if unmoved.is_empty() { c.inlier_ratio } else { k as f64 / unmoved.len() as f64 };
    InlierChoice { is_inlier, base_ratio }
}

/// 4. Points and scores: an inlier keeps its true point, an outlier gets a wrong one.
fn points_and_scores(
    inp: &CorrInputs,
    cands: &[Candidate],
    patch_of: &[Option<usize>],
    choice: &InlierChoice,
    rng: &mut StdRng,
) -> (Vec<Correspondence>, Vec<CorrLabel>) {
    let scores = Scores::new();
    // A matcher confuses a cubicle with its neighbour on one side in a frame (no draw without
    // repeated solids, so other scenes keep their sequences).
    let repeat_shift = repeats(inp.config)
        .then(|| Vector3::x() * inp.config.repeat_period_m * if rng.random::<bool>() { 1.0 } else { -1.0 });
    let config = inp.config;
    let visible: Vec<usize> = (0..inp.render.points.len())
        .filter(|&i| inp.render.points[i].x.is_finite() && config.is_mapped(&inp.render.points[i]))
        .collect();
    let mut correspondences = Vec::with_capacity(cands.len());
    let mut labels = Vec::with_capacity(cands.len());
    for (j, cand) in cands.iter().enumerate() {
        let base_inlier = match patch_of[j] {
            None => choice.is_inlier[j],
            Some(_) => cand.inlier_ok && rng.random::<f64>() < choice.base_ratio,
        };
        // A confused copy (one the map holds) looks exactly like the true match: the matcher is as
        // confident in it.
        let (point, looks_right) = match repeat_shift {
            _ if base_inlier => (cand.inlier_point, true),
            Some(shift)
                if patch_of[j].is_none()
                    && cand.repeated
                    && config.is_mapped(&(cand.inlier_point + shift))
                    && rng.random::<f64>() < inp.config.repeat_outlier_fraction =>
            {
                (cand.inlier_point + shift, true)
            }
            _ => (outlier_point(inp, &visible, cand, rng), false),
        };
        let score = scores.sample(looks_right, rng);
        let label = match patch_of[j] {
            None if base_inlier => CorrLabel::Inlier,
            None => CorrLabel::Outlier,
            Some(p) => CorrLabel::Patch { patch: p as u32, base_inlier },
        };
        correspondences.push(Correspondence { pixel: cand.pixel, point, score });
        labels.push(label);
    }
    (correspondences, labels)
}

/// Whether the scene's wrong matches include confused copies of a repeated object.
fn repeats(c: &SynthConfig) -> bool {
    c.repeat_period_m > 0.0 && c.repeat_outlier_fraction > 0.0
}

/// A wrong point for `cand`: a near miss (of a mapped point), a visible surface point the map
/// holds or a random map point, redrawn while it would still pass the ground-truth inlier test.
fn outlier_point(inp: &CorrInputs, visible: &[usize], cand: &Candidate, rng: &mut StdRng) -> Point3<f64> {
    let (c, map) = (inp.config, &inp.map.points);
    let lifted = inp.lift(&cand.pixel);
    let mut p = Point3::origin();
    for _ in 0..30 {
        let base = if cand.mapped && rng.random::<f64>() < c.near_outlier_fraction {
            // A near miss: the true point displaced by 8–30 cm in a random direction.
            let dir = gaussian3(rng, 1.0);
            let dir = if dir.norm() > 1e-9 { dir.normalize() } else { Vector3::x() };
            cand.inlier_point + dir * (0.08 + 0.22 * rng.random::<f64>())
        } else if !visible.is_empty() && (map.is_empty() || rng.random::<f64>() < c.visible_outlier_fraction) {
            inp.render.points[visible[pick(rng, visible.len())]] + gaussian3(rng, c.map_noise_m)
        } else if !map.is_empty() {
            map[pick(rng, map.len())].cast::<f64>() + gaussian3(rng, c.map_noise_m)
        } else {
            cand.inlier_point + Vector3::new(1.0, 0.0, 0.0)
        };
        p = base;
        if lifted.is_none_or(|l| (l - p).norm() >= 1.5 * c.inlier_threshold_m) {
            break;
        }
    }
    p
}

/// 5. One rigid motion per patch about its centroid, redrawn while any of its points would
///    still pass the ground-truth inlier test.
fn move_patches(inp: &CorrInputs, patches: &[Vec<usize>], correspondences: &mut [Correspondence], rng: &mut StdRng) {
    let c = inp.config;
    for members in patches {
        let base: Vec<Point3<f64>> = members.iter().map(|&j| correspondences[j].point).collect();
        let centroid = Point3::from(base.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / base.len().max(1) as f64);
        let lifted: Vec<Option<Point3<f64>>> = members.iter().map(|&j| inp.lift(&correspondences[j].pixel)).collect();
        let mut moved_points = base.clone();
        for _ in 0..30 {
            let r = UnitQuaternion::from_scaled_axis(gaussian3(rng, c.patch_rotation_sigma));
            let t = gaussian3(rng, c.patch_translation_sigma);
            moved_points = base.iter().map(|p| centroid + r * (p - centroid) + t).collect();
            let far = moved_points
                .iter()
                .zip(&lifted)
                .all(|(p, l)| l.is_none_or(|l| (l - p).norm() >= 1.5 * c.inlier_threshold_m));
            if far {
                break;
            }
        }
        for (&j, p) in members.iter().zip(moved_points) {
            correspondences[j].point = p;
        }
    }
}
