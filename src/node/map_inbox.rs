//! The node's one map: whichever way it comes (the map topic, `map_path`, `~/load_map`), it is
//! taken once, indexed once on the shared [`MapSwap`], and handed to every camera's ingest (one
//! `Arc`, no copy per camera). A map is checked before it replaces the one held: an unusable
//! one (no point, most points beyond any plausible place, all of it in a speck) is refused and
//! counted, and the node goes on with the map it had (#38). Who sent each map is logged; a map
//! from another publisher than the held map's is counted (`map_publisher_changed`, #37).

use std::sync::Arc;

use super::ingest::{Ingest, MapSender};
use super::log::{info, warn};
use crate::frame::MapCloud;
use crate::map_index::swap::MapSwap;
use crate::map_index::IndexSettings;
use crate::msgs::convert::DecodedMap;

/// The map the node localizes against, and the index every worker shares.
pub struct MapInbox {
    current: Option<Arc<MapCloud>>,
    /// Who sent `current`.
    sender: Option<MapSender>,
    swap: Arc<MapSwap>,
    settings: IndexSettings,
}

impl MapInbox {
    pub fn new(swap: Arc<MapSwap>, settings: IndexSettings) -> Self {
        Self { current: None, sender: None, swap, settings }
    }

    /// A map (or why one was unusable) from `sender`, for every camera in `cameras`.
    pub fn on_map<'a>(
        &mut self,
        map: Result<DecodedMap, String>,
        sender: MapSender,
        cameras: impl Iterator<Item = &'a mut Ingest>,
    ) {
        let DecodedMap { map, notes } = match map {
            Ok(decoded) => decoded,
            Err(reason) => {
                warn(format!("bad map (kept the previous one): {reason}"));
                cameras.for_each(|c| c.count_error("invalid_map", format!("map: {reason}")));
                return;
            }
        };
        if let Err(unusable) = MapCheck::of(&map) {
            warn(format!("unusable map (kept the previous one): {unusable}"));
            cameras.for_each(|c| c.count_error("invalid_map", format!("map: {unusable}")));
            return;
        }
        if self.current.as_deref().is_some_and(|m| m.frame_id == map.frame_id && m.points == map.points) {
            // `map_qos: auto` reads the map twice from a latched publisher.
            return;
        }
        let from = match &sender {
            MapSender::File => "the map file".to_string(),
            MapSender::Publisher(gid) => format!("publisher {gid}"),
        };
        info(format!("map received: {} points in frame {:?} from {from}", map.points.len(), map.frame_id));
        let cameras: Vec<&mut Ingest> = cameras.collect();
        if let (Some(MapSender::Publisher(before)), MapSender::Publisher(now)) = (&self.sender, &sender) {
            if before != now {
                let detail = format!("a map from publisher {now} replaces the one from {before}");
                warn(detail.clone());
                cameras.iter().for_each(|c| c.count_error("map_publisher_changed", detail.clone()));
            }
        }
        for note in &notes {
            warn(format!("map: {note}"));
        }
        let map = Arc::new(map);
        self.swap.new_map(Arc::clone(&map), self.settings, |index, took| {
            info(format!("map indexed: {} points in {:.0} ms", index.len(), took.as_secs_f64() * 1e3));
        });
        for camera in cameras {
            camera.set_map(Arc::clone(&map), &notes);
        }
        self.current = Some(map);
        self.sender = Some(sender);
    }
}

/// Farther than this from the map frame's origin no point of a real map lies (Earth's diameter
/// is 1.3·10⁷ m): coordinates beyond it are bytes that are not a map.
const MAX_PLAUSIBLE_COORDINATE_M: f32 = 1.0e7;
/// A map whose points all fit in a box this small is not a map of a place (a cloud of garbage
/// read as tiny numbers, or one point repeated).
const MIN_EXTENT_M: f32 = 1.0e-3;

/// Why a decoded map cannot replace the one held.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MapCheck {
    #[error("no usable point")]
    Empty,
    #[error("{implausible} of {points} points lie beyond {MAX_PLAUSIBLE_COORDINATE_M:e} m of the origin")]
    Implausible { implausible: usize, points: usize },
    #[error("its {points} points fit in a box {extent_m:e} m across")]
    Speck { points: usize, extent_m: f32 },
}

