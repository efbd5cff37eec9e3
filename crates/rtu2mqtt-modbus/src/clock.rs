//! Sub-millisecond waits for the wire's silences. Tokio timers tick in whole milliseconds and
//! round up, so sleeping for a 1.75 ms t3.5 with them alone would cost up to a millisecond more
//! on every transaction. This waits on a one-shot timerfd (a kernel high-resolution timer
//! without slack, registered with the runtime's reactor, so no thread is blocked) set to the
//! deadline itself. Where no timerfd can be had it falls back to the tokio timer and yields to
//! the runtime for the last stretch. The end of a line's t3.5, after which the next request
//! goes out, is waited for sharply: the timer expires earlier by the host's recent wake-up lag
//! and the thread watches the clock for the rest (at most 150 µs), so that the request does not
//! carry the lag of a sleeping processor's wake-up.

use std::os::fd::{AsFd, AsRawFd, RawFd};
use std::time::Duration;

use nix::sys::time::TimeSpec;
use nix::sys::timerfd::{ClockId, Expiration, TimerFd, TimerFlags, TimerSetTimeFlags};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;
use tokio::time::Instant;

/// How long before the deadline a tokio timer must end to cover its 1 ms rounding plus a little
/// scheduling slack. Code that listens with a tokio timeout before a precise deadline stops
/// listening this long before it.
pub(crate) const SPIN_WINDOW: Duration = Duration::from_micros(1500);

/// Waits until `deadline`, overshooting as little as the host allows.
///
/// Sleeps on a timerfd set to the deadline: a timerfd's expiry has no timer slack, so the
/// overshoot is the wake-up of the runtime's thread alone. Yielding to the runtime for the
/// last stretch before the deadline (a spin that looks at the reactor on every turn) shaves a
/// little off the overshoot for a system call per turn, which cost a large share of a
/// transaction's CPU time (`cargo bench --bench peer_compare`, docs/performance.md). Without a
/// timerfd the tokio timer sleeps until 1.5 ms before the deadline (its 1 ms rounding and a
/// little scheduling slack) and the rest is yielded away (`tokio::task::yield_now`), so other
/// tasks keep running even on a current_thread runtime and no thread is blocked. `cargo bench --bench timer_overshoot` compares the overshoot with
/// a plain `tokio::time::sleep_until` (docs/performance.md).
pub async fn sleep_until_precise(deadline: Instant) {
    PreciseTimer::default().sleep_until(deadline).await;
}

/// The precise wait of [`sleep_until_precise`] with one timerfd kept for every wait of its
/// owner (a master): armed again for each wait instead of created, registered with the
/// reactor, deregistered and closed each time, which saves four system calls per wait.
/// A wait dropped before its end (a `select!` that took another branch) leaves the timer armed;
/// the next wait re-arms it, and a stale expiry is told apart by the clock.
#[derive(Debug, Default)]
pub(crate) struct PreciseTimer {
    timer: Option<AsyncFd<Timer>>,
    /// No timerfd could be had: the tokio timer stands in from then on.
    unavailable: bool,
    /// How late the thread has recently woken after the timer's expiry.
    wake_lag: Duration,
    /// The deadline the timerfd is armed for, while no wait has seen it pass.
    armed_until: Option<Instant>,
}

/// The longest stretch a sharp wait spends watching the clock.
const MAX_SHARPENING: Duration = Duration::from_micros(150);

impl PreciseTimer {
    /// Waits until `deadline`, overshooting as little as the host allows (see
    /// [`sleep_until_precise`]).
    pub(crate) async fn sleep_until(&mut self, deadline: Instant) {
        let now = Instant::now();
        if deadline <= now {
            return;
        }
        let until_deadline = deadline - now;
        if self.timerfd_sleep(deadline, until_deadline).await.is_err()
            && until_deadline > SPIN_WINDOW
        {
            tokio::time::sleep_until(deadline - SPIN_WINDOW).await;
        }
        // The timerfd was armed after `now` was read: it expires at the deadline or later, and
        // this loop is left at once. Only the tokio timer's fallback yields here.
        while Instant::now() < deadline {
            tokio::task::yield_now().await;
        }
    }

