//! Playlists: the service's `[playback] source` as a list of items played in order, each with a
//! number of passes (`loop`) and, for stills, how long it stays (`duration_s`); the list starts
//! again after its last item when `repeat` is on. The socket's `next` and `previous` move
//! through it ([`crate::media::Control::skip`]).
//!
//! Switching items is gapless: the next item is opened on the feed's thread while the display
//! holds the last frame of the one before, so no black frame comes between. An item that fails
//! to open or to play is skipped with a warning; the playlist fails only when every item did
//! in a row.

use std::time::{Duration, Instant};

use serde::Serialize;

use super::{AudioOut, Next, SourceSpec, VideoSource};
use crate::error::{Error, Result};
use crate::media::{Control, ItemStatus};

/// How long a still image or a slideshow stays when its item gives no `duration_s`, s.
pub const DEFAULT_STILL_S: f64 = 10.0;

/// One item of a playlist.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlaylistItem {
    /// The source, spelled as `compend play --source` takes it.
    pub source: String,
    /// Passes in a row (1: once; 0: until the operator moves on).
    #[serde(rename = "loop")]
    pub loops: u32,
    /// How long the item stays, s: a still's time on screen, or a cut of a longer film (None: a
    /// film to its end, a still for [`DEFAULT_STILL_S`]).
    pub duration_s: Option<f64>,
}

impl PlaylistItem {
    /// An item played once.
    pub fn once(source: impl Into<String>) -> Self {
        Self {
            source: source.into(),
            loops: 1,
            duration_s: None,
        }
    }
}

/// What the service plays: one source, or several in order.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Playlist {
    pub items: Vec<PlaylistItem>,
    /// After the last item, the first again.
    pub repeat: bool,
}

impl Playlist {
    /// One source, played as `compend play` plays it (no repeat: a film ends, a still holds).
    pub fn single(source: impl Into<String>) -> Self {
        Self {
            items: vec![PlaylistItem::once(source)],
            repeat: false,
        }
    }

    /// The words for messages: the source, or the playlist's first item and its length.
    pub fn describe(&self) -> String {
        match self.items.as_slice() {
            [one] if one.loops == 1 && one.duration_s.is_none() => one.source.clone(),
            [first, ..] => format!(
                "a playlist of {} item(s) from {}{}",
                self.items.len(),
                first.source,
                if self.repeat { ", repeated" } else { "" }
            ),
            [] => "an empty playlist".into(),
        }
    }

    /// Every item's spelling parsed; the first wrong one named by its place.
    pub fn parse(&self) -> Result<Vec<SourceSpec>> {
        if self.items.is_empty() {
            return Err(Error::Input("the playlist has no items".into()));
        }
        self.items
            .iter()
            .enumerate()
            .map(|(i, item)| {
                SourceSpec::parse(&item.source).map_err(|e| {
                    if self.items.len() == 1 {
                        e
                    } else {
                        Error::Input(format!("playlist item {}: {e}", i + 1))
                    }
                })
            })
            .collect()
    }

    /// The source to play: a plain source for one item played once, else a
    /// [`PlaylistSource`].
    pub fn open(&self, audio: &AudioOut) -> Result<Box<dyn VideoSource>> {
        let specs = self.parse()?;
        if let ([item], [spec]) = (self.items.as_slice(), specs.as_slice())
            && item.loops == 1
            && item.duration_s.is_none()
        {
            return super::open_with(spec, audio);
        }
        Ok(Box::new(PlaylistSource::new(
            self.clone(),
            specs,
            audio.clone(),
        )))
    }
}

/// A playlist playing.
pub struct PlaylistSource {
    list: Playlist,
    specs: Vec<SourceSpec>,
    audio: AudioOut,
    live: bool,
    control: Control,
    /// The item playing (index into `specs`) and its pass (from 1).
    index: usize,
    pass: u32,
    current: Option<Box<dyn VideoSource>>,
    /// When the current item's first frame came.
    since: Option<Instant>,
    /// The current item ended and holds its last frame (a still) until its time is up.
    holding: bool,
    /// Items that failed in a row.
    failed_in_a_row: usize,
    /// The list ended (no repeat).
    done: bool,
}

impl PlaylistSource {
    fn new(list: Playlist, specs: Vec<SourceSpec>, audio: AudioOut) -> Self {
        let control = Control::default();
        control.set_trim(audio.delay_ms);
        Self {
            list,
            specs,
            audio,
            live: true,
            control,
            index: 0,
            pass: 1,
            current: None,
            since: None,
            holding: false,
            failed_in_a_row: 0,
            done: false,
        }
    }

    fn item(&self) -> &PlaylistItem {
        &self.list.items[self.index]
    }

