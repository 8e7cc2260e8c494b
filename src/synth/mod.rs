//! Synthetic localization data with ground truth.
//!
//! [`generate`] builds a furnished room of parry3d cuboids, samples its surfaces into a map
//! cloud, moves a camera along a smooth path inside it and, per frame, ray casts the
//! ground-truth depth, renders a textured JPEG, simulates an affine-ambiguous monocular
//! depth prior and draws putative 2D–3D correspondences with a controlled share of true
//! inliers, uniform outliers and patch-wise (locally rigid) outliers — mirroring the real
//! bag tiers of `make_rgbd_bags.py` (see [`SynthConfig::preset`]). Everything is
//! deterministic for a seed.

mod building;
mod corr;
mod prior;
mod scene;

use std::collections::HashSet;

use nalgebra::{Isometry3, Matrix3, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::frame::{EncodedImage, Frame, GroundTruth, MapCloud, Stamp};
use crate::geometry::{DepthImage, Intrinsics, PointIndex};

pub use building::{write_bag, SynthRun, SynthSummary};
pub use corr::CorrLabel;
pub use prior::{depth_prior, Prior, PriorParams};
pub use scene::{BuildingLayout, Hit, Scene, Solid, Texture};

/// Stamp of the map cloud; frame `n` (0-based) is stamped `FIRST_STAMP + (n + 1) · 100 ms`.
pub const FIRST_STAMP: Stamp = 1_700_000_000_000_000_000;
/// Frame id of the camera's optical frame.
pub const CAMERA_FRAME_ID: &str = "camera_color_optical_frame";
/// Frame id of the map.
pub const MAP_FRAME_ID: &str = "map";
/// Tiers accepted by [`SynthConfig::preset`] (the match quality).
pub const PRESETS: [&str; 4] = ["sift", "hard", "extreme", "easy"];
/// Modifiers a tier may be joined with by `+` in [`SynthConfig::preset`]: the sensor and scene
/// (`close`, `hd`, `wide`), the map (`small-map`, `large-map`) and the prior (`harsh`, `disparity`).
pub const PRESET_MODIFIERS: [&str; 8] =
    ["close", "hd", "wide", "small-map", "large-map", "harsh", "disparity", "building"];
/// Rooms per row of a building, at most.
pub const MAX_BUILDING_ROOMS: usize = 32;
/// Map points `synth` makes, at most.
pub const MAX_MAP_POINTS: usize = 50_000_000;

/// What kind of monocular prior the generator simulates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SynthPriorKind {
    /// Metric-like depth: ground truth warped at low frequency and blurred, then an unknown
    /// scale and shift (`depth ≈ scale·prior + shift`).
    #[default]
    Depth,
    /// Metric-like depth with the errors real networks make: object-sized regions off by up to
    /// ±15 %, a monotonic compression of far depths, edges smeared (use a strong warp with it).
    Harsh,
    /// Affine-invariant disparity: `prior = scale/depth + shift`, the shift 20–60 % of the median
    /// value (read it with `depth_kind: disparity`).
    Disparity,
}