    /// Waits until `deadline` and returns as close after it as the thread can: the timerfd is
    /// set to expire earlier by the host's recent wake-up lag, and the rest is spent watching
    /// the clock, without giving the thread up (at most [`MAX_SHARPENING`]).
    pub(crate) async fn sleep_until_sharp(&mut self, deadline: Instant) {
        let advance = self.wake_lag.min(MAX_SHARPENING);
        let wake_at = deadline.checked_sub(advance).unwrap_or(deadline);
        if wake_at > Instant::now() {
            self.sleep_until(wake_at).await;
            let lag = Instant::now().saturating_duration_since(wake_at);
            // A running average of the lag: about half the waits wake before their deadline
            // and watch the clock for a while, the others are as late as their wake-up beyond
            // the average. Aiming at the late ones instead would buy little for the time spent
            // watching the clock on every wait.
            self.wake_lag = (self.wake_lag * 7 + lag) / 8;
        }
        while Instant::now() < deadline {
            std::hint::spin_loop();
        }
    }

    /// The timerfd, made and registered on first use (within the runtime that runs the owner).
    fn timer(&mut self) -> std::io::Result<&AsyncFd<Timer>> {
        if self.unavailable {
            return Err(std::io::Error::from(std::io::ErrorKind::Unsupported));
        }
        match self.timer {
            Some(ref timer) => Ok(timer),
            None => {
                let timer = new_timerfd().inspect_err(|_| self.unavailable = true)?;
                Ok(self.timer.insert(timer))
            }
        }
    }

    /// Sleeps until `deadline` (`duration` from now) on the one-shot CLOCK_MONOTONIC timerfd
    /// watched by the runtime's reactor. An error when no timerfd could be had (the caller
    /// falls back to the tokio timer).
    ///
    /// The expiry is not read from the timerfd: the clock says whether the deadline has come,
    /// and re-arming for the next wait resets the timer's count of expirations, after which
    /// its next expiry is a new edge the reactor reports. That spares a system call per wait.
    async fn timerfd_sleep(
        &mut self,
        deadline: Instant,
        duration: Duration,
    ) -> std::io::Result<()> {
        self.timer()?.get_ref().arm(duration)?;
        self.armed_until = Some(deadline);
        let timer = self.timer()?;
        loop {
            let mut ready = timer.readable().await?;
            // Readiness left over from a wait that was dropped, or this wait's expiry.
            ready.clear_ready();
            if Instant::now() >= deadline {
                break;
            }
        }
        self.armed_until = None;
        Ok(())
    }

    /// Disarms the timerfd if a wait dropped before its deadline (a `select!` that took
    /// another branch) left it armed: on a line that idles until its next poll, the expiry
    /// would wake the runtime's thread for nothing.
    pub(crate) fn disarm(&mut self) {
        let Some(armed_until) = self.armed_until.take() else {
            return;
        };
        if armed_until <= Instant::now() {
            // Expired already: there is nothing left to spare.
            return;
        }
        if let Some(timer) = &self.timer {
            if let Err(error) = timer.get_ref().0.unset() {
                tracing::debug!(%error, "cannot disarm the line's timer");
            }
        }
    }
}

/// A non-blocking CLOCK_MONOTONIC timerfd, as the runtime's reactor watches it.
#[derive(Debug)]
struct Timer(TimerFd);

impl AsRawFd for Timer {
    fn as_raw_fd(&self) -> RawFd {
        self.0.as_fd().as_raw_fd()
    }
}

impl Timer {
    /// Arms the timer to expire once, `duration` from now. Re-arming also resets the count of
    /// expirations not read yet, so a stale expiry of an earlier wait cannot end this one.
    fn arm(&self, duration: Duration) -> std::io::Result<()> {
        // A zero expiry would disarm the timer: at least one nanosecond.
        let duration = duration.max(Duration::from_nanos(1));
        self.0.set(
            Expiration::OneShot(TimeSpec::from_duration(duration)),
            TimerSetTimeFlags::empty(),
        )?;
        Ok(())
    }
}