impl MapCheck {
    /// Whether `map` is usable: some points, most of them at plausible coordinates, spread over
    /// more than a speck.
    pub fn of(map: &MapCloud) -> Result<(), MapCheck> {
        let points = map.points.len();
        if points == 0 {
            return Err(MapCheck::Empty);
        }
        let plausible = |p: &&nalgebra::Point3<f32>| p.iter().all(|c| c.abs() <= MAX_PLAUSIBLE_COORDINATE_M);
        let implausible = points - map.points.iter().filter(plausible).count();
        if 2 * implausible > points {
            return Err(MapCheck::Implausible { implausible, points });
        }
        let (mut lo, mut hi) = (nalgebra::Vector3::repeat(f32::INFINITY), nalgebra::Vector3::repeat(f32::NEG_INFINITY));
        for p in map.points.iter().filter(plausible) {
            lo = lo.inf(&p.coords);
            hi = hi.sup(&p.coords);
        }
        let extent_m = (hi - lo).norm();
        if !(extent_m >= MIN_EXTENT_M) {
            return Err(MapCheck::Speck { points, extent_m });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Point3;

    use super::*;

    fn cloud(points: Vec<Point3<f32>>) -> MapCloud {
        MapCloud { frame_id: "map".into(), points }
    }

    fn room(n: usize) -> Vec<Point3<f32>> {
        (0..n).map(|i| Point3::new((i % 10) as f32 * 0.5, (i / 10 % 10) as f32 * 0.5, (i / 100) as f32 * 0.3)).collect()
    }

    /// A map that is not a map never replaces the good one (#38): none left after the limits
    /// (0 points, all NaN), bytes read as coordinates (most far beyond the Earth), or a speck.
    #[test]
    fn a_map_that_is_not_a_map_is_refused() {
        assert_eq!(MapCheck::of(&cloud(room(500))), Ok(()));
        assert_eq!(MapCheck::of(&cloud(vec![])), Err(MapCheck::Empty));
        let mut garbage = room(100);
        garbage.extend((0..300).map(|i| Point3::new(3.0e30 * i as f32, -1.0e12, 7.0)));
        assert!(matches!(MapCheck::of(&cloud(garbage)), Err(MapCheck::Implausible { implausible: 300, points: 400 })));
        let speck: Vec<_> = (0..200).map(|i| Point3::new(1.0e-30 * i as f32, 0.0, 2.0e-31)).collect();
        assert!(matches!(MapCheck::of(&cloud(speck)), Err(MapCheck::Speck { points: 200, .. })));
        // A few stray points do not make a map unusable.
        let mut stray = room(500);
        stray.push(Point3::new(1.0e20, 0.0, 0.0));
        assert_eq!(MapCheck::of(&cloud(stray)), Ok(()));
    }

    /// The inbox keeps the map it had when an unusable one comes, and takes the next good one.
    #[test]
    fn an_unusable_map_leaves_the_held_one_in_place() {
        let swap = Arc::new(MapSwap::default());
        let mut inbox = MapInbox::new(Arc::clone(&swap), IndexSettings::default());
        let decoded = |points| Ok(DecodedMap { map: cloud(points), notes: Vec::new() });
        inbox.on_map(decoded(room(300)), MapSender::File, std::iter::empty());
        assert_eq!(inbox.current.as_ref().map(|m| m.points.len()), Some(300));
        inbox.on_map(decoded(vec![]), MapSender::File, std::iter::empty());
        let far = vec![Point3::new(f32::MAX, f32::MAX, 1.0); 50];
        inbox.on_map(decoded(far), MapSender::File, std::iter::empty());
        assert_eq!(inbox.current.as_ref().map(|m| m.points.len()), Some(300), "the good map stays");
        inbox.on_map(decoded(room(400)), MapSender::File, std::iter::empty());
        assert_eq!(inbox.current.as_ref().map(|m| m.points.len()), Some(400), "a good map replaces it");
    }

    /// A map from another publisher than the held map's is counted (#37); the file's, the
    /// first publisher's and the same publisher's again are not.
    #[test]
    fn a_map_from_another_publisher_is_counted() {
        use crate::node::diagnostics::Stats;
        use crate::node::ingest::{Ingest, IngestRules};
        use crate::node::queue::DropOldestQueue;
        let rules = IngestRules {
            expected: Vec::new(),
            stamp_tolerance_ns: 0,
            frame_timeout: std::time::Duration::from_millis(100),
            require_map: true,
            limits: Default::default(),
            pixels: Default::default(),
        };
        let stats = Arc::new(std::sync::Mutex::new(Stats::default()));
        let mut camera = Ingest::new(rules, Arc::new(DropOldestQueue::new(2)), Arc::clone(&stats));
        let mut inbox = MapInbox::new(Arc::new(MapSwap::default()), IndexSettings::default());
        let publisher = |gid: &str| MapSender::Publisher(gid.into());
        for (points, sender) in
            [(300, MapSender::File), (310, publisher("a")), (320, publisher("a")), (330, publisher("b"))]
        {
            let decoded = Ok(DecodedMap { map: cloud(room(points)), notes: Vec::new() });
            inbox.on_map(decoded, sender, std::iter::once(&mut camera));
        }
        assert_eq!(inbox.current.as_ref().map(|m| m.points.len()), Some(330), "the map is taken");
        assert_eq!(stats.lock().unwrap().error_count("map_publisher_changed"), 1);
    }
}
