//! A bounded queue between the receive side and the worker that drops the OLDEST item when
//! full: a live localizer wants the newest frame, never a backlog.

use std::collections::VecDeque;
use std::sync::Mutex;

use tokio::sync::Notify;

pub struct DropOldestQueue<T> {
    capacity: usize,
    state: Mutex<(VecDeque<T>, bool)>,
    notify: Notify,
}

impl<T> DropOldestQueue<T> {
    /// `capacity` is at least 1.
    pub fn new(capacity: usize) -> Self {
        Self { capacity: capacity.max(1), state: Mutex::new((VecDeque::new(), false)), notify: Notify::new() }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, (VecDeque<T>, bool)> {
        // A panic while holding the lock leaves a consistent deque; keep going.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Adds `item`; returns the item dropped to make room, if any. After `close`, the item
    /// itself is returned (nothing is queued).
    pub fn push(&self, item: T) -> Option<T> {
        let dropped = {
            let mut s = self.lock();
            if s.1 {
                return Some(item);
            }
            let dropped = if s.0.len() >= self.capacity { s.0.pop_front() } else { None };
            s.0.push_back(item);
            dropped
        };
        self.notify.notify_one();
        dropped
    }

    /// The oldest item; waits while empty; `None` once closed and drained.
    pub async fn pop(&self) -> Option<T> {
        loop {
            let notified = self.notify.notified();
            {
                let mut s = self.lock();
                if let Some(item) = s.0.pop_front() {
                    return Some(item);
                }
                if s.1 {
                    return None;
                }
            }
            notified.await;
        }
    }

    pub fn len(&self) -> usize {
        self.lock().0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// No more pushes; `pop` drains what is left, then returns `None`.
    pub fn close(&self) {
        self.lock().1 = true;
        self.notify.notify_waiters();
        self.notify.notify_one();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn drops_oldest_when_full_and_drains_after_close() {
        let q = DropOldestQueue::new(2);
        assert_eq!(q.push(1), None);
        assert_eq!(q.push(2), None);
        assert_eq!(q.push(3), Some(1));
        assert_eq!(q.len(), 2);
        assert_eq!(q.pop().await, Some(2));
        q.close();
        assert_eq!(q.push(4), Some(4));
        assert_eq!(q.pop().await, Some(3));
        assert_eq!(q.pop().await, None);
    }

    #[tokio::test]
    async fn pop_waits_for_a_push() {
        let q = std::sync::Arc::new(DropOldestQueue::new(1));
        let q2 = q.clone();
        let waiter = tokio::spawn(async move { q2.pop().await });
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        q.push(7);
        let got = tokio::time::timeout(std::time::Duration::from_secs(5), waiter).await;
        assert_eq!(got.ok().and_then(|r| r.ok()).flatten(), Some(7));
    }
}
