//! Source specifications: the `--source` spellings, parsed without touching any device.

use std::path::PathBuf;
use std::time::Duration;

use crate::error::{Error, Result};
use crate::raster::ImageSize;

/// The spellings, as `compend play --help` shows them.
pub const HELP: &str = "\
Video sources (SRC):
  PATH                     a video file, a still image (PNG or JPEG) or a folder of images
                           (slideshow), by what is there
  file:PATH                a video file (MP4, MKV, MOV, WebM, ...; any codec the installed
                           GStreamer plugins decode), with its sound
  uri:URI                  a network stream or file URI GStreamer opens: http(s)://, rtsp://,
                           srt://, udp://, file:///...; a stream that drops is reconnected
  screen:[x11][?display=:0&xid=N&fps=F]
                           another program's output: an X11 display, or one window of it by
                           its id (xwininfo); default the DISPLAY of the service, 30 fps
  screen:pipewire?node=N[&fps=F]
                           a PipeWire screen-cast stream (Wayland), by node id
  gst:PIPELINE             any GStreamer pipeline; compend appends its own sink, e.g.
                           gst:videotestsrc pattern=ball ! video/x-raw,width=1280,height=720
  image:PATH               a still image, held until playback stops
  folder:DIR[?period=S]    a slideshow of the folder's images in name order, S seconds each
                           (default 5), looping
  raw:-?size=WxH[&format=rgb24|rgba]
                           raw 8-bit frames on standard input, e.g.
                           ffmpeg -i in.mp4 -f rawvideo -pix_fmt rgb24 - | compend play ... \\
                             --source 'raw:-?size=1280x720&format=rgb24'
  raw:PATH?size=WxH[&format=..]
                           raw frames from a FIFO (or a file)
  v4l2:DEVICE[?size=WxH]   a V4L2 capture device, e.g. v4l2:/dev/video2 (YUYV, NV12, RGB3 or MJPEG)
  pattern:NAME[?size=WxH&fps=F&frames=N]
                           a generated test pattern: bars, ramp, checker, gray, moving
                           (default 1280x720 at 60 fps, endless)";

/// Pixel layout of raw frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RawFormat {
    Rgb24,
    Rgba,
}

impl RawFormat {
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            RawFormat::Rgb24 => 3,
            RawFormat::Rgba => 4,
        }
    }
}

/// Test patterns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pattern {
    /// Colour bars (white, yellow, cyan, green, magenta, red, blue, black).
    Bars,
    /// Horizontal gray ramp, 0 to 255.
    Ramp,
    /// 8×8-cell black and white checkerboard.
    Checker,
    /// Mid gray (128).
    Gray,
    /// Colour bars with a white square moving one step per frame (shows dropped frames).
    Moving,
}

pub const PATTERNS: &[&str] = &["bars", "ramp", "checker", "gray", "moving"];

/// A parsed `--source`.
#[derive(Clone, Debug, PartialEq)]
pub enum SourceSpec {
    Image(PathBuf),
    Folder {
        dir: PathBuf,
        period: Duration,
    },
    /// `path` None = standard input.
    Raw {
        path: Option<PathBuf>,
        size: ImageSize,
        format: RawFormat,
    },
    V4l2 {
        device: PathBuf,
        size: Option<ImageSize>,
    },
    Pattern {
        pattern: Pattern,
        size: ImageSize,
        fps: f64,
        frames: Option<u64>,
    },
    /// Media decoded by GStreamer ([`crate::source::media`]).
    Media(MediaSpec),
}

/// Media that GStreamer decodes.
#[derive(Clone, Debug, PartialEq)]
pub enum MediaSpec {
    /// A video file (with its sound).
    File(PathBuf),
    /// A URI GStreamer opens (network streams; reconnected when they drop).
    Uri(String),
    /// Another program's output on the screen.
    Screen(ScreenSpec),
    /// A GStreamer pipeline description, to which compend appends its sink.
    Pipeline(String),
}

