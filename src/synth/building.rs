//! Building-scale synthetic data: the `building` preset (two rows of furnished rooms, a route
//! through all of them), maps of any size (`map_points`), and [`SynthRun`], which makes the
//! frames of a long trajectory batch by batch so that [`write_bag`] streams them to the bag in
//! constant memory.

use std::ops::Range;
use std::path::Path;

use nalgebra::{Point3, Vector3};
use rand::rngs::StdRng;
use rand::SeedableRng;

use super::scene::BuildingLayout;
use super::{map_cloud, CameraPath, FrameContext, FrameStats, Scene, SynthConfig, FIRST_STAMP};
use crate::bag::{write_frame, BagError, BagWriter, TopicMap};
use crate::frame::{Frame, MapCloud};
use crate::geometry::PointIndex;
use crate::msgs::convert;
use crate::rng::mix64;

/// Scenes with more solids than this ray cast only the solids in view of each frame.
pub(crate) const MANY_SOLIDS: usize = 40;

/// Frames made at a time by [`write_bag`] (what it holds in memory at once).
const BATCH: usize = 64;

/// The `building` modifier: 2 × 4 rooms of 8 × 6 × 3 m, a 1000-frame loop through all of them
/// (about 10 cm a frame), the matches drawn from a sparse map of ~80 k points and a published
/// map of 2 M points on the same surfaces (`map_points` sets it).
pub(super) fn preset(base: SynthConfig) -> SynthConfig {
    SynthConfig {
        building_rooms: 4,
        room_size: [8.0, 6.0, 3.0],
        camera_height_m: 1.4,
        map_density: 50.0,
        map_voxel_m: 0.0,
        map_points: 2_000_000,
        frames: 1000,
        ..base
    }
}

/// A loop through waypoints, walked at constant speed; the camera looks at the point
/// `LOOK_AHEAD_M` further on, so it turns smoothly through the corners.
#[derive(Clone, Debug)]
pub(super) struct Route {
    corners: Vec<Point3<f64>>,
    length: f64,
}

const LOOK_AHEAD_M: f64 = 1.5;

impl Route {
    pub fn new(corners: Vec<Point3<f64>>) -> Self {
        let n = corners.len();
        let length = (0..n).map(|i| (corners[(i + 1) % n] - corners[i]).norm()).sum();
        Self { corners, length }
    }

    /// The point `s` metres along the loop (wrapped).
    fn point(&self, s: f64) -> Point3<f64> {
        let n = self.corners.len();
        if n == 0 || self.length <= 0.0 {
            return self.corners.first().copied().unwrap_or_else(Point3::origin);
        }
        let mut s = s.rem_euclid(self.length);
        for i in 0..n {
            let (a, b) = (self.corners[i], self.corners[(i + 1) % n]);
            let d = (b - a).norm();
            if s <= d && d > 0.0 {
                return a + (b - a) * (s / d);
            }
            s -= d;
        }
        self.corners[0]
    }

    /// Position (lifted by `dz`) and yaw at `fraction` of the loop.
    pub fn at(&self, fraction: f64, dz: f64) -> (Point3<f64>, f64) {
        let s = fraction * self.length;
        let here = self.point(s);
        let ahead = self.point(s + LOOK_AHEAD_M);
        let yaw = (ahead.y - here.y).atan2(ahead.x - here.x);
        (here + Vector3::new(0.0, 0.0, dz), yaw)
    }
}

/// Everything the frames of one synthetic run are made from; frames on demand, in any batches
/// (each frame depends only on the seed and its number).
pub struct SynthRun {
    config: SynthConfig,
    scene: Scene,
    /// The map the matches are drawn from.
    matcher_map: MapCloud,
    /// The published map: `matcher_map`, then any extra points (`map_points`).
    map: MapCloud,
    index: Option<PointIndex>,
    path: CameraPath,
}

