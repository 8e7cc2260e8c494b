//! A new map indexed on its own thread while the workers go on localizing against the old one.
//! One [`MapSwap`] serves every worker of the node (one per camera): a map is indexed once, and
//! each worker takes the new index between two of its frames through its own [`MapTaker`] (an
//! `Arc` swap, no stall). The old index is dropped when the last worker lets go of it: during a
//! swap the node holds two indexes, whatever the number of workers.
//!
//! Work is bounded whatever others send: one thread indexes at a time, and maps that arrive
//! meanwhile wait in a queue of one, the newest superseding the one waiting (a storm of maps at
//! 20 Hz once started a thread per map: ~200 threads and 2.4 GB, no pose for 30 s, #38).

use std::sync::mpsc::{self, Receiver, TryRecvError};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use super::{IndexSettings, MapIndex};
use crate::frame::MapCloud;

/// The node's map index, shared by its workers: the newest index built, and the maps being
/// indexed. The first map is waited for (there is nothing to localize against before it); a
/// later one is swapped in by each worker when it is ready.
#[derive(Default)]
pub struct MapSwap {
    state: Mutex<SwapState>,
    built: Condvar,
}

#[derive(Default)]
struct SwapState {
    /// The newest index built, the one every worker moves to.
    newest: Option<Numbered>,
    /// The number of the newest map started (1, 2, …).
    started: u64,
    /// Maps being indexed now.
    building: usize,
    /// Indexes built (a map superseded while it was indexed is built and not counted).
    indexed: u64,
    /// The newest map waiting for the indexing thread, if any.
    waiting: Option<Waiting>,
    /// Whether the indexing thread runs.
    indexing: bool,
    /// Maps superseded while they waited (never indexed).
    superseded: u64,
}

/// A map waiting to be indexed.
struct Waiting {
    number: u64,
    map: Arc<MapCloud>,
    settings: IndexSettings,
    on_built: Box<dyn FnOnce(&MapIndex, Duration) + Send>,
}

/// An index and the number of its map.
#[derive(Clone)]
struct Numbered {
    number: u64,
    index: Arc<MapIndex>,
}

/// One worker's view of the node's [`MapSwap`]: which index it took last.
pub struct MapTaker {
    swap: Arc<MapSwap>,
    /// The number of the map this worker took last (0: none yet).
    taken: u64,
}

impl MapSwap {
    fn lock(&self) -> MutexGuard<'_, SwapState> {
        // A panic while holding the lock leaves consistent state (every write is one assignment).
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A new map arrived: it is indexed on the indexing thread (started if it is not running),
    /// after the map it is indexing now; a map still waiting is superseded by this one (the
    /// newest map wins, and an older one finishing later is not handed out); `on_built` hears of
    /// the index and how long it took.
    pub fn new_map<F>(self: &Arc<Self>, map: Arc<MapCloud>, settings: IndexSettings, on_built: F)
    where
        F: FnOnce(&MapIndex, Duration) + Send + 'static,
    {
        let mut s = self.lock();
        s.started += 1;
        s.building += 1;
        let waiting = Waiting { number: s.started, map, settings, on_built: Box::new(on_built) };
        if s.waiting.replace(waiting).is_some() {
            s.building -= 1;
            s.superseded += 1;
        }
        if std::mem::replace(&mut s.indexing, true) {
            return;
        }
        drop(s);
        let swap = Arc::clone(self);
        std::thread::spawn(move || swap.index_waiting());
    }

    /// The indexing thread: the waiting map, then the one that came meanwhile, until none waits.
    fn index_waiting(self: Arc<Self>) {
        loop {
            let Waiting { number, map, settings, on_built } = {
                let mut s = self.lock();
                match s.waiting.take() {
                    Some(waiting) => waiting,
                    None => {
                        s.indexing = false;
                        return;
                    }
                }
            };
            let started = Instant::now();
            let built = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                MapIndex::build(map.points.clone(), &settings)
            }));
            drop(map);
            let index = built.ok().map(Arc::new);
            if let Some(index) = &index {
                on_built(index, started.elapsed());
            }
            // Kept here only for a map searched per voxel, whose trees and cells this thread goes
            // on building.
            let keep = index.as_ref().filter(|i| i.searches_per_voxel()).map(Arc::clone);
            self.finished(number, index);
            if let Some(index) = keep {
                // The frames go on meanwhile; the per-voxel trees and cells their searches would
                // build are built here instead, until no one else holds the index any more or a
                // newer map waits.
                index.prepare_searches_while(|| Arc::strong_count(&index) > 1 && self.lock().waiting.is_none());
            }
        }
    }

    /// The build of map `number` ended (`None`: it panicked).
    fn finished(&self, number: u64, index: Option<Arc<MapIndex>>) {
        let mut s = self.lock();
        s.building = s.building.saturating_sub(1);
        if let Some(index) = index {
            s.indexed += 1;
            if s.newest.as_ref().is_none_or(|n| n.number < number) {
                s.newest = Some(Numbered { number, index });
            }
        }
        drop(s);
        self.built.notify_all();
    }

    /// A worker's hand-over point (it has taken nothing yet).
    pub fn taker(self: &Arc<Self>) -> MapTaker {
        MapTaker { swap: Arc::clone(self), taken: 0 }
    }

    /// Maps superseded by a newer one before they were indexed.
    pub fn superseded(&self) -> u64 {
        self.lock().superseded
    }

    /// Indexes built so far.
    pub fn indexed(&self) -> u64 {
        self.lock().indexed
    }
}

