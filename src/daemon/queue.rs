//! The triggers waiting for the relocalisation thread: bounded, and never losing one. Up to the
//! capacity every trigger waits on its own; beyond it, a trigger joins the newest waiting trigger of its
//! kind, whose burst then answers both, instead of being refused. A kind with nothing waiting always
//! gets in, so a storm from every input at once holds at most capacity + one trigger per kind.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use super::context::TriggerContext;
use crate::protocol::message::TriggerKind;

/// How often a waiting relocalisation thread looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(100);

/// A request to relocalise.
#[derive(Clone, Debug, PartialEq)]
pub struct TriggerEvent {
    /// Unique per run, from 1.
    pub id: u64,
    /// What happened.
    pub kind: TriggerKind,
    /// Detail for the message.
    pub reason: Option<String>,
    /// The head yaw the frames will be taken with, radians, if the trigger knows it.
    pub head_yaw: Option<f64>,
    /// What it brings to its burst's priors.
    pub context: TriggerContext,
    /// When it arrived.
    pub at: Instant,
    /// When it arrived, Unix seconds.
    pub t: f64,
}

/// Where a trigger went.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Queued {
    /// It waits for a burst of its own (shared with whatever else waits then).
    Waiting,
    /// The queue was full: the burst of waiting trigger `id`, of the same kind, answers it.
    Joined(u64),
}

/// Triggers in arrival order.
#[derive(Debug)]
pub struct TriggerQueue {
    waiting: Mutex<VecDeque<TriggerEvent>>,
    ready: Condvar,
    capacity: usize,
}

impl TriggerQueue {
    /// A queue where `capacity` triggers wait on their own.
    pub fn new(capacity: usize) -> Self {
        Self { waiting: Mutex::new(VecDeque::new()), ready: Condvar::new(), capacity }
    }

    /// Adds `event`, or joins it to the newest waiting trigger of its kind when the queue is full.
    pub fn push(&self, event: TriggerEvent) -> Queued {
        let mut waiting = self.lock();
        if waiting.len() >= self.capacity {
            if let Some(newest) = waiting.iter().rev().find(|waiting| waiting.kind == event.kind) {
                return Queued::Joined(newest.id);
            }
        }
        waiting.push_back(event);
        self.ready.notify_one();
        Queued::Waiting
    }

    /// The oldest waiting trigger, waiting for one to arrive; `None` once `stop` is set.
    pub fn next(&self, stop: &AtomicBool) -> Option<TriggerEvent> {
        let mut waiting = self.lock();
        loop {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            if let Some(event) = waiting.pop_front() {
                return Some(event);
            }
            waiting = match self.ready.wait_timeout(waiting, STOP_POLL) {
                Ok((guard, _)) => guard,
                Err(poisoned) => poisoned.into_inner().0,
            };
        }
    }

    /// Every trigger waiting now, oldest first.
    pub fn drain(&self) -> Vec<TriggerEvent> {
        self.lock().drain(..).collect()
    }

    fn lock(&self) -> MutexGuard<'_, VecDeque<TriggerEvent>> {
        self.waiting.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use super::*;
    use crate::protocol::message::TriggerKind;

    fn event(id: u64, kind: TriggerKind) -> TriggerEvent {
        TriggerEvent {
            id,
            kind,
            reason: None,
            head_yaw: None,
            context: TriggerContext::default(),
            at: Instant::now(),
            t: 0.0,
        }
    }

    #[test]
    fn beyond_the_capacity_triggers_join_the_newest_of_their_kind() {
        let queue = TriggerQueue::new(2);
        assert_eq!(queue.push(event(1, TriggerKind::Request)), Queued::Waiting);
        assert_eq!(queue.push(event(2, TriggerKind::Request)), Queued::Waiting);
        assert_eq!(queue.push(event(3, TriggerKind::Request)), Queued::Joined(2));
        // A kind with nothing waiting still gets in: a fall is never folded into a request.
        assert_eq!(queue.push(event(4, TriggerKind::Fall)), Queued::Waiting);
        assert_eq!(queue.push(event(5, TriggerKind::Fall)), Queued::Joined(4));
        let stop = AtomicBool::new(false);
        assert_eq!(queue.next(&stop).map(|event| event.id), Some(1));
        assert_eq!(queue.drain().iter().map(|event| event.id).collect::<Vec<_>>(), [2, 4]);
        assert_eq!(queue.push(event(6, TriggerKind::Request)), Queued::Waiting);
    }

    #[test]
    fn a_stop_ends_the_wait() {
        let queue = TriggerQueue::new(2);
        let stop = AtomicBool::new(true);
        assert!(queue.next(&stop).is_none());
    }
}