impl SynthRun {
    pub fn new(config: &SynthConfig) -> Self {
        let config = config.sanitized();
        let mut rng = StdRng::seed_from_u64(mix64(config.seed ^ 0x05EE_D0F5_CE1E));
        let [l, w, h] = config.room_size;
        let layout = BuildingLayout { rooms_per_row: config.building_rooms, room: Vector3::new(l, w, h) };
        let scene = match config.building_rooms {
            0 if config.repeat_period_m > 0.0 => Scene::office(layout.room, config.repeat_period_m, &mut rng),
            0 => Scene::room(layout.room, &mut rng),
            _ => Scene::building(&layout, &mut rng),
        };
        let matcher_map = map_cloud(&scene, &config, &mut rng);
        let mut path = CameraPath::random(&scene, &config, &mut rng);
        if config.building_rooms > 0 {
            path.route = Some(Route::new(layout.route(config.camera_height_m)));
        }
        let index = config.snap_to_map.then(|| PointIndex::new(&matcher_map.points));
        let map = published_map(&scene, &config, &matcher_map);
        Self { config, scene, matcher_map, map, index, path }
    }

    pub fn config(&self) -> &SynthConfig {
        &self.config
    }

    pub fn frame_count(&self) -> usize {
        self.config.frames
    }

    /// The published map.
    pub fn map(&self) -> &MapCloud {
        &self.map
    }

    pub fn into_map(self) -> MapCloud {
        self.map
    }

    /// Frames `range` (clamped to the run), in order.
    pub fn frames(&self, range: Range<usize>) -> Vec<(Frame, FrameStats)> {
        let range = range.start.min(self.frame_count())..range.end.min(self.frame_count());
        let ctx = FrameContext {
            scene: &self.scene,
            config: &self.config,
            map: &self.matcher_map,
            index: self.index.as_ref(),
            path: &self.path,
        };
        super::frames_parallel(&ctx, range)
    }
}

/// The matcher's map, plus (when `map_points` asks for more) points sampled on the same surfaces
/// at the density that brings it to about `map_points`, from a generator of their own.
fn published_map(scene: &Scene, config: &SynthConfig, matcher_map: &MapCloud) -> MapCloud {
    let extra = config.map_points.saturating_sub(matcher_map.points.len());
    if extra == 0 {
        return matcher_map.clone();
    }
    // The share of all face area that is visible, as the matcher map's sampling found it.
    let area = scene.face_area().max(1e-9);
    let visible = (matcher_map.points.len().max(1) as f64 / (area * config.map_density)).clamp(1e-3, 1.0);
    let density = extra as f64 / (area * visible);
    let mut points = Vec::with_capacity(matcher_map.points.len() + extra + extra / 8);
    points.extend_from_slice(&matcher_map.points);
    let drift = super::drift::MapDrift::of(config);
    let sampled = scene.sample_surfaces_parallel(density, config.cloud_noise_m, mix64(config.seed ^ 0xDE45_1F1E));
    let mapped = sampled.into_iter().map(|p| p.cast::<f64>()).filter(|p| config.is_mapped(p));
    points.extend(mapped.map(|p| drift.apply(&p).cast::<f32>()));
    MapCloud { frame_id: matcher_map.frame_id.clone(), points }
}

/// What [`write_bag`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthSummary {
    pub frames: usize,
    pub map_points: usize,
    pub mean_inlier_ratio: f64,
}