impl MapTaker {
    /// The index this worker localizes against from now on, when it changed since it last took
    /// one. Blocks only while the worker has none and a map is being indexed (its first map).
    pub fn take_ready(&mut self) -> Option<Arc<MapIndex>> {
        let mut s = self.swap.lock();
        while self.taken == 0 && s.newest.is_none() && s.building > 0 {
            s = self.swap.built.wait(s).unwrap_or_else(|p| p.into_inner());
        }
        let newest = s.newest.as_ref().filter(|n| n.number > self.taken)?;
        self.taken = newest.number;
        Some(Arc::clone(&newest.index))
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
            if index.searches_per_voxel() {
                index.prepare_searches_while(|| Arc::strong_count(&index) > 1);
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

#[cfg(test)]
mod tests {
    use std::sync::Weak;

    use nalgebra::Point3;

    use super::*;

    fn map(n: usize) -> Arc<MapCloud> {
        let points = (0..n).map(|i| Point3::new((i % 17) as f32 * 0.1, (i / 17) as f32 * 0.1, 1.0)).collect();
        Arc::new(MapCloud { frame_id: "map".into(), points })
    }

    /// Waits (bounded) until the swap has built `n` indexes.
    fn wait_indexed(swap: &MapSwap, n: u64) {
        let end = Instant::now() + std::time::Duration::from_secs(30);
        while swap.indexed() < n {
            assert!(Instant::now() < end, "the map was not indexed");
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
    }

    #[test]
    fn every_worker_takes_each_new_index_once_and_the_old_one_goes_with_the_last() {
        let swap = Arc::new(MapSwap::default());
        let (mut first, mut second) = (swap.taker(), swap.taker());
        assert!(first.take_ready().is_none(), "nothing to take, nothing being indexed: no wait");
        swap.new_map(map(500), IndexSettings::default(), |_, _| {});
        // A worker's first map is waited for.
        let held_first = first.take_ready().expect("the first map");
        let held_second = second.take_ready().expect("the first map, for the other worker too");
        assert!(Arc::ptr_eq(&held_first, &held_second), "one index for both workers");
        assert_eq!(held_first.len(), 500);
        assert!(first.take_ready().is_none() && second.take_ready().is_none(), "taken once each");
        let old: Weak<MapIndex> = Arc::downgrade(&held_first);

        swap.new_map(map(700), IndexSettings::default(), |_, _| {});
        wait_indexed(&swap, 2);
        assert_eq!(swap.indexed(), 2);
        let new_first = first.take_ready().expect("the new index");
        assert_eq!(new_first.len(), 700);
        drop(held_first);
        assert!(old.upgrade().is_some(), "the second worker still localizes against the old index");
        let new_second = second.take_ready().expect("the new index, for the other worker too");
        assert!(Arc::ptr_eq(&new_first, &new_second));
        drop(held_second);
        assert!(old.upgrade().is_none(), "the old index is dropped when the last worker lets go");
        // A worker that starts late (a fresh localizer) takes the newest.
        assert!(Arc::ptr_eq(&swap.taker().take_ready().expect("the newest"), &new_first));
    }

    /// A storm of maps (#38) starts one indexing thread, not one a map: the maps that arrive
    /// while one is indexed wait in a queue of one, each superseding the last, and the newest
    /// is the one every worker ends on.
    #[test]
    fn a_storm_of_maps_is_indexed_one_at_a_time_and_the_newest_wins() {
        let swap = Arc::new(MapSwap::default());
        let running = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let most = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let storm = 40;
        for i in 0..storm {
            let (running, most) = (Arc::clone(&running), Arc::clone(&most));
            // Each callback runs on the indexing thread: two at once would be two threads.
            swap.new_map(map(3000 + i), IndexSettings::default(), move |_, _| {
                let now = running.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1;
                most.fetch_max(now, std::sync::atomic::Ordering::SeqCst);
                std::thread::sleep(std::time::Duration::from_millis(2));
                running.fetch_sub(1, std::sync::atomic::Ordering::SeqCst);
            });
        }
        let end = Instant::now() + std::time::Duration::from_secs(30);
        while swap.indexed() + swap.superseded() < storm as u64 {
            assert!(Instant::now() < end, "the storm was not worked off");
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        assert_eq!(most.load(std::sync::atomic::Ordering::SeqCst), 1, "one index built at a time");
        assert!(swap.superseded() > 0, "maps waiting behind one being indexed are superseded");
        let newest = swap.taker().take_ready().expect("an index");
        assert_eq!(newest.len(), 3000 + storm - 1, "the newest map wins");
        assert!(!swap.lock().indexing, "the indexing thread ends once no map waits");
    }
}