/// A screen to capture.
#[derive(Clone, Debug, PartialEq)]
pub enum ScreenSpec {
    /// An X11 display (`None`: the `DISPLAY` of the process), or one window of it by id.
    X11 {
        display: Option<String>,
        xid: Option<u64>,
        fps: u32,
    },
    /// A PipeWire screen-cast node.
    PipeWire { node: String, fps: u32 },
}

/// File name endings played as video files when a bare path is given.
pub const VIDEO_EXTENSIONS: &[&str] = &[
    "mp4", "m4v", "mkv", "mov", "webm", "avi", "ts", "mts", "m2ts", "mxf", "ogv", "mpg", "mpeg",
    "flv", "wmv",
];

/// A source that cannot be parsed. The message names the source, not a flag: it reaches the
/// command line (`--source`), the configuration (`[playback] source`) and socket clients alike.
fn bad(spec: &str, why: impl std::fmt::Display) -> Error {
    Error::Input(format!(
        "source {spec:?}: {why} (the spellings: `compend play --help`)"
    ))
}

fn parse_size(spec: &str, v: &str) -> Result<ImageSize> {
    let (w, h) = v
        .split_once(['x', 'X'])
        .ok_or_else(|| bad(spec, format!("size {v:?} is not WxH")))?;
    let (w, h) = (
        w.parse::<usize>()
            .map_err(|_| bad(spec, format!("size {v:?} is not WxH")))?,
        h.parse::<usize>()
            .map_err(|_| bad(spec, format!("size {v:?} is not WxH")))?,
    );
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(bad(
            spec,
            format!("size {v:?} must be 1..16384 on each side"),
        ));
    }
    if w * h > ImageSize::MAX_PIXELS {
        return Err(bad(
            spec,
            format!("size {v:?} is more than the 8192x8192 pixels a frame may have"),
        ));
    }
    Ok(ImageSize::new(w, h))
}

/// `key=value&...` after the `?`; unknown keys are an error.
fn options<'a>(
    spec: &str,
    query: Option<&'a str>,
    known: &[&str],
) -> Result<Vec<(&'a str, &'a str)>> {
    let mut out = Vec::new();
    for kv in query
        .into_iter()
        .flat_map(|q| q.split('&'))
        .filter(|s| !s.is_empty())
    {
        let (k, v) = kv
            .split_once('=')
            .ok_or_else(|| bad(spec, format!("option {kv:?} is not key=value")))?;
        if !known.contains(&k) {
            return Err(bad(
                spec,
                format!("unknown option {k:?} (known: {})", known.join(", ")),
            ));
        }
        out.push((k, v));
    }
    Ok(out)
}

impl SourceSpec {
    /// Parses a `--source` value. A bare path is an image or a folder, decided by what is there
    /// (a missing path is an error naming it).
    pub fn parse(spec: &str) -> Result<Self> {
        let (scheme, rest) = match spec.split_once(':') {
            Some((s, r))
                if [
                    "image", "folder", "raw", "v4l2", "pattern", "file", "uri", "screen", "gst",
                ]
                .contains(&s) =>
            {
                (Some(s), r)
            }
            _ => (None, spec),
        };
        // Whole rest, queries and all: a URI and a pipeline have their own syntax.
        match scheme {
            Some("uri") => return Self::uri(spec, rest),
            Some("gst") => {
                if rest.trim().is_empty() {
                    return Err(bad(spec, "gst: needs a pipeline description"));
                }
                return Ok(Self::Media(MediaSpec::Pipeline(rest.trim().to_string())));
            }
            Some("file") => {
                if rest.is_empty() {
                    return Err(bad(spec, "file: needs a path"));
                }
                return Ok(Self::Media(MediaSpec::File(PathBuf::from(rest))));
            }
            _ => {}
        }
        let (body, query) = match rest.split_once('?') {
            Some((b, q)) => (b, Some(q)),
            None => (rest, None),
        };
        match scheme {
            None => Self::bare_path(spec),
            Some("image") => {
                options(spec, query, &[])?;
                Ok(Self::Image(PathBuf::from(body)))
            }
            Some("folder") => Self::folder(spec, body, query),
            Some("raw") => Self::raw(spec, body, query),
            Some("v4l2") => Self::v4l2(spec, body, query),
            Some("screen") => Self::screen(spec, body, query),
            _ => Self::pattern(spec, body, query),
        }
    }