/// Generates the run of `config` and writes it as an input bag at `dir` (the map, then every
/// frame), `BATCH` frames at a time: memory does not grow with the number of frames. The bag is
/// the one [`crate::bag::write_input_bag`] writes from [`super::generate`]'s scene.
pub fn write_bag(dir: &Path, topics: &TopicMap, config: &SynthConfig) -> Result<SynthSummary, BagError> {
    let run = SynthRun::new(config);
    let mut writer = BagWriter::create(dir)?;
    let n = run.frame_count();
    let first = if n > 0 { FIRST_STAMP + 100_000_000 } else { 100_000_000 };
    let map_stamp = first.saturating_sub(100_000_000).max(0);
    // Offered latched, as a map server does: played back, a node that matches the map's
    // publisher late still gets it (volatile, a large map was lost to the discovery race).
    writer.latch(&topics.map);
    writer.write(&topics.map, map_stamp, &convert::point_cloud(map_stamp, run.map()))?;
    let mut ratio_sum = 0.0;
    for start in (0..n).step_by(BATCH) {
        for (frame, stats) in run.frames(start..(start + BATCH).min(n)) {
            write_frame(&mut writer, topics, &frame)?;
            ratio_sum += stats.inlier_ratio;
        }
    }
    writer.finish()?;
    Ok(SynthSummary {
        frames: n,
        map_points: run.map().points.len(),
        mean_inlier_ratio: if n == 0 { 0.0 } else { ratio_sum / n as f64 },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map_index::{MapIndex, MapScale};

    fn building(frames: usize, map_points: usize) -> SynthRun {
        let preset = SynthConfig::preset("building").expect("building preset");
        SynthRun::new(&SynthConfig { frames, map_points, seed: 4, ..preset })
    }

    /// The bag offers the map latched (transient local), the frames volatile, as
    /// [`crate::bag::write_input_bag`] does: a player's late-matching subscriber still gets it.
    #[test]
    fn the_bag_offers_the_map_latched() {
        let tmp = tempfile::tempdir().expect("a temporary directory");
        let dir = tmp.path().join("bag");
        let topics = TopicMap::default();
        let config = SynthConfig { frames: 1, ..SynthConfig::preset("hard").expect("hard preset") };
        write_bag(&dir, &topics, &config).expect("a bag");
        let text = std::fs::read_to_string(dir.join("metadata.yaml")).expect("metadata");
        let durability = |topic: &str| {
            let at = text.find(&format!("name: {topic}\n")).expect("the topic");
            let rest = &text[at..];
            let line = rest.lines().find(|l| l.trim_start().starts_with("durability:")).expect("durability");
            line.trim().trim_start_matches("durability:").trim().to_string()
        };
        assert_eq!(durability(&topics.map), "transient_local");
        assert_eq!(durability(&topics.correspondences), "volatile");
    }

    #[test]
    fn the_route_stays_clear_of_every_solid() {
        let run = building(400, 0);
        assert!(run.scene.solids.len() > MANY_SOLIDS, "{} solids", run.scene.solids.len());
        for k in 0..run.frame_count() {
            let eye = Point3::from(run.path.pose(k).translation.vector);
            let clearance = run.scene.distance_to_surfaces(&eye);
            assert!(run.scene.is_free(&eye) && clearance > 0.25, "frame {k} at {eye}: {clearance} m from a surface");
        }
    }

    #[test]
    fn more_map_points_leave_the_frames_as_they_are() {
        let (sparse, dense) = (building(2, 0), building(2, 300_000));
        let n = dense.map().points.len();
        assert!((270_000..330_000).contains(&n), "{n} points for 300 000");
        assert_eq!(
            &dense.map().points[..sparse.map().points.len()],
            &sparse.map().points[..],
            "the sparse map comes first"
        );
        let frames = |run: &SynthRun| run.frames(0..2).into_iter().map(|(f, _)| f.correspondences).collect::<Vec<_>>();
        assert_eq!(frames(&sparse), frames(&dense));
        // A building of 300 000 points is more than the render budget covers: its verification culls.
        let index = MapIndex::new(dense.map().points.clone());
        assert_eq!(index.scale(), MapScale::Building, "{} points", index.len());
    }

    #[test]
    fn the_culled_ray_cast_sees_what_the_full_one_sees() {
        let run = building(12, 0);
        let intrinsics = run.config.intrinsics();
        for k in 0..run.frame_count() {
            let pose = run.path.pose(k);
            let origin = Point3::from(pose.translation.vector);
            let in_view = run.scene.solids_in_view(&pose, &intrinsics);
            for (u, v) in [(0.0, 0.0), (160.0, 120.0), (319.0, 239.0), (40.0, 200.0), (300.0, 10.0)] {
                let d = pose.rotation
                    * Vector3::new((u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, 1.0);
                let (all, culled) = (run.scene.cast(&origin, &d), run.scene.cast_among(&origin, &d, &in_view));
                assert_eq!(all.map(|h| h.toi), culled.map(|h| h.toi), "frame {k}, pixel ({u}, {v})");
            }
        }
    }
}
