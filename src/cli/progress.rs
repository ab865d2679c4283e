//! Progress of a long command (`calibrate`, `train`, `recalibrate --wait`): a bar on a
//! terminal; without one (a log file, journald, a pipe) plain lines on stderr
//! ([`ProgressLines`]): one when a phase starts and ends, and one at least every
//! [`LINE_PERIOD`] with n of N and the time left, even while a phase reports nothing (a fit's
//! colour solve), so a person reading the log knows it is alive.

use std::io::IsTerminal;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use compend::calibrate::progress::{LINE_PERIOD, ProgressLines};

/// Where progress goes: a bar, lines, or nowhere.
pub enum Progress {
    Bar(indicatif::ProgressBar),
    Lines(Lines),
    Hidden,
}

impl Progress {
    /// A bar when stderr is a terminal (hidden with `quiet`, e.g. `--json`), otherwise lines
    /// prefixed with `command` ("calibrate").
    pub fn new(command: &'static str, quiet: bool) -> Self {
        if std::io::stderr().is_terminal() {
            if quiet {
                Progress::Hidden
            } else {
                Progress::Bar(super::progress_bar(false))
            }
        } else {
            Progress::Lines(Lines::start(command))
        }
    }

    /// Phase `stage` has done `done` of `total`.
    pub fn update(&self, stage: &str, done: usize, total: usize) {
        match self {
            Progress::Bar(bar) => {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
                bar.set_message(stage.to_string());
            }
            Progress::Lines(lines) => lines.update(stage, done, total),
            Progress::Hidden => {}
        }
    }

    /// Clears the bar; stops the lines.
    pub fn finish(self) {
        match self {
            Progress::Bar(bar) => bar.finish_and_clear(),
            Progress::Lines(lines) => drop(lines),
            Progress::Hidden => {}
        }
    }
}

/// Progress lines on stderr, with a thread that writes one whenever [`LINE_PERIOD`] passes
/// without any.
pub struct Lines {
    state: Arc<Mutex<Option<ProgressLines>>>,
    command: &'static str,
    stop: Option<mpsc::Sender<()>>,
    ticker: Option<JoinHandle<()>>,
}

impl Lines {
    fn start(command: &'static str) -> Self {
        let state: Arc<Mutex<Option<ProgressLines>>> = Arc::new(Mutex::new(None));
        let (stop, stopped) = mpsc::channel::<()>();
        let shared = state.clone();
        let ticker = std::thread::Builder::new()
            .name("progress".into())
            .spawn(move || {
                let mut wait = LINE_PERIOD;
                loop {
                    match stopped.recv_timeout(wait) {
                        Err(RecvTimeoutError::Timeout) => {}
                        _ => return,
                    }
                    let mut guard = shared.lock().unwrap_or_else(|e| e.into_inner());
                    wait = match guard.as_mut() {
                        Some(p) => {
                            if let Some(line) = p.tick() {
                                eprintln!("{command}: {line}");
                            }
                            p.until_due().max(std::time::Duration::from_millis(100))
                        }
                        None => LINE_PERIOD,
                    };
                }
            })
            .ok();
        Lines {
            state,
            command,
            stop: Some(stop),
            ticker,
        }
    }

    fn update(&self, stage: &str, done: usize, total: usize) {
        let mut guard = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let line = match guard.as_mut() {
            Some(p) => p.update(stage, done, total),
            None => {
                let p = ProgressLines::new(stage, done, total);
                let line = p.line();
                *guard = Some(p);
                Some(line)
            }
        };
        if let Some(line) = line {
            eprintln!("{}: {line}", self.command);
        }
    }
}

impl Drop for Lines {
    fn drop(&mut self) {
        drop(self.stop.take());
        if let Some(t) = self.ticker.take() {
            let _ = t.join();
        }
    }
}