/// Everything that shapes a synthetic scene. Every field has a default (the "sift" tier).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SynthConfig {
    pub seed: u64,
    /// Number of camera frames.
    pub frames: usize,
    /// Camera image size and pinhole intrinsics (pixel centres at integer coordinates).
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Prior resolution relative to the camera image (0.5 = half size).
    pub prior_resolution: f64,
    /// Putative correspondences per frame.
    pub correspondences: usize,
    /// Share of correspondences that are true inliers (3D distance of the ground-truth
    /// lifted pixel to the map point below `inlier_threshold_m`).
    pub inlier_ratio: f64,
    /// Per-frame spread of the inlier ratio: each frame's ratio is
    /// `inlier_ratio · exp(spread · N(0, 1))` (0 = every frame exactly `inlier_ratio`).
    pub inlier_ratio_spread: f64,
    /// Share of keypoints drawn around `keypoint_blobs` random image spots (Gaussian,
    /// σ = 8 % of the smaller image side) rather than uniformly, as features crowd textured spots.
    pub keypoint_clustering: f64,
    pub keypoint_blobs: usize,
    /// Share of correspondences moved patch by patch by one rigid motion each.
    pub patch_outlier_fraction: f64,
    /// Radius of an outlier patch in pixels.
    pub patch_radius_px: f64,
    /// Std-dev of the rigid motion of a patch: rotation vector (rad) and translation (m).
    pub patch_rotation_sigma: f64,
    pub patch_translation_sigma: f64,
    /// Pixel noise (std-dev per axis, px).
    pub pixel_noise_px: f64,
    /// Noise on a correspondence's 3D point (std-dev per axis, m).
    pub map_noise_m: f64,
    /// Noise on the map cloud's points (std-dev per axis, m).
    pub cloud_noise_m: f64,
    /// Surface sampling density of the map cloud before voxelisation (points per m²).
    pub map_density: f64,
    /// Voxel size of the map cloud (first point per voxel is kept), m.
    pub map_voxel_m: f64,
    /// Inliers take the nearest map-cloud point to the true surface point (like a matcher
    /// snapping to the map) instead of the true point, before `map_noise_m`.
    pub snap_to_map: bool,
    /// Share of the other outliers whose point is visible in the frame (another pixel's
    /// surface point); the rest take a random map point anywhere.
    pub visible_outlier_fraction: f64,
    /// Share of (non-patch) outliers that are near misses: the true point displaced by
    /// 8–30 cm, as repeated texture or a wrong keyframe depth gives them.
    pub near_outlier_fraction: f64,
    /// Ground-truth inlier threshold (m), as the evaluation measures it.
    pub inlier_threshold_m: f64,
    /// Log-uniform range of the prior's scale `s` (depth ≈ s · prior + t).
    pub prior_scale_range: [f64; 2],
    /// The prior's shift `t` ~ U(−f, f) · median depth.
    pub prior_shift_fraction: f64,
    /// Amplitude of the prior's low-frequency multiplicative warp.
    pub warp_amplitude: f64,
    /// Gaussian blur of the prior, in prior pixels.
    pub blur_sigma_px: f64,
    /// Interior size of the room (x, y, z), m.
    pub room_size: [f64; 3],
    /// Camera path: height of the optical centre and radius of the loop about the room centre.
    pub camera_height_m: f64,
    pub path_radius_m: f64,
    /// JPEG quality (1–100).
    pub jpeg_quality: u8,
    /// The kind of prior and its error classes.
    pub prior_kind: SynthPriorKind,
    /// 0: one room. N: a building of two rows of N rooms of `room_size` joined by doorways,
    /// the camera on a loop through all of them ([`Scene::building`]).
    pub building_rooms: usize,
    /// 0: the map as sampled. N: about N points — the sampled map (which the matches are
    /// drawn from, so frames do not change with N) plus points sampled on the same surfaces.
    pub map_points: usize,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            seed: 0,
            frames: 20,
            width: 320,
            height: 240,
            fx: 262.5,
            fy: 262.5,
            cx: 160.0,
            cy: 120.0,
            prior_resolution: 0.5,
            correspondences: 800,
            inlier_ratio: 0.5,
            inlier_ratio_spread: 0.0,
            keypoint_clustering: 0.5,
            keypoint_blobs: 6,
            patch_outlier_fraction: 0.0,
            patch_radius_px: 20.0,
            patch_rotation_sigma: 0.3,
            patch_translation_sigma: 0.6,
            pixel_noise_px: 1.0,
            map_noise_m: 0.015,
            cloud_noise_m: 0.003,
            map_density: 700.0,
            map_voxel_m: 0.025,
            snap_to_map: false,
            visible_outlier_fraction: 0.8,
            near_outlier_fraction: 0.15,
            inlier_threshold_m: 0.05,
            prior_scale_range: [0.4, 2.5],
            prior_shift_fraction: 0.2,
            warp_amplitude: 0.10,
            blur_sigma_px: 2.0,
            room_size: [5.0, 4.0, 2.7],
            camera_height_m: 1.3,
            path_radius_m: 0.35,
            jpeg_quality: 90,
            prior_kind: SynthPriorKind::Depth,
            building_rooms: 0,
            map_points: 0,
        }
    }
}

