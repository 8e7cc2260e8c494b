//! A new map indexed on its own thread while the worker goes on localizing against the old
//! one; the worker takes the new index between two frames (an `Arc` swap, no stall).

use std::sync::mpsc::{self, Receiver, TryRecvError};
use std::sync::Arc;

use super::{IndexSettings, MapIndex, MapScale};
use crate::frame::MapCloud;

/// The worker's maps: the one frames are localized against, and a newer one being indexed.
/// The first map is waited for (there is nothing to localize against before it); a later one is
/// indexed on its own thread and swapped in between two frames when ready.
#[derive(Default)]
pub struct MapSwap {
    current: Option<IndexedCloud>,
    fresh: Option<IndexedCloud>,
    building: BackgroundIndex,
}

impl MapSwap {
    /// A new map arrived.
    pub fn new_map(&mut self, map: Arc<MapCloud>, settings: IndexSettings) {
        self.building.start(map, settings);
        if self.current.is_none() {
            self.fresh = self.building.wait();
        }
    }

    /// The index to localize against from now on, when it changed (never blocks).
    pub fn take_ready(&mut self) -> Option<Arc<MapIndex>> {
        let done = self.fresh.take().or_else(|| self.building.ready())?;
        let index = Arc::clone(&done.index);
        self.current = Some(done);
        Some(index)
    }

    /// The index frames are localized against.
    pub fn current(&self) -> Option<Arc<MapIndex>> {
        self.current.as_ref().map(|c| Arc::clone(&c.index))
    }
}

/// A map being indexed, and the index once it is built.
#[derive(Default)]
pub struct BackgroundIndex {
    pending: Option<Receiver<IndexedCloud>>,
}

/// A map and its index.
#[derive(Clone, Debug)]
pub struct IndexedCloud {
    pub map: Arc<MapCloud>,
    pub index: Arc<MapIndex>,
}

impl BackgroundIndex {
    /// Starts indexing `map` (a map still being indexed is abandoned: the newest one wins).
    pub fn start(&mut self, map: Arc<MapCloud>, settings: IndexSettings) {
        let (send, receive) = mpsc::channel();
        std::thread::spawn(move || {
            let index = Arc::new(MapIndex::build(map.points.clone(), &settings));
            // The receiver is gone when a newer map replaced this one: nothing to do.
            let _ = send.send(IndexedCloud { map, index: Arc::clone(&index) });
            if index.scale() == MapScale::Building {
                // The frames go on meanwhile; the per-voxel trees their searches would build
                // are built here instead, until no one holds the index any more.
                index.grid().build_trees_while(|| Arc::strong_count(&index) > 1);
            }
        });
        self.pending = Some(receive);
    }

    /// Whether a map is being indexed.
    pub fn is_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// The newest map's index if it is ready (never blocks).
    pub fn ready(&mut self) -> Option<IndexedCloud> {
        let receive = self.pending.as_ref()?;
        match receive.try_recv() {
            Ok(done) => {
                self.pending = None;
                Some(done)
            }
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => {
                self.pending = None;
                None
            }
        }
    }

    /// The newest map's index, waiting for it (`None` when nothing is pending or the build died).
    pub fn wait(&mut self) -> Option<IndexedCloud> {
        let receive = self.pending.take()?;
        receive.recv().ok()
    }
}
