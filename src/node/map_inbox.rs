//! The node's one map: whichever way it comes (the map topic, `map_path`, `~/load_map`), it is
//! taken once, indexed once on the shared [`MapSwap`], and handed to every camera's ingest (one
//! `Arc`, no copy per camera).

use std::sync::Arc;

use super::ingest::Ingest;
use super::log::{info, warn};
use crate::frame::MapCloud;
use crate::map_index::swap::MapSwap;
use crate::map_index::IndexSettings;
use crate::msgs::convert::DecodedMap;

/// The map the node localizes against, and the index every worker shares.
pub struct MapInbox {
    current: Option<Arc<MapCloud>>,
    swap: Arc<MapSwap>,
    settings: IndexSettings,
}

impl MapInbox {
    pub fn new(swap: Arc<MapSwap>, settings: IndexSettings) -> Self {
        Self { current: None, swap, settings }
    }

    /// A map (or why one was unusable) for every camera in `cameras`.
    pub fn on_map<'a>(&mut self, map: Result<DecodedMap, String>, cameras: impl Iterator<Item = &'a mut Ingest>) {
        let DecodedMap { map, notes } = match map {
            Ok(decoded) => decoded,
            Err(reason) => {
                warn(format!("bad map (kept the previous one): {reason}"));
                cameras.for_each(|c| c.count_error("invalid_map", format!("map: {reason}")));
                return;
            }
        };
        if self.current.as_deref().is_some_and(|m| m.frame_id == map.frame_id && m.points == map.points) {
            // `map_qos: auto` reads the map twice from a latched publisher.
            return;
        }
        info(format!("map received: {} points in frame {:?}", map.points.len(), map.frame_id));
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
    }
}