impl SynthConfig {
    /// A tier, optionally joined with modifiers by `+` (e.g. `hard+close+disparity`); `None` for
    /// an unknown name. Tiers mirror the real bags: "sift" (≈ 800 matches, ~50 % inliers, no
    /// patch outliers), "hard" (400, ~15 %, half moved patch-wise), "extreme" (300, ~6 %,
    /// three quarters moved patch-wise), and "easy" (400, ~83 %, as a good matcher on an RGB-D
    /// sensor gives). Modifiers ([`PRESET_MODIFIERS`]):
    /// * `close`: an RGB-D sensor at close range (640×480, f = 615 px, surfaces 0.3–1.5 m away
    ///   in a 3 × 3 m room, the map and matches with a near sensor's millimetre noise);
    /// * `hd`: 1280×720, f = 900 px, an 8 × 6 m room; `wide`: 640×480, f = 400 px (~77° FOV);
    /// * `small-map`: a sparse map (voxels of 8 cm: a few thousand points); `large-map`: a dense
    ///   one (voxels of 1 cm);
    /// * `harsh`: a metric-like prior with object-sized errors, far-depth compression, smeared
    ///   edges and a ±20 % warp at an odd resolution; `disparity`: affine-invariant disparity.
    pub fn preset(name: &str) -> Option<SynthConfig> {
        let name = name.trim().to_ascii_lowercase();
        let mut parts = name.split('+').map(str::trim);
        let mut config = Self::tier(parts.next()?)?;
        for modifier in parts {
            config = config.with_modifier(modifier)?;
        }
        Some(config)
    }

    /// `self` changed by one of [`PRESET_MODIFIERS`]; `None` for an unknown one. Pixel sizes
    /// (patch radius) follow the image width.
    fn with_modifier(self, modifier: &str) -> Option<SynthConfig> {
        let resize = |c: SynthConfig, width: u32, height: u32, f: f64| {
            let ratio = width as f64 / c.width as f64;
            SynthConfig {
                width,
                height,
                fx: f,
                fy: f,
                cx: width as f64 / 2.0,
                cy: height as f64 / 2.0,
                patch_radius_px: c.patch_radius_px * ratio,
                ..c
            }
        };
        Some(match modifier {
            "close" => SynthConfig {
                room_size: [3.0, 3.0, 2.5],
                path_radius_m: 0.85,
                camera_height_m: 1.1,
                cloud_noise_m: 0.003,
                map_noise_m: 0.004,
                map_density: 300.0,
                map_voxel_m: 0.03,
                ..resize(self, 640, 480, 615.0)
            },
            "hd" => SynthConfig { room_size: [8.0, 6.0, 3.0], path_radius_m: 1.5, ..resize(self, 1280, 720, 900.0) },
            "wide" => SynthConfig { room_size: [6.0, 5.0, 2.8], ..resize(self, 640, 480, 400.0) },
            "small-map" => SynthConfig { map_voxel_m: 0.08, map_density: 150.0, ..self },
            "large-map" => SynthConfig { map_voxel_m: 0.01, map_density: 4000.0, ..self },
            "harsh" => SynthConfig {
                prior_kind: SynthPriorKind::Harsh,
                warp_amplitude: 0.2,
                blur_sigma_px: 3.0,
                prior_resolution: 0.7,
                ..self
            },
            "disparity" => SynthConfig { prior_kind: SynthPriorKind::Disparity, ..self },
            "building" => building::preset(self),
            _ => return None,
        })
    }

