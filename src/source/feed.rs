//! A source on its own thread: frames are decoded there and handed to the render loop through a
//! one-frame mailbox, so the render loop never waits for a decoder.
//!
//! - [`FeedMode::Latest`] (live playback): a new frame replaces one the render loop has not taken
//!   yet; the replaced frame is dropped and counted ([`FeedStats::dropped`]). When the source is
//!   slower than the display the render loop finds nothing new and holds the last frame.
//! - [`FeedMode::Queue`] (offline rendering, tests): the source thread waits until the render loop
//!   took the previous frame; nothing is dropped, and the source is paced by the display.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use super::{Next, VideoSource};
use crate::error::{Error, Result};
use crate::playback::ContentFrame;

/// How the mailbox hands frames over (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FeedMode {
    /// Live: a newer frame replaces one not yet taken (`--pace display`).
    Latest,
    /// Offline: every frame is taken once, the source waits (`--pace source`).
    Queue,
}

/// Counts kept by the feed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct FeedStats {
    /// Frames the source delivered.
    pub received: u64,
    /// Frames replaced in the mailbox before the render loop took them (source faster than the
    /// display, or the pipeline late).
    pub dropped: u64,
}

/// What the mailbox holds for the render loop.
#[derive(Debug)]
pub enum Poll {
    /// A frame not seen before; `seq` counts the source's frames from 1; `at` is when the
    /// source delivered it (the frame's wait in the mailbox is part of the picture's latency).
    Frame {
        seq: u64,
        frame: ContentFrame,
        at: Instant,
    },
    /// Nothing new yet: hold the last frame.
    Nothing,
    /// The source ended and every frame was taken.
    Ended,
}

#[derive(Default)]
struct Slot {
    frame: Option<(u64, ContentFrame, Instant)>,
    stats: FeedStats,
    ended: bool,
    error: Option<Error>,
    stop: bool,
    /// The source's thread has returned.
    finished: bool,
}