    /// A bare path: a folder is a slideshow, a file with a video file's ending a video file,
    /// any other file an image.
    fn bare_path(spec: &str) -> Result<Self> {
        let path = PathBuf::from(spec);
        let video = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| VIDEO_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
        if path.is_dir() {
            Ok(Self::Folder {
                dir: path,
                period: Duration::from_secs(5),
            })
        } else if path.is_file() && video {
            Ok(Self::Media(MediaSpec::File(path)))
        } else if path.is_file() {
            Ok(Self::Image(path))
        } else if path.exists() {
            // A FIFO or a device: a raw source, spelled as one.
            Err(Error::Input(format!(
                "{}: not a regular file (a FIFO or a device); to play raw frames from it, spell \
                 it raw:{0}?size=WxH",
                path.display()
            )))
        } else {
            Err(Error::Missing {
                path,
                expected: "a video file, an image or a folder of images to play (or a source \
                           spelled uri:, screen:, gst:, raw:, v4l2:, pattern:; see `compend play \
                           --help`)"
                    .into(),
            })
        }
    }

    /// `folder:DIR?period=S`.
    fn folder(spec: &str, body: &str, query: Option<&str>) -> Result<Self> {
        let mut period = Duration::from_secs(5);
        for (k, v) in options(spec, query, &["period"])? {
            if k == "period" {
                let s: f64 = v
                    .parse()
                    .map_err(|_| bad(spec, format!("period {v:?} is not a number of seconds")))?;
                if !(s.is_finite() && s > 0.0) {
                    return Err(bad(spec, "period must be positive"));
                }
                period = Duration::from_secs_f64(s);
            }
        }
        Ok(Self::Folder {
            dir: PathBuf::from(body),
            period,
        })
    }

    /// `raw:-|PATH?size=WxH&format=rgb24|rgba`.
    fn raw(spec: &str, body: &str, query: Option<&str>) -> Result<Self> {
        let (mut size, mut format) = (None, RawFormat::Rgb24);
        for (k, v) in options(spec, query, &["size", "format"])? {
            match k {
                "size" => size = Some(parse_size(spec, v)?),
                _ => {
                    format = match v {
                        "rgb24" | "rgb" => RawFormat::Rgb24,
                        "rgba" | "rgba32" => RawFormat::Rgba,
                        _ => {
                            return Err(bad(spec, format!("format {v:?} is not rgb24 or rgba")));
                        }
                    }
                }
            }
        }
        let size = size.ok_or_else(|| bad(spec, "raw frames need ?size=WxH"))?;
        if body.is_empty() {
            return Err(bad(spec, "raw needs - (standard input) or a path"));
        }
        Ok(Self::Raw {
            path: (body != "-").then(|| PathBuf::from(body)),
            size,
            format,
        })
    }

    /// `v4l2:DEVICE?size=WxH`.
    fn v4l2(spec: &str, body: &str, query: Option<&str>) -> Result<Self> {
        let mut size = None;
        for (_, v) in options(spec, query, &["size"])? {
            size = Some(parse_size(spec, v)?);
        }
        if body.is_empty() {
            return Err(bad(spec, "v4l2 needs a device path, e.g. v4l2:/dev/video0"));
        }
        Ok(Self::V4l2 {
            device: PathBuf::from(body),
            size,
        })
    }