    /// The match-quality tier alone.
    fn tier(name: &str) -> Option<SynthConfig> {
        let base = SynthConfig::default();
        match name {
            "sift" => Some(base),
            "hard" => {
                Some(SynthConfig { correspondences: 400, inlier_ratio: 0.15, patch_outlier_fraction: 0.5, ..base })
            }
            "extreme" => {
                Some(SynthConfig { correspondences: 300, inlier_ratio: 0.06, patch_outlier_fraction: 0.75, ..base })
            }
            "easy" => Some(SynthConfig { correspondences: 400, inlier_ratio: 0.83, ..base }),
            // A building alone is the hard tier in a building.
            "building" => Self::tier("hard")?.with_modifier("building"),
            _ => None,
        }
    }

    /// The camera intrinsics of every frame.
    pub fn intrinsics(&self) -> Intrinsics {
        let c = self.sanitized();
        Intrinsics { fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy, width: c.width, height: c.height }
    }

    /// A copy with every value brought into a usable range (never fails).
    pub fn sanitized(&self) -> SynthConfig {
        let d = SynthConfig::default();
        let fin = |v: f64, dflt: f64| if v.is_finite() { v } else { dflt };
        let nonneg = |v: f64, dflt: f64| fin(v, dflt).max(0.0);
        let unit = |v: f64, dflt: f64| fin(v, dflt).clamp(0.0, 1.0);
        let width = self.width.clamp(8, 4096);
        let height = self.height.clamp(8, 4096);
        let pos = |v: f64, dflt: f64| if v.is_finite() && v > 0.0 { v } else { dflt };
        let fx = pos(self.fx, d.fx * width as f64 / d.width as f64);
        let fy = pos(self.fy, d.fy * height as f64 / d.height as f64);
        let cx = fin(self.cx, width as f64 / 2.0);
        let cy = fin(self.cy, height as f64 / 2.0);
        let mut scale_range = [pos(self.prior_scale_range[0], 0.4), pos(self.prior_scale_range[1], 2.5)];
        if scale_range[1] < scale_range[0] {
            scale_range.swap(0, 1);
        }
        let room = [
            fin(self.room_size[0], 5.0).clamp(3.0, 50.0),
            fin(self.room_size[1], 4.0).clamp(3.0, 50.0),
            fin(self.room_size[2], 2.7).clamp(2.0, 10.0),
        ];
        SynthConfig {
            seed: self.seed,
            frames: self.frames.min(100_000),
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            prior_resolution: fin(self.prior_resolution, 0.5).clamp(0.01, 1.0),
            correspondences: self.correspondences.min(1_000_000),
            inlier_ratio: unit(self.inlier_ratio, d.inlier_ratio),
            inlier_ratio_spread: nonneg(self.inlier_ratio_spread, 0.0).min(3.0),
            keypoint_clustering: unit(self.keypoint_clustering, d.keypoint_clustering),
            keypoint_blobs: self.keypoint_blobs.min(1000),
            patch_outlier_fraction: unit(self.patch_outlier_fraction, 0.0),
            patch_radius_px: pos(self.patch_radius_px, d.patch_radius_px),
            patch_rotation_sigma: nonneg(self.patch_rotation_sigma, d.patch_rotation_sigma),
            patch_translation_sigma: nonneg(self.patch_translation_sigma, d.patch_translation_sigma),
            pixel_noise_px: nonneg(self.pixel_noise_px, d.pixel_noise_px),
            map_noise_m: nonneg(self.map_noise_m, d.map_noise_m),
            cloud_noise_m: nonneg(self.cloud_noise_m, d.cloud_noise_m),
            map_density: fin(self.map_density, d.map_density).clamp(1.0, 20_000.0),
            map_voxel_m: nonneg(self.map_voxel_m, d.map_voxel_m),
            snap_to_map: self.snap_to_map,
            visible_outlier_fraction: unit(self.visible_outlier_fraction, d.visible_outlier_fraction),
            near_outlier_fraction: unit(self.near_outlier_fraction, d.near_outlier_fraction),
            inlier_threshold_m: pos(self.inlier_threshold_m, d.inlier_threshold_m),
            prior_scale_range: scale_range,
            prior_shift_fraction: nonneg(self.prior_shift_fraction, d.prior_shift_fraction).min(0.9),
            warp_amplitude: nonneg(self.warp_amplitude, d.warp_amplitude).min(0.9),
            blur_sigma_px: nonneg(self.blur_sigma_px, d.blur_sigma_px).min(50.0),
            room_size: room,
            camera_height_m: fin(self.camera_height_m, 1.3).clamp(0.9, room[2] - 0.9),
            path_radius_m: nonneg(self.path_radius_m, d.path_radius_m).min(room[0].min(room[1]) / 2.0 - 0.5),
            jpeg_quality: self.jpeg_quality.clamp(1, 100),
            prior_kind: self.prior_kind,
            building_rooms: self.building_rooms.min(MAX_BUILDING_ROOMS),
            map_points: self.map_points.min(MAX_MAP_POINTS),
        }
    }
}