struct Shared {
    slot: Mutex<Slot>,
    changed: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Slot> {
        self.slot.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A running source.
pub struct Feed {
    shared: Arc<Shared>,
    describe: String,
    ends_playback: bool,
    mode: FeedMode,
    control: Option<crate::media::Control>,
}

impl Feed {
    /// Starts `source` on a thread.
    pub fn spawn(mut source: Box<dyn VideoSource>, mode: FeedMode) -> Result<Self> {
        let shared = Arc::new(Shared {
            slot: Mutex::new(Slot::default()),
            changed: Condvar::new(),
        });
        source.set_live(mode == FeedMode::Latest);
        let describe = source.describe();
        let ends_playback = source.ends_playback();
        let control = source.control();
        let theirs = shared.clone();
        std::thread::Builder::new()
            .name("compend-source".into())
            .spawn(move || {
                run(source.as_mut(), &theirs, mode);
                // The source is dropped (a file, a device closed) before the feed hears of it.
                drop(source);
                theirs.lock().finished = true;
                theirs.changed.notify_all();
            })
            .map_err(|e| Error::Failed(format!("cannot start the source thread: {e}")))?;
        Ok(Self {
            shared,
            describe,
            ends_playback,
            mode,
            control,
        })
    }

    /// The media source's handle (pause, resume, seek, counts), for media sources.
    pub fn control(&self) -> Option<&crate::media::Control> {
        self.control.as_ref()
    }

    /// How frames are handed over: newest first (live) or every one (offline).
    pub fn mode(&self) -> FeedMode {
        self.mode
    }

    pub fn describe(&self) -> &str {
        &self.describe
    }

    /// Whether playback ends with the source (streams) or holds its last frame (stills).
    pub fn ends_playback(&self) -> bool {
        self.ends_playback
    }

    /// The newest untaken frame, without waiting. A source error is returned once every frame
    /// before it was taken.
    pub fn poll(&self) -> Result<Poll> {
        let mut slot = self.shared.lock();
        take(&mut slot, &self.shared.changed)
    }

    /// Like [`Feed::poll`], but waits up to `timeout` for something new.
    pub fn wait(&self, timeout: Duration) -> Result<Poll> {
        let deadline = Instant::now() + timeout;
        let mut slot = self.shared.lock();
        loop {
            if slot.frame.is_some() || slot.ended || slot.error.is_some() {
                return take(&mut slot, &self.shared.changed);
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(Poll::Nothing);
            }
            slot = self
                .shared
                .changed
                .wait_timeout(slot, deadline - now)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }

    pub fn stats(&self) -> FeedStats {
        self.shared.lock().stats
    }
}

fn take(slot: &mut Slot, changed: &Condvar) -> Result<Poll> {
    if let Some((seq, frame, at)) = slot.frame.take() {
        changed.notify_all();
        return Ok(Poll::Frame { seq, frame, at });
    }
    if let Some(e) = slot.error.take() {
        slot.ended = true;
        return Err(e);
    }
    Ok(if slot.ended {
        Poll::Ended
    } else {
        Poll::Nothing
    })
}

/// How long a feed being dropped waits for its thread to end.
const STOP_WAIT: Duration = Duration::from_secs(1);

impl Drop for Feed {
    fn drop(&mut self) {
        // The thread notices the stop at its next frame, or within a raw source's poll: it is
        // waited for (a little), so the next source on the same FIFO or device has it to
        // itself and no thread is left behind. A source stuck elsewhere is left to end alone.
        let deadline = Instant::now() + STOP_WAIT;
        let mut slot = self.shared.lock();
        slot.stop = true;
        self.shared.changed.notify_all();
        while !slot.finished {
            let now = Instant::now();
            if now >= deadline {
                tracing::debug!(
                    "{}: its thread did not stop within {STOP_WAIT:?}",
                    self.describe
                );
                return;
            }
            slot = self
                .shared
                .changed
                .wait_timeout(slot, deadline - now)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }
}

fn run(source: &mut dyn VideoSource, shared: &Shared, mode: FeedMode) {
    // A source stopped while it waited here (a FIFO no one wrote into yet) reads nothing: a
    // later source on the same FIFO has the stream to itself.
    let prepared = source.prepare();
    {
        let mut slot = shared.lock();
        if slot.stop {
            return;
        }
        if let Err(e) = prepared {
            slot.error = Some(e);
            shared.changed.notify_all();
            return;
        }
    }
    let mut due = Instant::now();
    loop {
        let next = source.next();
        let mut slot = shared.lock();
        if slot.stop {
            return;
        }
        let wait = match next {
            Ok(Next::Frame { frame, wait }) => {
                if mode == FeedMode::Queue {
                    while slot.frame.is_some() && !slot.stop {
                        slot = shared.changed.wait(slot).unwrap_or_else(|e| e.into_inner());
                    }
                    if slot.stop {
                        return;
                    }
                }
                slot.stats.received += 1;
                if slot.frame.is_some() {
                    slot.stats.dropped += 1;
                }
                slot.frame = Some((slot.stats.received, frame, Instant::now()));
                shared.changed.notify_all();
                wait
            }
            Ok(Next::Idle) => {
                due = Instant::now();
                continue;
            }
            Ok(Next::End) => {
                slot.ended = true;
                shared.changed.notify_all();
                return;
            }
            Err(e) => {
                slot.error = Some(e);
                shared.changed.notify_all();
                return;
            }
        };
        // Paced sources: sleep until the next frame is due (deadline-based, no drift), waking
        // early to stop.
        if let Some(period) = wait {
            due += period;
            loop {
                let now = Instant::now();
                if slot.stop {
                    return;
                }
                if now >= due {
                    break;
                }
                slot = shared
                    .changed
                    .wait_timeout(slot, due - now)
                    .unwrap_or_else(|e| e.into_inner())
                    .0;
            }
            // Far behind (e.g. the machine stalled): restart the schedule instead of bursting.
            if Instant::now() > due + period * 4 {
                due = Instant::now();
            }
        } else {
            due = Instant::now();
        }
    }
}