/// A new timerfd registered with the runtime's reactor (needs the runtime's I/O driver, as
/// the serial port does).
fn new_timerfd() -> std::io::Result<AsyncFd<Timer>> {
    let timer = TimerFd::new(
        ClockId::CLOCK_MONOTONIC,
        TimerFlags::TFD_NONBLOCK | TimerFlags::TFD_CLOEXEC,
    )?;
    // SAFETY: the AsyncFd owns the TimerFd, so its descriptor stays open and the same until
    // the AsyncFd is dropped.
    unsafe { AsyncFd::register_with_interest(Timer(timer), Interest::READABLE) }
        .map_err(std::io::Error::from)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(flavor = "current_thread")]
    async fn never_returns_early_on_current_thread() {
        for micros in [0u64, 300, 1750, 3646] {
            let deadline = Instant::now() + Duration::from_micros(micros);
            sleep_until_precise(deadline).await;
            assert!(Instant::now() >= deadline);
        }
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_sharp_wait_never_returns_early_and_learns_the_wake_up_lag() {
        let mut timer = PreciseTimer::default();
        for round in 0..40u64 {
            let deadline = Instant::now() + Duration::from_micros(500 + round * 97 % 3000);
            timer.sleep_until_sharp(deadline).await;
            assert!(Instant::now() >= deadline);
        }
        // Every wake-up comes some time after the timer's expiry, and the timer has learnt it.
        assert!(timer.wake_lag > Duration::ZERO);
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_wait_dropped_before_its_deadline_leaves_no_expiry_once_disarmed() {
        let mut timer = PreciseTimer::default();
        let far = Instant::now() + Duration::from_millis(50);
        let dropped = tokio::time::timeout(Duration::from_millis(2), timer.sleep_until(far)).await;
        assert!(dropped.is_err(), "the wait was dropped before its end");
        let armed = |timer: &PreciseTimer| {
            let fd = timer.timer.as_ref().expect("the timerfd was made");
            fd.get_ref().0.get().expect("the timerfd answers")
        };
        assert!(
            armed(&timer).is_some(),
            "the dropped wait left the timer armed"
        );
        timer.disarm();
        assert!(armed(&timer).is_none(), "disarmed");
        // A wait that ran to its end leaves nothing to disarm, and the next wait still works.
        let deadline = Instant::now() + Duration::from_millis(1);
        timer.sleep_until(deadline).await;
        assert!(Instant::now() >= deadline);
        assert!(timer.armed_until.is_none());
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn never_returns_early_on_multi_thread() {
        let deadline = Instant::now() + Duration::from_micros(2500);
        sleep_until_precise(deadline).await;
        assert!(Instant::now() >= deadline);
    }

    #[tokio::test(flavor = "current_thread")]
    async fn a_timer_reused_after_a_dropped_wait_ends_each_wait_on_time() {
        let mut timer = PreciseTimer::default();
        // A wait dropped long before its end leaves the timerfd armed; its expiry then comes
        // while nobody waits, and stays unread.
        let far = Instant::now() + Duration::from_millis(20);
        let dropped = tokio::time::timeout(Duration::from_millis(2), timer.sleep_until(far)).await;
        assert!(
            dropped.is_err(),
            "the first wait was dropped before its end"
        );
        tokio::time::sleep_until(far + Duration::from_millis(5)).await;
        for micros in [3646u64, 500, 2000] {
            let deadline = Instant::now() + Duration::from_micros(micros);
            timer.sleep_until(deadline).await;
            let overshoot = Instant::now() - deadline;
            assert!(
                overshoot < Duration::from_millis(50),
                "{micros} µs wait ended {overshoot:?} late"
            );
        }
        assert!(timer.timer.is_some(), "one timerfd, kept for every wait");
    }

    #[tokio::test(flavor = "current_thread")]
    async fn other_tasks_run_during_the_wait() {
        let ticker = tokio::spawn(async {
            let mut ticks = 0u32;
            for _ in 0..3 {
                tokio::task::yield_now().await;
                ticks += 1;
            }
            ticks
        });
        sleep_until_precise(Instant::now() + Duration::from_millis(3)).await;
        assert!(ticker.is_finished());
        assert_eq!(ticker.await.ok(), Some(3));
    }
}