/// What the generator knows about one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameStats {
    pub stamp: Stamp,
    pub correspondences: usize,
    /// Ground-truth inliers, measured as the evaluation does ([`inlier_mask`]).
    pub inliers: usize,
    pub inlier_ratio: f64,
    /// Correspondences moved patch-wise, and the number of patches.
    pub patch_moved: usize,
    pub patches: usize,
    /// The prior's affine map: ground-truth depth ≈ `prior_scale` · prior + `prior_shift`
    /// (for a disparity prior: prior = `prior_scale` / depth + `prior_shift`).
    pub prior_scale: f64,
    pub prior_shift: f64,
    pub min_depth: f64,
    pub median_depth: f64,
    /// Distance from the camera centre to the nearest surface, m.
    pub clearance_m: f64,
    /// How each correspondence was made, in order.
    pub labels: Vec<CorrLabel>,
}

/// A generated scene: the map, the frames and what the generator knows about them.
#[derive(Clone, Debug)]
pub struct SynthScene {
    pub map: MapCloud,
    pub frames: Vec<Frame>,
    pub stats: Vec<FrameStats>,
    /// The (sanitised) configuration it was generated from.
    pub config: SynthConfig,
}

impl SynthScene {
    /// Mean ground-truth inlier ratio over the frames (0 for none).
    pub fn mean_inlier_ratio(&self) -> f64 {
        if self.stats.is_empty() {
            return 0.0;
        }
        self.stats.iter().map(|s| s.inlier_ratio).sum::<f64>() / self.stats.len() as f64
    }
}

/// 3D distance between a correspondence's map point and its pixel lifted with the
/// ground-truth depth (nearest pixel) and pose; `None` where the depth is unknown.
pub fn lifted_distance(
    intrinsics: &Intrinsics,
    pose: &Isometry3<f64>,
    depth: &DepthImage,
    pixel: &Point2<f64>,
    point: &Point3<f64>,
) -> Option<f64> {
    let lifted = lift_pixel(intrinsics, pose, depth, pixel)?;
    Some((lifted - point).norm())
}

/// A pixel lifted to the map frame with the ground-truth depth at the nearest pixel.
pub fn lift_pixel(
    intrinsics: &Intrinsics,
    pose: &Isometry3<f64>,
    depth: &DepthImage,
    pixel: &Point2<f64>,
) -> Option<Point3<f64>> {
    if !(pixel.x.is_finite() && pixel.y.is_finite()) {
        return None;
    }
    let sx = depth.width as f64 / intrinsics.width.max(1) as f64;
    let sy = depth.height as f64 / intrinsics.height.max(1) as f64;
    let u = ((pixel.x + 0.5) * sx - 0.5).round() as i64;
    let v = ((pixel.y + 0.5) * sy - 0.5).round() as i64;
    let z = depth.at(u, v)? as f64;
    Some(pose * intrinsics.back_project(pixel, z))
}

/// Ground-truth inlier flags of a frame's correspondences (3D distance < `threshold_m`);
/// all false without ground truth pose and depth.
pub fn inlier_mask(frame: &Frame, threshold_m: f64) -> Vec<bool> {
    let gt = frame.ground_truth.as_ref();
    let (Some(pose), Some(depth)) = (gt.and_then(|g| g.pose), gt.and_then(|g| g.depth.as_ref())) else {
        return vec![false; frame.correspondences.len()];
    };
    frame
        .correspondences
        .iter()
        .map(|c| lifted_distance(&frame.intrinsics, &pose, depth, &c.pixel, &c.point).is_some_and(|d| d < threshold_m))
        .collect()
}