    /// Opens and prepares the current item, reporting it through the control.
    fn open_current(&mut self) -> Result<()> {
        let spec = &self.specs[self.index];
        let mut src: Box<dyn VideoSource> = match spec {
            SourceSpec::Media(m) => Box::new(super::media::MediaSource::with_control(
                m,
                self.audio.clone(),
                self.control.clone(),
            )?),
            other => super::open_with(other, &self.audio)?,
        };
        src.set_live(self.live);
        src.prepare()?;
        let status = ItemStatus {
            index: self.index + 1,
            count: self.specs.len(),
            source: self.item().source.clone(),
            pass: self.pass,
        };
        tracing::info!(
            "playlist: item {} of {}: {}{}",
            status.index,
            status.count,
            status.source.escape_debug(),
            if self.pass > 1 {
                format!(" (pass {})", self.pass)
            } else {
                String::new()
            }
        );
        self.control.update(|s| s.item = Some(status));
        self.current = Some(src);
        self.since = None;
        self.holding = false;
        Ok(())
    }

    /// Moves to the item `delta` places on (wrapping), from its first pass; at the end of a
    /// list without repeat (moving forward), the playlist is done.
    fn go(&mut self, delta: i64) {
        self.current = None;
        self.pass = 1;
        let n = self.specs.len() as i64;
        let to = self.index as i64 + delta;
        if delta > 0 && to >= n && !self.list.repeat {
            self.done = true;
            return;
        }
        self.index = to.rem_euclid(n) as usize;
    }

    /// The current item has played a pass: another pass, or the next item.
    fn pass_done(&mut self) {
        let loops = self.item().loops;
        if loops == 0 || self.pass < loops {
            self.pass += 1;
            self.current = None;
        } else {
            self.go(1);
        }
    }

    /// How long the current item stays, when it is timed.
    fn limit(&self) -> Option<Duration> {
        let still = matches!(
            self.specs[self.index],
            SourceSpec::Image(_) | SourceSpec::Folder { .. }
        );
        match self.item().duration_s {
            Some(s) => Some(Duration::from_secs_f64(s)),
            None if still => Some(Duration::from_secs_f64(DEFAULT_STILL_S)),
            None => None,
        }
    }
}

impl VideoSource for PlaylistSource {
    fn describe(&self) -> String {
        self.list.describe()
    }

    fn set_live(&mut self, live: bool) {
        self.live = live;
    }

    fn next(&mut self) -> Result<Next> {
        let skip = self.control.take_skip();
        if skip != 0 {
            self.done = false;
            self.go(skip);
        }
        if self.done {
            return Ok(Next::End);
        }
        if self.current.is_none()
            && let Err(e) = self.open_current()
        {
            self.failed_in_a_row += 1;
            if self.failed_in_a_row >= self.specs.len() {
                return Err(e);
            }
            tracing::warn!("playlist: skipping item {}: {e}", self.index + 1);
            self.control
                .update(|s| s.last_problem = Some(format!("item skipped: {e}")));
            self.go(1);
            return Ok(Next::Idle);
        }
        if let (Some(limit), Some(since)) = (self.limit(), self.since)
            && since.elapsed() >= limit
        {
            self.pass_done();
            return Ok(Next::Idle);
        }
        if self.holding {
            std::thread::sleep(Duration::from_millis(20));
            return Ok(Next::Idle);
        }
        let current = self.current.as_mut().expect("opened above");
        match current.next() {
            Ok(Next::Frame { frame, wait }) => {
                self.failed_in_a_row = 0;
                self.since.get_or_insert_with(Instant::now);
                // A slideshow's own period runs inside the item's time.
                Ok(Next::Frame { frame, wait })
            }
            Ok(Next::Idle) => Ok(Next::Idle),
            Ok(Next::End) if self.limit().is_some() && self.since.is_some() => {
                // A still (or a film shorter than its time): held until the time is up.
                self.holding = true;
                Ok(Next::Idle)
            }
            Ok(Next::End) => {
                self.pass_done();
                Ok(Next::Idle)
            }
            Err(e) => {
                let shown = self.since.is_some();
                self.failed_in_a_row += usize::from(!shown);
                if self.failed_in_a_row >= self.specs.len() {
                    return Err(e);
                }
                tracing::warn!("playlist: item {} stopped: {e}", self.index + 1);
                self.control
                    .update(|s| s.last_problem = Some(format!("item {}: {e}", self.index + 1)));
                self.go(1);
                Ok(Next::Idle)
            }
        }
    }

    fn ends_playback(&self) -> bool {
        true
    }

    fn control(&self) -> Option<Control> {
        Some(self.control.clone())
    }
}
