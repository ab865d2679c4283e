//! `[playback]`: what the service plays.

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::read::{Table, Walker, span_of};

/// `[playback]`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlaybackConfig {
    /// What to play: one source (`compend play --help` lists the spellings) or a playlist,
    /// with `repeat`.
    pub source: crate::source::Playlist,
    /// Play the source as soon as a verified model is installed (at start and after each
    /// calibration).
    pub autoplay: bool,
    /// The folders whose files a `play` request may name (images, folders, films, raw files
    /// and FIFOs) [default: STATE/media]. The configured `source` is not limited to them.
    pub media: Vec<PathBuf>,
}

impl PlaybackConfig {
    /// The colour bars, played as soon as a model is installed; media under `state`/media.
    pub fn defaults(state: &Path) -> Self {
        PlaybackConfig {
            source: crate::source::Playlist::single("pattern:bars"),
            autoplay: true,
            media: vec![state.join("media")],
        }
    }

    /// The section, with the state directory `state` for the default media folder.
    pub(super) fn read<'t>(w: &mut Walker<'t>, t: &mut Table<'t>, state: &Path) -> Self {
        let d = Self::defaults(state);
        let items = playlist(w, t);
        let repeat = w.get(t, "repeat").unwrap_or(true);
        PlaybackConfig {
            source: match items {
                Some(items) if items.len() > 1 || items[0].loops != 1 => {
                    crate::source::Playlist { items, repeat }
                }
                Some(mut items) => crate::source::Playlist {
                    items: vec![items.remove(0)],
                    repeat: false,
                },
                None => d.source,
            },
            autoplay: w.get(t, "autoplay").unwrap_or(d.autoplay),
            media: w.get(t, "media").unwrap_or(d.media),
        }
    }
}

/// `[playback] source`: a source's spelling, or a list of items, each a spelling or a
/// table `{ src = "...", loop = N, duration_s = S }`. `None` when absent or wrong
/// (recorded, each wrong item at its line).
fn playlist<'t>(w: &mut Walker<'t>, t: &mut Table<'t>) -> Option<Vec<crate::source::PlaylistItem>> {
    use crate::source::{PlaylistItem, SourceSpec};
    let span = span_of(t, "source");
    let value: serde_json::Value = w.get(t, "source")?;
    let mut errors = Vec::new();
    let mut item = |i: Option<usize>, v: &serde_json::Value| -> Option<PlaylistItem> {
        let at = i.map_or(String::new(), |i| format!(" item {}", i + 1));
        let mut it = match v {
            serde_json::Value::String(s) => PlaylistItem::once(s.clone()),
            serde_json::Value::Object(o) => {
                if let Some(k) = o
                    .keys()
                    .find(|k| !["src", "loop", "duration_s"].contains(&k.as_str()))
                {
                    errors.push(format!(
                        "[playback] source{at}: unknown key `{k}` (known: src, loop, \
                         duration_s)"
                    ));
                    return None;
                }
                let Some(src) = o.get("src").and_then(|s| s.as_str()) else {
                    errors.push(format!(
                        "[playback] source{at}: needs `src`, the source's spelling"
                    ));
                    return None;
                };
                let loops = match o.get("loop") {
                    None => 1,
                    Some(l) => match l.as_u64().filter(|&n| n <= u32::MAX as u64) {
                        Some(n) => n as u32,
                        None => {
                            errors.push(format!(
                                "[playback] source{at}: loop must be a whole number of \
                                 passes (0: until the operator moves on), got {l}"
                            ));
                            return None;
                        }
                    },
                };
                let duration_s = match o.get("duration_s") {
                    None => None,
                    Some(d) => match d.as_f64().filter(|d| d.is_finite() && *d > 0.0) {
                        Some(d) => Some(d),
                        None => {
                            errors.push(format!(
                                "[playback] source{at}: duration_s must be a positive \
                                 number of seconds, got {d}"
                            ));
                            return None;
                        }
                    },
                };
                PlaylistItem {
                    source: src.to_string(),
                    loops,
                    duration_s,
                }
            }
            other => {
                errors.push(format!(
                    "[playback] source{at}: expected a source's spelling or a table with \
                     src, got {other}"
                ));
                return None;
            }
        };
        if let Err(e) = SourceSpec::parse(&it.source) {
            errors.push(format!("[playback] source{at}: {e}"));
            return None;
        }
        it.source = it.source.trim().to_string();
        Some(it)
    };
    let items: Vec<Option<PlaylistItem>> = match &value {
        serde_json::Value::Array(list) if list.is_empty() => {
            errors.push("[playback] source: an empty list; give at least one item".into());
            Vec::new()
        }
        serde_json::Value::Array(list) => list
            .iter()
            .enumerate()
            .map(|(i, v)| item(Some(i), v))
            .collect(),
        v => vec![item(None, v)],
    };
    let ok = errors.is_empty();
    for e in errors {
        w.error(span.clone(), e);
    }
    ok.then(|| items.into_iter().flatten().collect())
}