/// Generates a scene, deterministically for `config.seed` (all frames in memory; a long
/// trajectory streams through [`SynthRun`] instead).
pub fn generate(config: &SynthConfig) -> SynthScene {
    let run = SynthRun::new(config);
    let (frames, stats) = run.frames(0..run.frame_count()).into_iter().unzip();
    let config = run.config().clone();
    SynthScene { map: run.into_map(), frames, stats, config }
}

/// Frames `range` of `ctx`, generated on up to 8 threads, in order.
fn frames_parallel(ctx: &FrameContext, range: std::ops::Range<usize>) -> Vec<(Frame, FrameStats)> {
    let (first, n) = (range.start, range.len());
    let threads = std::thread::available_parallelism().map_or(1, |p| p.get()).clamp(1, 8).min(n.max(1));
    let mut results: Vec<Option<(Frame, FrameStats)>> = Vec::new();
    results.resize_with(n, || None);
    if threads <= 1 {
        for (k, slot) in results.iter_mut().enumerate() {
            *slot = Some(ctx.frame(first + k));
        }
    } else {
        let chunks: Vec<Vec<(usize, (Frame, FrameStats))>> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..threads)
                .map(|t| {
                    s.spawn(move || (t..n).step_by(threads).map(|k| (k, ctx.frame(first + k))).collect::<Vec<_>>())
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap_or_default()).collect()
        });
        for (k, r) in chunks.into_iter().flatten() {
            if let Some(slot) = results.get_mut(k) {
                *slot = Some(r);
            }
        }
        // A worker that died (it cannot, short of a bug) leaves holes: fill them serially.
        for (k, slot) in results.iter_mut().enumerate() {
            if slot.is_none() {
                *slot = Some(ctx.frame(first + k));
            }
        }
    }
    results.into_iter().flatten().collect()
}

/// The map cloud: surfaces sampled uniformly by area, jittered, voxel-downsampled.
fn map_cloud(scene: &Scene, config: &SynthConfig, rng: &mut StdRng) -> MapCloud {
    let raw = scene.sample_surfaces(config.map_density, rng);
    let mut seen = HashSet::new();
    let mut points = Vec::with_capacity(raw.len());
    for p in raw {
        let noise = gaussian3(rng, config.cloud_noise_m);
        let q = p + noise;
        if config.map_voxel_m > 0.0 {
            let key = (
                (q.x / config.map_voxel_m).floor() as i64,
                (q.y / config.map_voxel_m).floor() as i64,
                (q.z / config.map_voxel_m).floor() as i64,
            );
            if !seen.insert(key) {
                continue;
            }
        }
        points.push(Point3::new(q.x as f32, q.y as f32, q.z as f32));
    }
    MapCloud { frame_id: MAP_FRAME_ID.to_string(), points }
}

fn gaussian3(rng: &mut StdRng, sigma: f64) -> Vector3<f64> {
    if sigma <= 0.0 {
        return Vector3::zeros();
    }
    Vector3::new(
        rng.sample::<f64, _>(StandardNormal),
        rng.sample::<f64, _>(StandardNormal),
        rng.sample::<f64, _>(StandardNormal),
    ) * sigma
}

/// A smooth loop about the room centre, looking outward with a little pitch and roll (or, in a
/// building, a loop along `route`, looking ahead).
struct CameraPath {
    centre: Point3<f64>,
    radius: f64,
    phase: f64,
    wobble: [f64; 4],
    frames: usize,
    route: Option<building::Route>,
}

impl CameraPath {
    fn random(scene: &Scene, config: &SynthConfig, rng: &mut StdRng) -> CameraPath {
        let tau = std::f64::consts::TAU;
        CameraPath {
            centre: Point3::new(scene.size.x / 2.0, scene.size.y / 2.0, config.camera_height_m),
            radius: config.path_radius_m,
            phase: rng.random::<f64>() * tau,
            wobble: [
                rng.random::<f64>() * tau,
                rng.random::<f64>() * tau,
                rng.random::<f64>() * tau,
                rng.random::<f64>() * tau,
            ],
            frames: config.frames.max(1),
            route: None,
        }
    }