    /// `uri:URI`: a URI with a scheme GStreamer may open.
    fn uri(spec: &str, uri: &str) -> Result<Self> {
        let scheme = uri.split_once("://").map(|(s, _)| s).unwrap_or_default();
        if scheme.is_empty()
            || !scheme
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
        {
            return Err(bad(
                spec,
                "uri: needs a URI with a scheme, e.g. uri:rtsp://camera.local/stream or \
                 uri:https://host/film.mp4",
            ));
        }
        Ok(Self::Media(MediaSpec::Uri(uri.to_string())))
    }

    /// `screen:[x11][?display=:0&xid=N&fps=F]` or `screen:pipewire?node=N[&fps=F]`.
    fn screen(spec: &str, body: &str, query: Option<&str>) -> Result<Self> {
        let fps = |v: &str| -> Result<u32> {
            match v.parse::<u32>() {
                Ok(f) if (1..=240).contains(&f) => Ok(f),
                _ => Err(bad(
                    spec,
                    format!("fps {v:?} is not a whole number from 1 to 240"),
                )),
            }
        };
        match body {
            "" | "x11" => {
                let (mut display, mut xid, mut rate) = (None, None, 30);
                for (k, v) in options(spec, query, &["display", "xid", "fps"])? {
                    match k {
                        "display" => display = Some(v.to_string()),
                        "xid" => {
                            let parsed = match v.strip_prefix("0x") {
                                Some(hex) => u64::from_str_radix(hex, 16).ok(),
                                None => v.parse().ok(),
                            };
                            xid = Some(parsed.ok_or_else(|| {
                                bad(
                                    spec,
                                    format!("xid {v:?} is not a window id (0x1a00003 or decimal)"),
                                )
                            })?);
                        }
                        _ => rate = fps(v)?,
                    }
                }
                Ok(Self::Media(MediaSpec::Screen(ScreenSpec::X11 {
                    display,
                    xid,
                    fps: rate,
                })))
            }
            "pipewire" => {
                let (mut node, mut rate) = (None, 30);
                for (k, v) in options(spec, query, &["node", "fps"])? {
                    match k {
                        "node" => node = Some(v.to_string()),
                        _ => rate = fps(v)?,
                    }
                }
                let node = node.ok_or_else(|| {
                    bad(
                        spec,
                        "screen:pipewire needs ?node=N (the screen-cast's node id)",
                    )
                })?;
                Ok(Self::Media(MediaSpec::Screen(ScreenSpec::PipeWire {
                    node,
                    fps: rate,
                })))
            }
            other => Err(bad(
                spec,
                format!("unknown screen {other:?} (known: x11, pipewire)"),
            )),
        }
    }

