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
mod config;
mod corr;
mod drift;
mod odometry;
mod prior;
mod scene;

use std::collections::HashSet;

use nalgebra::{Isometry3, Matrix3, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;

use crate::frame::{CameraImage, EncodedImage, Frame, GroundTruth, MapCloud, Stamp};
use crate::geometry::{DepthImage, Intrinsics, PointIndex};
use crate::rng::mix64;

pub use building::{write_bag, SynthRun, SynthSummary};
pub use config::{SynthConfig, SynthPriorKind, MAX_BUILDING_ROOMS, MAX_MAP_POINTS, PRESETS, PRESET_MODIFIERS};
pub use corr::CorrLabel;
pub use prior::{depth_prior, Prior, PriorParams};
pub use scene::{BuildingLayout, Hit, Scene, Solid, Texture};

/// Stamp of the map cloud; frame `n` (0-based) is stamped `FIRST_STAMP + (n + 1) · 100 ms`.
pub const FIRST_STAMP: Stamp = 1_700_000_000_000_000_000;
/// Frame id of the camera's optical frame.
pub const CAMERA_FRAME_ID: &str = "camera_color_optical_frame";
/// Frame id of the map.
pub const MAP_FRAME_ID: &str = "map";
/// Frame id of the odometry frame (`odom → camera` on `/tf` with the `odometry` modifier).
pub const ODOM_FRAME_ID: &str = "odom";
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

/// The map cloud: surfaces sampled uniformly by area, jittered, moved by the fused map's drift
/// ([`drift::MapDrift`]), voxel-downsampled.
fn map_cloud(scene: &Scene, config: &SynthConfig, rng: &mut StdRng) -> MapCloud {
    let raw = scene.sample_surfaces(config.map_density, rng);
    let drift = drift::MapDrift::of(config);
    let mut seen = HashSet::new();
    let mut points = Vec::with_capacity(raw.len());
    for p in raw.into_iter().filter(|p| config.is_mapped(p)) {
        let noise = gaussian3(rng, config.cloud_noise_m);
        let q = drift.apply(&p) + noise;
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
    /// The first frame of the kidnapped camera (half its path on), if any.
    kidnap_frame: Option<usize>,
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
            kidnap_frame: (config.kidnap_at > 0.0 && config.kidnap_at < 1.0)
                .then(|| (config.kidnap_at * config.frames.max(1) as f64).round() as usize),
        }
    }

    /// Camera-to-map pose of the optical frame (x right, y down, z forward) of frame `k`.
    fn pose(&self, k: usize) -> Isometry3<f64> {
        self.pose_along(k, self.kidnap_frame.is_some_and(|first| k >= first))
    }

    /// The motion into frame `k` that odometry feels where it is not the true one: at the
    /// kidnap, the step the camera would have made had it not been carried away.
    fn felt_step(&self, k: usize) -> Option<Isometry3<f64>> {
        (self.kidnap_frame == Some(k) && k > 0)
            .then(|| self.pose_along(k - 1, false).inverse() * self.pose_along(k, false))
    }

    /// The pose of frame `k` on the path, `kidnapped` (half the path further on) or not.
    fn pose_along(&self, k: usize, kidnapped: bool) -> Isometry3<f64> {
        let along = (k as f64 / self.frames as f64 + if kidnapped { 0.5 } else { 0.0 }).fract();
        let phi = self.phase + std::f64::consts::TAU * along;
        let [a, b, c, d] = self.wobble;
        let (position, yaw) = match &self.route {
            Some(route) => route.at(along, 0.08 * (2.0 * phi + a).sin()),
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
        let mut rng = StdRng::seed_from_u64(mix64(c.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ mix64(k as u64 + 1)));
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
        let image = encode_jpeg(&render.rgb, c.width, c.height, c.jpeg_quality).map(CameraImage::Compressed);

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
            lens: None,
            odometry: (c.odometry_drift >= 0.0).then(|| {
                let odometry = odometry::Odometry::new(c.odometry_drift, c.seed);
                odometry.at(k, |j| self.path.pose(j), |j| self.path.felt_step(j))
            }),
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
                let noise = (mix64((i as u64) ^ self.scene.texture_seed ^ (self.config.seed << 20)) % 7) as f64 - 3.0;
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