    /// Camera-to-map pose of the optical frame (x right, y down, z forward) of frame `k`.
    fn pose(&self, k: usize) -> Isometry3<f64> {
        let phi = self.phase + std::f64::consts::TAU * k as f64 / self.frames as f64;
        let [a, b, c, d] = self.wobble;
        let (position, yaw) = match &self.route {
            Some(route) => route.at(k as f64 / self.frames as f64, 0.08 * (2.0 * phi + a).sin()),
            None => (
                self.centre
                    + Vector3::new(self.radius * phi.cos(), self.radius * phi.sin(), 0.08 * (2.0 * phi + a).sin()),
                phi + 0.35 * (3.0 * phi + b).sin(),
            ),
        };
        let pitch = -0.2 + 0.1 * (2.0 * phi + c).sin();
        let roll = 0.05 * (5.0 * phi + d).sin();
        let forward = Vector3::new(pitch.cos() * yaw.cos(), pitch.cos() * yaw.sin(), pitch.sin());
        let right0 = forward.cross(&Vector3::z()).normalize();
        let down0 = forward.cross(&right0);
        let right = right0 * roll.cos() + down0 * roll.sin();
        let down = down0 * roll.cos() - right0 * roll.sin();
        let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[right, down, forward]));
        Isometry3::from_parts(Translation3::from(position.coords), UnitQuaternion::from_rotation_matrix(&r))
    }
}

/// Shared, read-only inputs of the per-frame generator.
struct FrameContext<'a> {
    scene: &'a Scene,
    config: &'a SynthConfig,
    map: &'a MapCloud,
    index: Option<&'a PointIndex>,
    path: &'a CameraPath,
}

/// A frame's ray-cast render.
pub(crate) struct Render {
    pub depth: DepthImage,
    /// Map-frame surface point of every pixel centre (NaN where nothing was hit).
    pub points: Vec<Point3<f64>>,
    pub rgb: Vec<u8>,
}

