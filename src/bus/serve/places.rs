//! The places of a served line (`max_clients`) and who holds them. A connection that has
//! completed a request keeps its place for as long as it stays. When every place is taken, a
//! new connection waits (in order of arrival, at most [`PLACE_WAIT`], at most `max_clients`
//! of them) and takes the place of the oldest connection that has completed no request (none
//! yet, or one still arriving) once that one has had [`PLACE_GRACE`] to send it: slow or
//! silent connections cannot keep a newcomer out, and a newcomer is not pushed out before
//! it could speak.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::sync::{oneshot, Notify};
use tokio::time::Instant;

/// A connection that has completed no request keeps its place this long against newcomers.
pub const PLACE_GRACE: Duration = Duration::from_secs(1);
/// A new connection waits this long for a place before it is closed.
pub const PLACE_WAIT: Duration = Duration::from_secs(5);

/// The places of one server.
#[derive(Debug)]
pub(crate) struct Places {
    max: usize,
    grace: Duration,
    wait: Duration,
    state: Mutex<State>,
    /// A place was given up.
    freed: Notify,
}

#[derive(Debug, Default)]
struct State {
    next_id: u64,
    held: Vec<Holder>,
    /// Tickets of the connections waiting for a place, in order of arrival.
    queue: VecDeque<u64>,
    /// Holders told to go whose place is not free yet.
    leaving: usize,
}

#[derive(Debug)]
struct Holder {
    id: u64,
    since: Instant,
    completed: bool,
    /// Taken when the holder is told to give its place up.
    evict: Option<oneshot::Sender<()>>,
}

/// Why a connection got no place.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum NoPlace {
    /// `max_clients` connections already wait for one.
    QueueFull,
    /// None came free within [`PLACE_WAIT`].
    TimedOut,
}

/// A connection's ticket in the queue of those waiting for a place, taken out when it stops
/// waiting however that happens.
struct InQueue<'a> {
    places: &'a Places,
    ticket: u64,
}

impl Drop for InQueue<'_> {
    fn drop(&mut self) {
        let ticket = self.ticket;
        self.places.state().queue.retain(|t| *t != ticket);
    }
}

/// A place held by a connection; given up when dropped.
#[derive(Debug)]
pub(crate) struct Place {
    places: Arc<Places>,
    id: u64,
    /// Fires when a newcomer takes the place (only before a completed request).
    pub(crate) evicted: oneshot::Receiver<()>,
}

impl Places {
    /// `max` places; [`PLACE_GRACE`] and [`PLACE_WAIT`] but in tests.
    pub(crate) fn new(max: usize, grace: Duration, wait: Duration) -> Arc<Self> {
        Arc::new(Places {
            max,
            grace,
            wait,
            state: Mutex::new(State::default()),
            freed: Notify::new(),
        })
    }

    fn state(&self) -> MutexGuard<'_, State> {
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Waits for a place; `on_evict` is called once for each connection told to give its
    /// place up for this one.
    pub(crate) async fn take(self: &Arc<Self>, on_evict: impl Fn()) -> Result<Place, NoPlace> {
        let ticket = {
            let mut state = self.state();
            if state.queue.len() >= self.max.max(1) {
                return Err(NoPlace::QueueFull);
            }
            let ticket = state.next_id;
            state.next_id += 1;
            state.queue.push_back(ticket);
            ticket
        };
        // A connection that stops waiting (shutdown) leaves the queue.
        let _in_queue = InQueue {
            places: self,
            ticket,
        };
        let deadline = Instant::now() + self.wait;
        loop {
            let freed = self.freed.notified();
            tokio::pin!(freed);
            freed.as_mut().enable();
            let now = Instant::now();
            let wake = {
                let mut state = self.state();
                let free = self.max.saturating_sub(state.held.len());
                let position = state.queue.iter().position(|t| *t == ticket);
                if position.is_some_and(|position| position < free) {
                    state.queue.retain(|t| *t != ticket);
                    let (evict, evicted) = oneshot::channel();
                    state.held.push(Holder {
                        id: ticket,
                        since: now,
                        completed: false,
                        evict: Some(evict),
                    });
                    return Ok(Place {
                        places: Arc::clone(self),
                        id: ticket,
                        evicted,
                    });
                }
                if now >= deadline {
                    state.queue.retain(|t| *t != ticket);
                    return Err(NoPlace::TimedOut);
                }
                // One place to come free for each waiting connection beyond the free ones.
                let short = state.queue.len().saturating_sub(free);
                if state.leaving < short {
                    if let Some(sender) = state.oldest_evictable(now, self.grace) {
                        state.leaving += 1;
                        let _ = sender.send(());
                        on_evict();
                    }
                }
                state
                    .held
                    .iter()
                    .filter(|holder| !holder.completed && holder.evict.is_some())
                    .map(|holder| holder.since + self.grace)
                    .min()
                    .map_or(deadline, |mature| mature.min(deadline))
            };
            tokio::select! {
                () = freed => {}
                () = tokio::time::sleep_until(wake) => {}
            }
        }
    }
}

