//! Progress in words, for a log that is read later (a file, the journal) rather than a bar:
//! a line when a phase starts, a line when it ends, and a line at least every
//! [`LINE_PERIOD`] between, with n of N and the time left. The CLI prints them when stderr is
//! not a terminal; the service logs them.

use std::time::{Duration, Instant};

/// The longest a run goes without a progress line.
pub const LINE_PERIOD: Duration = Duration::from_secs(5);

/// The progress reported so far and when its last line was written.
#[derive(Debug)]
pub struct ProgressLines {
    stage: String,
    done: usize,
    total: usize,
    /// When the stage started, and when it had done its first unit (the rate counts from
    /// there, not from a slow start).
    stage_started: Instant,
    first_done: Option<(Instant, usize)>,
    last_line: Instant,
}

impl ProgressLines {
    /// Progress starting with `stage`; its line is [`ProgressLines::line`].
    pub fn new(stage: &str, done: usize, total: usize) -> Self {
        let now = Instant::now();
        Self {
            stage: stage.to_string(),
            done,
            total,
            stage_started: now,
            first_done: None,
            last_line: now,
        }
    }

    /// Records that `stage` has done `done` of `total`; returns the line to write, if one is
    /// due: a new stage, the stage's end, or [`LINE_PERIOD`] since the last line.
    pub fn update(&mut self, stage: &str, done: usize, total: usize) -> Option<String> {
        let now = Instant::now();
        if stage != self.stage {
            *self = Self::new(stage, done, total);
            return Some(self.line());
        }
        if self.first_done.is_none() && done > 0 {
            self.first_done = Some((now, done));
        }
        let finished = done >= total && self.done < total;
        (self.done, self.total) = (done, total);
        self.due(now, finished)
    }

    /// The line to write if [`LINE_PERIOD`] has passed without one (a stage that reports
    /// nothing for a while).
    pub fn tick(&mut self) -> Option<String> {
        self.due(Instant::now(), false)
    }

    fn due(&mut self, now: Instant, forced: bool) -> Option<String> {
        if forced || now.duration_since(self.last_line) >= LINE_PERIOD {
            self.last_line = now;
            Some(self.line())
        } else {
            None
        }
    }

    /// How long until a line is due without news.
    pub fn until_due(&self) -> Duration {
        LINE_PERIOD.saturating_sub(self.last_line.elapsed())
    }

    /// "captures 24/61 (4 s in this phase, about 6 s left)".
    pub fn line(&self) -> String {
        let in_stage = self.stage_started.elapsed().as_secs_f64();
        let left = self.first_done.and_then(|(at, from)| {
            let (units, secs) = (self.done.saturating_sub(from), at.elapsed().as_secs_f64());
            (units > 0 && self.total > self.done)
                .then(|| secs / units as f64 * (self.total - self.done) as f64)
        });
        let left = match left {
            Some(s) => format!(", about {s:.0} s left"),
            None if self.done >= self.total => String::new(),
            None => ", time left not known yet".to_string(),
        };
        format!(
            "{} {}/{} ({in_stage:.0} s in this phase{left})",
            self.stage, self.done, self.total
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_per_stage_and_at_its_end_none_between_within_the_period() {
        let mut p = ProgressLines::new("captures", 0, 3);
        assert!(p.line().starts_with("captures 0/3"), "{}", p.line());
        assert_eq!(p.update("captures", 1, 3), None);
        assert_eq!(p.update("captures", 2, 3), None);
        let end = p
            .update("captures", 3, 3)
            .expect("a line at the stage's end");
        assert!(end.starts_with("captures 3/3"), "{end}");
        let next = p.update("colour", 0, 1).expect("a line for a new stage");
        assert!(next.starts_with("colour 0/1"), "{next}");
        assert!(next.contains("time left not known yet"), "{next}");
        assert_eq!(p.tick(), None);
        assert!(p.until_due() <= LINE_PERIOD);
    }

    #[test]
    fn the_time_left_follows_the_rate_since_the_first_unit() {
        let mut p = ProgressLines::new("captures", 0, 100);
        p.update("captures", 1, 100);
        std::thread::sleep(Duration::from_millis(30));
        p.update("captures", 4, 100);
        let line = p.line();
        // 3 units in 30 ms or more: 96 more take 1 s or more (the host may be slow).
        let left: f64 = line
            .split("about ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no time left in {line:?}"));
        assert!((1.0..60.0).contains(&left), "{line}");
    }
}