impl FrameContext<'_> {
    fn frame(&self, k: usize) -> (Frame, FrameStats) {
        let c = self.config;
        let mut rng = StdRng::seed_from_u64(scene::mix64(
            c.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ scene::mix64(k as u64 + 1),
        ));
        let intrinsics = c.intrinsics();
        let pose = self.path.pose(k);
        let stamp = FIRST_STAMP + (k as i64 + 1) * 100_000_000;
        let render = self.render(&intrinsics, &pose);

        let frame_config;
        let c = if c.inlier_ratio_spread > 0.0 {
            let ratio = c.inlier_ratio * (c.inlier_ratio_spread * rng.sample::<f64, _>(StandardNormal)).exp();
            frame_config = SynthConfig { inlier_ratio: ratio.clamp(0.0, 1.0), ..c.clone() };
            &frame_config
        } else {
            c
        };
        let generated = corr::correspondences(
            &corr::CorrInputs {
                scene: self.scene,
                config: c,
                intrinsics: &intrinsics,
                pose: &pose,
                render: &render,
                map: self.map,
                index: self.index,
            },
            &mut rng,
        );

        let params = PriorParams {
            width: ((c.width as f64 * c.prior_resolution).round() as u32).max(1),
            height: ((c.height as f64 * c.prior_resolution).round() as u32).max(1),
            warp_amplitude: c.warp_amplitude,
            blur_sigma: c.blur_sigma_px,
            scale_range: c.prior_scale_range,
            shift_fraction: c.prior_shift_fraction,
            kind: c.prior_kind,
        };
        let prior = depth_prior(&render.depth, &params, &mut rng);
        let image = encode_jpeg(&render.rgb, c.width, c.height, c.jpeg_quality);

        let mut depths: Vec<f64> =
            render.depth.data.iter().filter(|d| d.is_finite() && **d > 0.0).map(|&d| d as f64).collect();
        depths.sort_by(|a, b| a.total_cmp(b));
        let min_depth = depths.first().copied().unwrap_or(0.0);
        let median_depth = depths.get(depths.len() / 2).copied().unwrap_or(0.0);

        let frame = Frame {
            stamp,
            camera_frame_id: CAMERA_FRAME_ID.to_string(),
            map_frame_id: MAP_FRAME_ID.to_string(),
            intrinsics,
            correspondences: generated.correspondences,
            depth_prior: Some(prior.image),
            image,
            ground_truth: Some(GroundTruth { pose: Some(pose), depth: Some(render.depth) }),
        };
        let mask = inlier_mask(&frame, c.inlier_threshold_m);
        let inliers = mask.iter().filter(|&&m| m).count();
        let n = frame.correspondences.len();
        let stats = FrameStats {
            stamp,
            correspondences: n,
            inliers,
            inlier_ratio: if n == 0 { 0.0 } else { inliers as f64 / n as f64 },
            patch_moved: generated.labels.iter().filter(|l| matches!(l, CorrLabel::Patch { .. })).count(),
            patches: generated.patches,
            prior_scale: prior.scale,
            prior_shift: prior.shift,
            min_depth,
            median_depth,
            clearance_m: self.scene.distance_to_surfaces(&Point3::from(pose.translation.vector)),
            labels: generated.labels,
        };
        (frame, stats)
    }

    /// Ray casts every pixel centre: z-depth, surface point and shaded colour.
    fn render(&self, intrinsics: &Intrinsics, pose: &Isometry3<f64>) -> Render {
        let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
        let origin = Point3::from(pose.translation.vector);
        let rot = pose.rotation.to_rotation_matrix();
        let mut depth = vec![0.0f32; w * h];
        let mut points = vec![Point3::new(f64::NAN, f64::NAN, f64::NAN); w * h];
        let mut rgb = vec![0u8; w * h * 3];
        // A building has hundreds of solids: each ray tries only those in view.
        let in_view =
            (self.scene.solids.len() > building::MANY_SOLIDS).then(|| self.scene.solids_in_view(pose, intrinsics));
        for v in 0..h {
            for u in 0..w {
                let i = v * w + u;
                // Camera-frame direction with z = 1, so the time of impact is the z-depth.
                let d_cam = Vector3::new(
                    (u as f64 - intrinsics.cx) / intrinsics.fx,
                    (v as f64 - intrinsics.cy) / intrinsics.fy,
                    1.0,
                );
                let dir = rot * d_cam;
                let hit = match &in_view {
                    Some(candidates) => self.scene.cast_among(&origin, &dir, candidates),
                    None => self.scene.cast(&origin, &dir),
                };
                let Some(hit) = hit else { continue };
                let p = origin + dir * hit.toi;
                depth[i] = hit.toi as f32;
                points[i] = p;
                let col = self.scene.shade(&p, &hit, &origin);
                // Linear → sRGB-ish gamma, plus a little deterministic sensor noise.
                let noise =
                    (scene::mix64((i as u64) ^ self.scene.texture_seed ^ (self.config.seed << 20)) % 7) as f64 - 3.0;
                for ch in 0..3 {
                    rgb[i * 3 + ch] = (col[ch].powf(1.0 / 2.2) * 255.0 + noise).round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        Render { depth: DepthImage::new(w as u32, h as u32, depth), points, rgb }
    }
}

/// JPEG-encodes an RGB8 buffer; `None` if it cannot be encoded.
fn encode_jpeg(rgb: &[u8], width: u32, height: u32, quality: u8) -> Option<EncodedImage> {
    if rgb.len() != width as usize * height as usize * 3 {
        return None;
    }
    let mut data = Vec::new();
    let mut encoder = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut data, quality);
    encoder.encode(rgb, width, height, image::ExtendedColorType::Rgb8).ok()?;
    Some(EncodedImage { format: "jpeg".to_string(), data })
}

#[cfg(test)]
mod tests;