impl State {
    /// The eviction handle of the oldest holder that has completed no request and has had
    /// its grace, taken.
    fn oldest_evictable(&mut self, now: Instant, grace: Duration) -> Option<oneshot::Sender<()>> {
        self.held
            .iter_mut()
            .filter(|holder| !holder.completed && holder.evict.is_some())
            .filter(|holder| now.saturating_duration_since(holder.since) >= grace)
            .min_by_key(|holder| holder.since)
            .and_then(|holder| holder.evict.take())
    }
}

impl Place {
    /// The connection has completed a request: it keeps its place from now on. False when a
    /// newcomer has already taken it (the connection closes without answering).
    pub(crate) fn complete(&self) -> bool {
        let mut state = self.places.state();
        match state.held.iter_mut().find(|holder| holder.id == self.id) {
            Some(holder) if holder.evict.is_some() => {
                holder.completed = true;
                true
            }
            _ => false,
        }
    }
}

impl Drop for Place {
    fn drop(&mut self) {
        {
            let mut state = self.places.state();
            if let Some(index) = state.held.iter().position(|h| h.id == self.id) {
                let holder = state.held.swap_remove(index);
                if holder.evict.is_none() {
                    state.leaving = state.leaving.saturating_sub(1);
                }
            }
        }
        self.places.freed.notify_waiters();
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use super::*;

    const GRACE: Duration = Duration::from_millis(300);
    const WAIT: Duration = Duration::from_millis(600);

    #[tokio::test]
    async fn a_newcomer_takes_the_place_of_the_oldest_connection_without_a_request() {
        let places = Places::new(2, GRACE, WAIT);
        let evictions = Arc::new(AtomicUsize::new(0));
        let count = || {
            let evictions = Arc::clone(&evictions);
            move || {
                evictions.fetch_add(1, Ordering::Relaxed);
            }
        };
        let talker = places.take(count()).await.unwrap();
        assert!(talker.complete());
        let mut silent = places.take(count()).await.unwrap();

        // Every place is taken: the newcomer waits out the silent one's grace, then has it.
        let newcomer = {
            let places = Arc::clone(&places);
            let count = count();
            tokio::spawn(async move { places.take(count).await })
        };
        tokio::task::yield_now().await;
        assert!(
            silent.evicted.try_recv().is_err(),
            "evicted within its grace"
        );
        tokio::time::timeout(WAIT, &mut silent.evicted)
            .await
            .expect("evicted once its grace is over")
            .unwrap();
        assert!(
            !silent.complete(),
            "a request after its eviction is too late"
        );
        drop(silent);
        let newcomer = newcomer.await.unwrap().unwrap();
        assert_eq!(evictions.load(Ordering::Relaxed), 1);

        // Both holders have completed a request: the next newcomer waits and gets no place.
        assert!(newcomer.complete());
        assert_eq!(places.take(count()).await.unwrap_err(), NoPlace::TimedOut);
        assert_eq!(evictions.load(Ordering::Relaxed), 1);
        drop(talker);
        assert!(places.take(count()).await.is_ok());
    }

    #[tokio::test]
    async fn waiting_connections_are_bounded() {
        let places = Places::new(1, GRACE, WAIT);
        let holder = places.take(|| {}).await.unwrap();
        assert!(holder.complete());
        let waiting = {
            let places = Arc::clone(&places);
            tokio::spawn(async move { places.take(|| {}).await.is_ok() })
        };
        while places.state().queue.is_empty() {
            tokio::task::yield_now().await;
        }
        assert_eq!(places.take(|| {}).await.unwrap_err(), NoPlace::QueueFull);
        drop(holder);
        assert!(waiting.await.unwrap());
    }
}