    /// `pattern:NAME?size=WxH&fps=F&frames=N`.
    fn pattern(spec: &str, body: &str, query: Option<&str>) -> Result<Self> {
        let pattern = match body {
            "bars" => Pattern::Bars,
            "ramp" => Pattern::Ramp,
            "checker" => Pattern::Checker,
            "gray" | "grey" => Pattern::Gray,
            "moving" => Pattern::Moving,
            _ => {
                return Err(bad(
                    spec,
                    format!("unknown pattern {body:?} (known: {})", PATTERNS.join(", ")),
                ));
            }
        };
        let (mut size, mut fps, mut frames) = (ImageSize::new(1280, 720), 60.0f64, None);
        for (k, v) in options(spec, query, &["size", "fps", "frames"])? {
            match k {
                "size" => size = parse_size(spec, v)?,
                "fps" => {
                    fps = v
                        .parse()
                        .map_err(|_| bad(spec, format!("fps {v:?} is not a number")))?;
                    if !(fps.is_finite() && fps > 0.0) {
                        return Err(bad(spec, "fps must be positive"));
                    }
                }
                _ => {
                    frames = Some(
                        v.parse()
                            .map_err(|_| bad(spec, format!("frames {v:?} is not a count")))?,
                    )
                }
            }
        }
        Ok(Self::Pattern {
            pattern,
            size,
            fps,
            frames,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spellings() {
        assert_eq!(
            SourceSpec::parse("raw:-?size=1280x720&format=rgb24").unwrap(),
            SourceSpec::Raw {
                path: None,
                size: ImageSize::new(1280, 720),
                format: RawFormat::Rgb24
            }
        );
        assert_eq!(
            SourceSpec::parse("raw:/tmp/f?size=4x2&format=rgba").unwrap(),
            SourceSpec::Raw {
                path: Some("/tmp/f".into()),
                size: ImageSize::new(4, 2),
                format: RawFormat::Rgba
            }
        );
        assert_eq!(
            SourceSpec::parse("v4l2:/dev/video2").unwrap(),
            SourceSpec::V4l2 {
                device: "/dev/video2".into(),
                size: None
            }
        );
        assert!(matches!(
            SourceSpec::parse("pattern:moving?size=64x48&fps=30&frames=10").unwrap(),
            SourceSpec::Pattern {
                pattern: Pattern::Moving,
                size: ImageSize {
                    width: 64,
                    height: 48
                },
                frames: Some(10),
                ..
            }
        ));
        assert!(matches!(
            SourceSpec::parse("folder:/x?period=0.5").unwrap(),
            SourceSpec::Folder { .. }
        ));
        // Media: a URI and a pipeline are taken whole, queries and all.
        assert_eq!(
            SourceSpec::parse("uri:rtsp://cam.local:554/live?token=a&b=c").unwrap(),
            SourceSpec::Media(MediaSpec::Uri(
                "rtsp://cam.local:554/live?token=a&b=c".into()
            ))
        );
        assert_eq!(
            SourceSpec::parse("gst:videotestsrc ! video/x-raw,width=8,height=8").unwrap(),
            SourceSpec::Media(MediaSpec::Pipeline(
                "videotestsrc ! video/x-raw,width=8,height=8".into()
            ))
        );
        assert_eq!(
            SourceSpec::parse("file:/srv/show/a film?.mp4").unwrap(),
            SourceSpec::Media(MediaSpec::File("/srv/show/a film?.mp4".into()))
        );
        assert_eq!(
            SourceSpec::parse("screen:x11?display=:1&xid=0x1a00003&fps=25").unwrap(),
            SourceSpec::Media(MediaSpec::Screen(ScreenSpec::X11 {
                display: Some(":1".into()),
                xid: Some(0x1a00003),
                fps: 25
            }))
        );
        assert_eq!(
            SourceSpec::parse("screen:pipewire?node=42").unwrap(),
            SourceSpec::Media(MediaSpec::Screen(ScreenSpec::PipeWire {
                node: "42".into(),
                fps: 30
            }))
        );
        // A bare path by what is there: a video file's ending is a film.
        let dir = tempfile::tempdir().unwrap();
        let film = dir.path().join("Intro.MP4");
        std::fs::write(&film, b"x").unwrap();
        assert_eq!(
            SourceSpec::parse(film.to_str().unwrap()).unwrap(),
            SourceSpec::Media(MediaSpec::File(film))
        );
        for bad in [
            "uri:",
            "uri:no-scheme",
            "gst:",
            "gst:   ",
            "file:",
            "screen:wayland",
            "screen:pipewire",
            "screen:x11?fps=0",
            "screen:x11?xid=zz",
            "screen:x11?size=4x4",
            "raw:-",
            "raw:-?size=12",
            "raw:-?size=4x4&format=yuv",
            "raw:-?size=4x4&fps=3",
            "raw:-?size=16384x16384",
            "pattern:nope",
            "/definitely/not/here.png",
        ] {
            let e = SourceSpec::parse(bad).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{bad}: {e}");
        }
    }
}
