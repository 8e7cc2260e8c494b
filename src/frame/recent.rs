//! The stamps an assembler has handed out lately, to recognise late parts and repeated stamps.

use std::collections::{BTreeMap, VecDeque};

use super::{MonotonicNs, Stamp};

/// How many handed-out stamps are remembered at most.
pub const REMEMBERED_STAMPS: usize = 4096;

/// A bounded set of recently handed-out stamps: the oldest is forgotten first, past
/// [`REMEMBERED_STAMPS`] or, with a window, once it was handed out more than the window ago.
pub struct RecentStamps {
    /// Hand-out order: (stamp, when), `when` never decreasing.
    order: VecDeque<(Stamp, MonotonicNs)>,
    stamps: BTreeMap<Stamp, MonotonicNs>,
    window_ns: Option<i64>,
}

impl RecentStamps {
    /// Remembers stamps for `window_ns` of the caller's clock (`None`: until crowded out).
    pub fn new(window_ns: Option<i64>) -> Self {
        Self { order: VecDeque::new(), stamps: BTreeMap::new(), window_ns }
    }

    pub fn insert(&mut self, stamp: Stamp, now: MonotonicNs) {
        self.stamps.insert(stamp, now);
        self.order.push_back((stamp, now));
        while self.order.len() > REMEMBERED_STAMPS {
            self.forget_oldest();
        }
    }

    /// Forgets the stamps handed out more than the window before `now`.
    pub fn forget_old(&mut self, now: MonotonicNs) {
        let Some(window) = self.window_ns else { return };
        let cutoff = now.saturating_sub(window);
        while self.order.front().is_some_and(|&(_, when)| when < cutoff) {
            self.forget_oldest();
        }
    }

    fn forget_oldest(&mut self) {
        if let Some((stamp, when)) = self.order.pop_front() {
            // A stamp handed out again later keeps its newer entry.
            if self.stamps.get(&stamp) == Some(&when) {
                self.stamps.remove(&stamp);
            }
        }
    }

    pub fn contains(&self, stamp: Stamp) -> bool {
        self.stamps.contains_key(&stamp)
    }

    /// The remembered stamps in `lo..=hi`, ascending.
    pub fn range(&self, lo: Stamp, hi: Stamp) -> impl Iterator<Item = Stamp> + '_ {
        self.stamps.range(lo..=hi).map(|(s, _)| *s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forgets_by_count_and_by_window() {
        let mut r = RecentStamps::new(Some(10));
        r.insert(1, 0);
        r.insert(2, 5);
        r.forget_old(12);
        assert!(!r.contains(1) && r.contains(2));
        r.insert(1, 20);
        r.forget_old(20);
        assert_eq!(r.range(0, 9).collect::<Vec<_>>(), vec![1]);
        let mut crowded = RecentStamps::new(None);
        for s in 0..=REMEMBERED_STAMPS as i64 {
            crowded.insert(s, 0);
        }
        crowded.forget_old(i64::MAX);
        assert!(!crowded.contains(0) && crowded.contains(REMEMBERED_STAMPS as i64));
    }
}
