//! The log lines of a link's outages (runs of missed requests).
//!
//! Every outage that matters is logged, but not every blip: on a VM that misses a few requests
//! a second, one line per outage would be thousands of lines in a minute. So an outage is
//! logged one by one (when it starts and when the controller answers again) only if none was
//! logged in the second before; the others are counted and summed up in one line once a
//! second. An outage that lasts (a dead or stuck controller) is logged as soon as it reaches
//! [`LONG_OUTAGE`] whatever came before. Lines are only formatted when something goes wrong, so
//! a link whose controller answers allocates nothing here.

use std::time::{Duration, Instant};

/// Outages at least this long are logged however many were logged just before.
pub const LONG_OUTAGE: Duration = Duration::from_millis(100);

/// At most one outage is logged one by one per this interval.
const QUIET: Duration = Duration::from_secs(1);

/// Outages and other events of a link, as lines to print.
#[derive(Debug, Default)]
pub struct OutageLog {
    /// Consecutive misses so far (0 while the controller answers).
    streak: u64,
    /// Whether the current outage was logged.
    logged: bool,
    /// The first request of the current outage and when it was missed.
    start: Option<(u64, Instant)>,
    /// No outage is logged one by one before this time.
    quiet_until: Option<Instant>,
    /// Outages (and their missed requests) since the last line, counted instead of logged.
    quiet: (u64, u64),
    lines: Vec<String>,
}

impl OutageLog {
    /// An empty log (no outage yet).
    pub fn new() -> Self {
        Self::default()
    }

    /// The controller answered.
    pub fn answered(&mut self) {
        if self.streak == 0 {
            return;
        }
        if self.logged {
            self.lines.push(format!(
                "controller: answering again after {} missed request(s)",
                self.streak
            ));
        } else {
            self.quiet.0 += 1;
            self.quiet.1 += self.streak;
        }
        self.streak = 0;
        self.start = None;
        self.logged = false;
    }

    /// Request `seq` was missed at `now`; `why` says how (only called if the line is logged).
    pub fn missed(&mut self, seq: u64, now: Instant, why: impl FnOnce() -> String) {
        let (first, since) = *self.start.get_or_insert((seq, now));
        self.streak += 1;
        let long = now - since >= LONG_OUTAGE;
        if self.logged || !(long || self.quiet_until.is_none_or(|t| now >= t)) {
            return;
        }
        self.logged = true;
        self.quiet_until = Some(now + QUIET);
        self.sum_up_quiet();
        let why = why();
        self.lines.push(if self.streak == 1 {
            format!(
                "controller: request {seq} missed ({why}); applying the safe action (zero) until it answers"
            )
        } else {
            format!(
                "controller: requests {first} to {seq} missed (last: {why}); applying the safe action (zero) until it answers"
            )
        });
    }

    /// The end of the current outage is logged even if the outage itself was too short to be
    /// (after a restart, whose own line explains the outage).
    pub fn log_its_end(&mut self) {
        if self.streak > 0 {
            self.logged = true;
        }
    }

    /// Any other line (restarts).
    pub fn push(&mut self, line: String) {
        self.lines.push(line);
    }

    /// Lines since the last call; the count of unlogged outages once a second.
    pub fn take(&mut self, now: Instant) -> Vec<String> {
        if self.quiet.0 > 0 && self.quiet_until.is_none_or(|t| now >= t) {
            self.quiet_until = Some(now + QUIET);
            self.sum_up_quiet();
        }
        std::mem::take(&mut self.lines)
    }

    /// Every remaining line, the count of unlogged outages included (at the end of a run).
    pub fn drain(&mut self) -> Vec<String> {
        self.sum_up_quiet();
        std::mem::take(&mut self.lines)
    }

    fn sum_up_quiet(&mut self) {
        let (outages, missed) = std::mem::take(&mut self.quiet);
        if outages > 0 {
            self.lines.push(format!(
                "controller: {outages} more short outage(s), {missed} missed request(s) in all, \
                 each answered again (at most one outage a second is logged one by one)"
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(t0: Instant, ms: u64) -> Instant {
        t0 + Duration::from_millis(ms)
    }

    fn why() -> String {
        "no answer by the deadline".into()
    }

    #[test]
    fn the_first_outage_is_logged_then_blips_are_counted_once_a_second() {
        let t0 = Instant::now();
        let mut log = OutageLog::new();
        log.answered();
        assert!(log.take(t0).is_empty(), "nothing happened");
        log.missed(5, ms(t0, 0), why);
        log.missed(6, ms(t0, 1), why);
        log.answered();
        let lines = log.take(ms(t0, 2));
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(lines[0].contains("request 5 missed (no answer by the deadline)"));
        assert!(lines[1].contains("answering again after 2 missed"));
        // Two blips within the quiet second: counted, not logged.
        log.missed(20, ms(t0, 20), why);
        log.answered();
        log.missed(40, ms(t0, 40), || {
            panic!("a blip's reason is never formatted")
        });
        log.missed(41, ms(t0, 41), || {
            panic!("a blip's reason is never formatted")
        });
        log.answered();
        assert!(log.take(ms(t0, 500)).is_empty());
        let lines = log.take(ms(t0, 1000));
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(
            lines[0].contains("2 more short outage(s), 3 missed request(s)"),
            "{lines:?}"
        );
        assert!(log.take(ms(t0, 3000)).is_empty(), "summed up once");
        // After the quiet second the next outage is logged one by one again.
        log.missed(3000, ms(t0, 3000), why);
        log.answered();
        assert_eq!(log.take(ms(t0, 3001)).len(), 2);
    }

    #[test]
    fn a_long_outage_is_logged_even_right_after_another() {
        let t0 = Instant::now();
        let mut log = OutageLog::new();
        log.missed(1, t0, why);
        log.answered();
        assert_eq!(log.take(t0).len(), 2);
        // Starts in the quiet second; logged when it has lasted LONG_OUTAGE.
        for (i, t) in (10..=110).enumerate() {
            log.missed(100 + i as u64, ms(t0, t), why);
            if t < 110 {
                assert!(log.take(ms(t0, t)).is_empty(), "at {t} ms");
            }
        }
        let lines = log.take(ms(t0, 110));
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(lines[0].contains("requests 100 to 200 missed"), "{lines:?}");
        log.answered();
        let lines = log.take(ms(t0, 111));
        assert!(lines[0].contains("answering again after 101 missed"));
    }

    #[test]
    fn drain_sums_up_and_a_restart_logs_the_recovery() {
        let t0 = Instant::now();
        let mut log = OutageLog::new();
        log.missed(1, t0, why);
        log.answered();
        log.take(t0);
        log.missed(7, ms(t0, 10), why);
        log.answered();
        log.missed(9, ms(t0, 20), why);
        log.push("controller: the process exited; started it again".into());
        log.log_its_end();
        log.answered();
        let lines = log.take(ms(t0, 30));
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(lines[1].contains("answering again after 1 missed"));
        let lines = log.drain();
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(lines[0].contains("1 more short outage(s), 1 missed request(s)"));
        assert!(log.drain().is_empty());
    }
}
