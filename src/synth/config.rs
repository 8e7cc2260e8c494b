//! What shapes a synthetic scene ([`SynthConfig`]) and the named presets: tiers of match
//! quality joined with sensor, map and prior modifiers.

use serde::{Deserialize, Serialize};

use crate::geometry::Intrinsics;

/// Tiers accepted by [`SynthConfig::preset`] (the match quality).
pub const PRESETS: [&str; 4] = ["sift", "hard", "extreme", "easy"];
/// Modifiers a tier may be joined with by `+` in [`SynthConfig::preset`]: the sensor and scene
/// (`close`, `hd`, `wide`, `office`), the map (`small-map`, `large-map`, `partial-map`) and the
/// prior (`harsh`, `disparity`).
pub const PRESET_MODIFIERS: [&str; 12] = [
    "close",
    "hd",
    "wide",
    "small-map",
    "large-map",
    "partial-map",
    "harsh",
    "disparity",
    "building",
    "office",
    "kidnap",
    "odometry",
];
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
    /// the camera on a loop through all of them ([`super::Scene::building`]).
    pub building_rooms: usize,
    /// 0: the map as sampled. N: about N points — the sampled map (which the matches are
    /// drawn from, so frames do not change with N) plus points sampled on the same surfaces.
    pub map_points: usize,
    /// Rows of identical cubicles (desk, partition, chair) along the long walls, one every this
    /// many metres; 0: none.
    pub repeat_period_m: f64,
    /// Share of the wrong matches on a cubicle that land on the same spot of the next cubicle of
    /// its row (one direction per frame, as a matcher that confuses the copies does): groups of
    /// wrong matches that agree with each other as rigidly as the true ones.
    pub repeat_outlier_fraction: f64,
    /// A map fused from keyframes with structure-from-motion pose errors: regions of this side
    /// (m) each moved by one rigid error ([`super::drift::MapDrift`]); 0: an exact map.
    pub map_keyframe_m: f64,
    /// Range of a region's rotation error, degrees.
    pub map_rotation_deg: [f64; 2],
    /// Range of a region's offset, metres.
    pub map_offset_m: [f64; 2],
    /// A kidnapped camera: from this share of the frames on, the camera is half its path further
    /// on (across the room, or the building), with nothing in the stream saying so; 0: never.
    pub kidnap_at: f64,
    /// Odometry on `/tf` (`odom → camera`): each step measured with errors of this share of its
    /// distance and turn, adding up ([`super::odometry::Odometry`]); negative: no odometry.
    pub odometry_drift: f64,
    /// The share of the room's length (x from 0) the map holds, 1: all of it. Matches on the
    /// rest cannot be true: the matcher pairs those pixels with map points of the mapped part.
    pub mapped_share: f64,
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
            repeat_period_m: 0.0,
            repeat_outlier_fraction: 0.0,
            map_keyframe_m: 0.0,
            map_rotation_deg: [0.5, 1.5],
            map_offset_m: [0.01, 0.04],
            kidnap_at: 0.0,
            mapped_share: 1.0,
            odometry_drift: -1.0,
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
    ///   one (voxels of 1 cm); `partial-map`: a map of half the room (x up to half its length),
    ///   so that it covers all, part or none of a view, and a matcher pairing the pixels it does
    ///   not cover with points of the part it does;
    /// * `office`: an office seen by an Asus Xtion (640×480, f = 570 px) — rows of identical
    ///   cubicles 1.6–4 m away, a third of the wrong matches on them landing on the next copy,
    ///   and a map fused from 2 m keyframe regions each off by 0.5–1.5° and 1–4 cm, as maps built
    ///   from structure-from-motion poses are;
    /// * `harsh`: a metric-like prior with object-sized errors, far-depth compression, smeared
    ///   edges and a ±20 % warp at an odd resolution; `disparity`: affine-invariant disparity;
    /// * `kidnap`: half-way through, the camera jumps half its path on (a kidnapped robot);
    /// * `odometry`: the robot's odometry on `/tf` (`odom → camera`), off by 2 % of every step's
    ///   distance and turn, adding up (wheel odometry's drift); it does not see a kidnap.
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
            "partial-map" => SynthConfig { mapped_share: 0.5, ..self },
            "large-map" => SynthConfig { map_voxel_m: 0.01, map_density: 4000.0, ..self },
            "harsh" => SynthConfig {
                prior_kind: SynthPriorKind::Harsh,
                warp_amplitude: 0.2,
                blur_sigma_px: 3.0,
                prior_resolution: 0.7,
                ..self
            },
            "disparity" => SynthConfig { prior_kind: SynthPriorKind::Disparity, ..self },
            "kidnap" => SynthConfig { kidnap_at: 0.5, ..self },
            "odometry" => SynthConfig { odometry_drift: 0.02, ..self },
            "building" => super::building::preset(self),
            "office" => SynthConfig {
                room_size: [9.0, 6.5, 2.8],
                path_radius_m: 0.6,
                camera_height_m: 1.4,
                repeat_period_m: 1.5,
                repeat_outlier_fraction: 0.35,
                map_keyframe_m: 2.0,
                // The fused map's few centimetres of error are inside a true match's tolerance.
                inlier_threshold_m: 0.1,
                ..resize(self, 640, 480, 570.0)
            },
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

    /// Whether the map holds the true surface point `p` (see [`SynthConfig::mapped_share`]).
    pub fn is_mapped(&self, p: &nalgebra::Point3<f64>) -> bool {
        self.mapped_share >= 1.0 || p.x <= self.mapped_share * self.room_size[0]
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
        let ordered = |[lo, hi]: [f64; 2], dflt: [f64; 2], max: f64| {
            let (lo, hi) = (nonneg(lo, dflt[0]).min(max), nonneg(hi, dflt[1]).min(max));
            [lo.min(hi), lo.max(hi)]
        };
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
            // A cubicle is 1.5 m wide with its partition: copies closer than that would overlap.
            repeat_period_m: match nonneg(self.repeat_period_m, 0.0) {
                p if p > 0.0 => p.clamp(1.5, 10.0),
                _ => 0.0,
            },
            repeat_outlier_fraction: unit(self.repeat_outlier_fraction, 0.0),
            map_keyframe_m: nonneg(self.map_keyframe_m, 0.0),
            map_rotation_deg: ordered(self.map_rotation_deg, d.map_rotation_deg, 10.0),
            map_offset_m: ordered(self.map_offset_m, d.map_offset_m, 1.0),
            kidnap_at: unit(self.kidnap_at, 0.0),
            mapped_share: fin(self.mapped_share, 1.0).clamp(0.1, 1.0),
            odometry_drift: match self.odometry_drift {
                d if d >= 0.0 => d.min(0.5),
                _ => -1.0,
            },
        }
    }
}
