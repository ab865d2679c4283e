//! `compend bench-media`: films through compend, on this machine, against baselines from the
//! same run. The films are made by GStreamer here (nothing is downloaded or committed):
//!
//! - **decode**: the film decoded to RGBA frames alone (GStreamer, as fast as it goes), ms per
//!   frame, against the film's frame period;
//! - **live**: the film played in real time through the model's compensation pass at the
//!   projector's size with no display ([`Headless`]: upload and pass waited for each frame), at
//!   `--refresh` Hz, for `--seconds`: frames shown, held and dropped (by the source, by the
//!   pipeline), pipeline and picture latency, and the process's CPU load;
//! - **offline**: the film compensated to an H.264 file as fast as it goes (`compensate`'s
//!   path), against its own length: the real-time factor;
//! - **sync**: a film of black frames with a white flash and a 1 kHz beep at each whole second,
//!   played live on the virtual rig with its sound into a sink on the pipeline's clock: the time
//!   the rig's camera sees each flash against the time its beep is rendered. The sound is
//!   delayed by the picture latency compend measures; the offset left is what a viewer would
//!   hear.
//!
//! Writes bench-media.json and bench-media.md in `--out`, with the films.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use compend::gpu::GpuContext;
use compend::model::Model;
use compend::output::{MediaOutput, OutputSpec, Teed};
use compend::player::{Headless, PlayStats, Player, ViewSink, WatchedSink};
use compend::raster::ImageSize;
use compend::source::{AudioOut, FeedMode, MediaSpec, Playlist, PlaylistItem, SourceSpec};
use gstreamer as gst;
use gstreamer::prelude::*;
use serde::Serialize;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// A model made by `compend calibrate` (its canvas gives the projector's size; on the
    /// virtual rig its calibration record gives the scene).
    #[arg(long)]
    pub model: PathBuf,
    /// Folder for bench-media.json, bench-media.md and the films made for the run.
    #[arg(long)]
    pub out: PathBuf,
    /// The test film's frame size.
    #[arg(long, value_parser = super::sim::parse_size, default_value = "1920x1080")]
    pub size: ImageSize,
    /// The test film's frame rate, frames per second.
    #[arg(long, default_value_t = 30)]
    pub film_fps: u32,
    /// The test film's length, s (the live run loops it).
    #[arg(long, default_value_t = 20.0)]
    pub film_seconds: f64,
    /// Seconds of live playback.
    #[arg(long, default_value_t = 60.0)]
    pub seconds: f64,
    /// Display refresh rate of the live and sync runs, Hz.
    #[arg(long, default_value_t = 60.0)]
    pub refresh: f64,
    /// Flashes (one a second) in the sync run.
    #[arg(long, default_value_t = 10)]
    pub marks: u32,
    /// Rounds of the decode and offline measurements (the host's speed drifts: a range).
    #[arg(long, default_value_t = 2)]
    pub rounds: u32,
}

#[derive(Debug, Serialize)]
struct Report {
    film: String,
    adapter: String,
    projector: (usize, usize),
    decode_ms_per_frame: Vec<f64>,
    frame_period_ms: f64,
    live: LiveRun,
    offline_realtime_factor: Vec<f64>,
    sync: SyncRun,
}

#[derive(Debug, Serialize)]
struct LiveRun {
    seconds: f64,
    refresh_hz: f64,
    stats: PlayStats,
    /// The process's CPU time over the run's wall time, in cores (2 = both cores busy).
    cpu_cores_busy: f64,
}

#[derive(Debug, Default, Serialize)]
struct SyncRun {
    /// Flash time minus beep time for each mark seen and heard, ms (positive: the picture
    /// later).
    offsets_ms: Vec<f64>,
    flashes_seen: usize,
    beeps_heard: usize,
    /// The delay given to the sound at the end, ms.
    audio_delay_ms: f64,
    latency_ms_mean: f64,
}

pub fn run(args: Args) -> Result<()> {
    compend::files::check_out_folder(&args.out)?;
    if !(args.seconds > 0.0 && args.film_seconds > 0.0 && args.refresh > 0.0) {
        bail!(compend::Error::Input(
            "--seconds, --film-seconds and --refresh must be positive".into()
        ));
    }
    std::fs::create_dir_all(&args.out)
        .map_err(|e| compend::Error::io(&args.out, "create folder", e))?;
    let model = Model::load(&args.model)?;
    let projector = super::model_projector(&model, None)?;
    compend::media::init()?;

    let film = args.out.join("film.mp4");
    let frames = (args.film_seconds * args.film_fps as f64).round().max(1.0) as u64;
    if !film.exists() {
        eprintln!(
            "bench-media: making a {}x{} {} fps film of {frames} frames with sound",
            args.size.width, args.size.height, args.film_fps
        );
        make_film(&film, args.size, args.film_fps, frames, None)?;
    }
    let ctx = GpuContext::new()?;
    let period_ms = 1e3 / args.film_fps as f64;

    let mut decode = Vec::new();
    let mut offline = Vec::new();
    for round in 0..args.rounds {
        let ms = decode_ms(&film)?;
        eprintln!("bench-media: round {round}: decode {ms:.2} ms per frame");
        decode.push(ms);
        let out = args.out.join(format!(".offline-{round}.mp4"));
        let _ = std::fs::remove_file(&out);
        let f = offline_factor(&ctx, &model, projector, &film, &out, args.film_fps as f64)?;
        let _ = std::fs::remove_file(&out);
        eprintln!("bench-media: round {round}: offline {f:.2}x real time");
        offline.push(f);
    }

    let live = live_run(&ctx, &model, projector, &film, &args)?;
    eprintln!("bench-media: live: {}", live.stats.summary());

    let sync_film = args.out.join("sync.mp4");
    if !sync_film.exists() {
        make_film(
            &sync_film,
            ImageSize::new(64, 48),
            args.film_fps,
            (args.marks as u64 + 1) * args.film_fps as u64,
            Some(args.film_fps),
        )?;
    }
    let sync = sync_run(&model, &sync_film, &args)?;
    eprintln!(
        "bench-media: sync: {} flashes seen, {} beeps heard, offsets {:?} ms",
        sync.flashes_seen, sync.beeps_heard, sync.offsets_ms
    );

    let report = Report {
        film: format!(
            "{}x{} at {} fps, {} s, H.264 + AAC (made by GStreamer)",
            args.size.width, args.size.height, args.film_fps, args.film_seconds
        ),
        adapter: ctx.describe(),
        projector: (projector.width, projector.height),
        decode_ms_per_frame: decode,
        frame_period_ms: period_ms,
        live,
        offline_realtime_factor: offline,
        sync,
    };
    let json = serde_json::to_string_pretty(&report)?;
    compend::files::write_atomically(&args.out.join("bench-media.json"), json.as_bytes())?;
    compend::files::write_atomically(
        &args.out.join("bench-media.md"),
        markdown(&report).as_bytes(),
    )?;
    println!("{}", markdown(&report));
    Ok(())
}

/// Makes a film: `frames` frames of `size` at `fps` with sound. `flash_every`: black frames
/// with a white one every that many frames (from frame `fps`: one second in), and a 100 ms
/// 1 kHz beep starting with each (pushed from here); otherwise GStreamer's moving ball and a
/// steady tone.
fn make_film(
    path: &Path,
    size: ImageSize,
    fps: u32,
    frames: u64,
    flash_every: Option<u32>,
) -> Result<()> {
    let loc = path.to_str().context("a UTF-8 path")?;
    let (w, h) = (size.width, size.height);
    if flash_every.is_none() {
        // The content film from GStreamer's own test sources (a moving ball, a tone).
        let encoder = if compend::media::has_element("x264enc") {
            "x264enc speed-preset=veryfast bitrate=8000 key-int-max=30"
        } else {
            "openh264enc bitrate=8000000"
        };
        let desc = format!(
            "videotestsrc num-buffers={frames} pattern=ball ! \
             video/x-raw,width={w},height={h},framerate={fps}/1 ! videoconvert ! \
             video/x-raw,format=I420 ! {encoder} ! h264parse ! mp4mux name=mux ! \
             filesink location=\"{loc}\" audiotestsrc num-buffers={frames} \
             samplesperbuffer={} ! audioconvert ! avenc_aac ! aacparse ! mux.",
            44_100 / fps
        );
        return run_to_end(&desc, path);
    }
    let encoder = if compend::media::has_element("x264enc") {
        "x264enc speed-preset=veryfast bitrate=8000 key-int-max=30"
    } else {
        "openh264enc bitrate=8000000"
    };
    // 44.1 kHz mono in buffers of one video frame.
    let spb = 44_100 / fps;
    let desc = format!(
        "appsrc name=v format=time caps=\"video/x-raw,format=RGBA,width={w},height={h},\
         framerate={fps}/1\" ! videoconvert ! video/x-raw,format=I420 ! {encoder} ! h264parse ! \
         mp4mux name=mux ! filesink location=\"{loc}\" \
         appsrc name=a format=time caps=\"audio/x-raw,format=F32LE,rate=44100,channels=1,\
         layout=interleaved\" ! queue max-size-buffers=0 max-size-bytes=0 max-size-time=0 ! \
         audioconvert ! avenc_aac ! aacparse ! mux."
    );
    let p = gst::parse::launch(&desc)?
        .downcast::<gst::Pipeline>()
        .map_err(|_| anyhow::anyhow!("not a pipeline"))?;
    let v = p
        .by_name("v")
        .and_then(|e| e.downcast::<gstreamer_app::AppSrc>().ok())
        .context("video appsrc")?;
    let a = p
        .by_name("a")
        .and_then(|e| e.downcast::<gstreamer_app::AppSrc>().ok())
        .context("audio appsrc")?;
    // The sync film is small (64x48): both sources take everything at once (no limit, no
    // waiting), so no push waits on a muxer that waits for the other stream.
    for src in [&v, &a] {
        src.set_block(false);
        src.set_max_bytes(0);
    }
    p.set_state(gst::State::Playing)?;
    let frame_ns = 1_000_000_000 / fps as u64;
    // A picture that moves (the decoder has work to do) or the flashes.
    for n in 0..frames {
        let flash = flash_every.is_some_and(|k| n >= fps as u64 && n % k as u64 == 0);
        let mut rgba = vec![0u8; w * h * 4];
        for (i, px) in rgba.chunks_exact_mut(4).enumerate() {
            let (x, y) = (i % w, i / w);
            let v8 = match flash_every {
                Some(_) if flash => 255,
                Some(_) => 0,
                None => ((x + y + n as usize * 4) % 256) as u8,
            };
            px.copy_from_slice(&[v8, ((x * 255) / w.max(1)) as u8 & v8, v8, 255]);
        }
        let mut b = gst::Buffer::from_mut_slice(rgba);
        {
            let b = b.get_mut().context("a new buffer")?;
            b.set_pts(gst::ClockTime::from_nseconds(n * frame_ns));
            b.set_duration(gst::ClockTime::from_nseconds(frame_ns));
        }
        let samples: Vec<f32> = (0..spb)
            .map(|i| {
                let t = i as f32 / 44_100.0;
                let on = match flash_every {
                    Some(_) => flash && t < 0.1,
                    None => true,
                };
                if on {
                    0.5 * (2.0 * std::f32::consts::PI * 1000.0 * t).sin()
                } else {
                    0.0
                }
            })
            .collect();
        let mut ab = gst::Buffer::from_mut_slice(bytemuck_f32(&samples));
        {
            let ab = ab.get_mut().context("a new buffer")?;
            ab.set_pts(gst::ClockTime::from_nseconds(n * frame_ns));
            ab.set_duration(gst::ClockTime::from_nseconds(frame_ns));
        }
        a.push_buffer(ab)?;
        v.push_buffer(b)?;
    }
    v.end_of_stream()?;
    a.end_of_stream()?;
    wait_end(&p, path)
}

/// Runs a pipeline description to its end (10 minutes at most).
fn run_to_end(desc: &str, path: &Path) -> Result<()> {
    let p = gst::parse::launch(desc)?
        .downcast::<gst::Pipeline>()
        .map_err(|_| anyhow::anyhow!("not a pipeline"))?;
    p.set_state(gst::State::Playing)?;
    wait_end(&p, path)
}

/// Waits for a playing pipeline writing `path` to end (10 minutes at most), then stops it.
fn wait_end(p: &gst::Pipeline, path: &Path) -> Result<()> {
    let bus = p.bus().context("bus")?;
    let msg = bus
        .timed_pop_filtered(
            gst::ClockTime::from_seconds(600),
            &[gst::MessageType::Eos, gst::MessageType::Error],
        )
        .context("the film was not written within 10 minutes")?;
    p.set_state(gst::State::Null)?;
    if let gst::MessageView::Error(e) = msg.view() {
        bail!("making {}: {}", path.display(), e.error());
    }
    Ok(())
}

fn bytemuck_f32(s: &[f32]) -> Vec<u8> {
    s.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// The film decoded to RGBA by GStreamer alone, as fast as it goes: ms per frame.
fn decode_ms(film: &Path) -> Result<f64> {
    let desc = format!(
        "filesrc location=\"{}\" ! decodebin ! videoconvert ! video/x-raw,format=RGBA ! \
         fakesink name=s sync=false signal-handoffs=false",
        film.display()
    );
    let p = gst::parse::launch(&desc)?
        .downcast::<gst::Pipeline>()
        .map_err(|_| anyhow::anyhow!("not a pipeline"))?;
    let sink = p.by_name("s").context("sink")?;
    let t = Instant::now();
    p.set_state(gst::State::Playing)?;
    let bus = p.bus().context("bus")?;
    let msg = bus
        .timed_pop_filtered(
            gst::ClockTime::from_seconds(600),
            &[gst::MessageType::Eos, gst::MessageType::Error],
        )
        .context("decoding took over 10 minutes")?;
    let secs = t.elapsed().as_secs_f64();
    let frames: u64 = sink
        .property::<gst::Structure>("stats")
        .get::<u64>("rendered")
        .unwrap_or(0);
    p.set_state(gst::State::Null)?;
    if let gst::MessageView::Error(e) = msg.view() {
        bail!("decoding {}: {}", film.display(), e.error());
    }
    if frames == 0 {
        bail!("decoding {}: no frames counted", film.display());
    }
    Ok(secs * 1e3 / frames as f64)
}

/// The film compensated to a file offline: film seconds per wall second.
fn offline_factor(
    ctx: &GpuContext,
    model: &Model,
    projector: ImageSize,
    film: &Path,
    out: &Path,
    fps: f64,
) -> Result<f64> {
    let no_sound = AudioOut {
        sink: None,
        delay_ms: 0.0,
    };
    let spec = SourceSpec::Media(MediaSpec::File(film.to_path_buf()));
    let source = compend::source::open_with(&spec, &no_sound)?;
    let mut player = Player::start(
        ctx,
        model,
        projector,
        model.display_range(),
        source,
        FeedMode::Queue,
    )?;
    let output = MediaOutput::start(&OutputSpec::File(out.to_path_buf()), projector, fps, false)?;
    let mut screen = Headless::new(ctx, fps);
    let stats = player.run(&mut Teed::new(&mut screen, output), None)?;
    Ok(stats.shown as f64 / fps / stats.seconds.max(1e-9))
}

/// CPU time of this process so far, s (user + system, from /proc/self/stat).
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    // Fields after the command name (which may hold spaces) in parentheses.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // utime and stime are fields 14 and 15 of the line: 12 and 13 after the state.
    // Clock ticks per second (100 on Linux, where sysconf always knows it).
    let hz = match nix::unistd::sysconf(nix::unistd::SysconfVar::CLK_TCK) {
        Ok(Some(hz)) if hz > 0 => hz as f64,
        _ => 100.0,
    };
    (ticks(11) + ticks(12)) / hz
}

/// The film played live (looped) through the pass with no display.
fn live_run(
    ctx: &GpuContext,
    model: &Model,
    projector: ImageSize,
    film: &Path,
    args: &Args,
) -> Result<LiveRun> {
    let list = Playlist {
        items: vec![PlaylistItem {
            source: film.display().to_string(),
            loops: 0,
            duration_s: None,
        }],
        repeat: true,
    };
    let sound = AudioOut {
        sink: Some("fakesink sync=true".into()),
        delay_ms: 0.0,
    };
    let source = list.open(&sound)?;
    let mut player = Player::start(
        ctx,
        model,
        projector,
        model.display_range(),
        source,
        FeedMode::Latest,
    )?;
    let refreshes = (args.seconds * args.refresh).round() as u64;
    let mut screen = Headless::new(ctx, args.refresh);
    let (cpu0, t0) = (cpu_seconds(), Instant::now());
    let stats = player.run(&mut screen, Some(refreshes))?;
    let cpu = (cpu_seconds() - cpu0) / t0.elapsed().as_secs_f64();
    Ok(LiveRun {
        seconds: args.seconds,
        refresh_hz: args.refresh,
        stats,
        cpu_cores_busy: cpu,
    })
}

/// The flash-and-beep film on the virtual rig: when each flash is seen against when its beep
/// is rendered.
fn sync_run(model: &Model, film: &Path, args: &Args) -> Result<SyncRun> {
    // The scene the model was calibrated on (`calibrate --rig virtual:SCENE` records it).
    let scene = model
        .meta
        .calibration
        .as_ref()
        .and_then(|c| c.rig.strip_prefix("virtual:").map(str::to_string));
    let (rig, range) = super::play::virtual_rig(model, scene.as_deref(), None)?;
    let ctx = GpuContext::new()?;
    let sim = rig.simulator();
    // The beep onsets, from the audio sink: an appsink on the pipeline's clock (it releases a
    // buffer when a sound card would play it), read on a thread of its own.
    let sound = AudioOut {
        sink: Some(
            "appsink name=compend-av-probe sync=true max-buffers=64 \
             caps=audio/x-raw,format=F32LE,channels=1"
                .into(),
        ),
        delay_ms: 0.0,
    };
    let spec = SourceSpec::Media(MediaSpec::File(film.to_path_buf()));
    let source = compend::source::open_with(&spec, &sound)?;
    let mut player = Player::start(
        &ctx,
        model,
        sim.projector_size(),
        range,
        source,
        FeedMode::Latest,
    )?;
    let control = player
        .feed
        .control()
        .cloned()
        .context("a media source has a control")?;
    let flashes: Arc<Mutex<Vec<Instant>>> = Arc::default();
    let seen = flashes.clone();
    // (the black level: the first view's mean, whether the last view was lit)
    let state = Arc::new(Mutex::new((None::<f32>, false)));
    let views: ViewSink = Box::new(move |_, _, view| {
        let at = Instant::now();
        let mean = view.data().iter().sum::<f32>() / view.data().len().max(1) as f32;
        let mut st = state.lock().unwrap_or_else(|e| e.into_inner());
        let black = *st.0.get_or_insert(mean);
        let lit = mean > black + 0.1;
        if lit && !st.1 {
            seen.lock().unwrap_or_else(|e| e.into_inner()).push(at);
        }
        st.1 = lit;
        Ok(())
    });
    let beeps: Arc<Mutex<Vec<Instant>>> = Arc::default();
    let heard = beeps.clone();
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stopped = stop.clone();
    let listener = std::thread::spawn(move || {
        let mut sink = None;
        let mut silent_since: Option<Instant> = Some(Instant::now());
        while !stopped.load(std::sync::atomic::Ordering::Relaxed) {
            if sink.is_none() {
                sink = control
                    .pipeline()
                    .and_then(|p| p.by_name("compend-av-probe"))
                    .and_then(|e| e.downcast::<gstreamer_app::AppSink>().ok());
                if sink.is_none() {
                    std::thread::sleep(Duration::from_millis(5));
                    continue;
                }
            }
            let s = sink.as_ref().expect("found above");
            let Some(sample) = s.try_pull_sample(gst::ClockTime::from_mseconds(50)) else {
                continue;
            };
            let at = Instant::now();
            let Some(buf) = sample.buffer() else { continue };
            let Ok(map) = buf.map_readable() else {
                continue;
            };
            let x: Vec<f32> = map
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            match x.iter().position(|v| v.abs() > 0.05) {
                Some(i) if silent_since.is_some() => {
                    heard
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .push(at + Duration::from_secs_f64(i as f64 / 44_100.0));
                    silent_since = None;
                }
                Some(_) => {}
                None => {
                    silent_since.get_or_insert(at);
                }
            }
        }
    });
    let mut screen = WatchedSink::new(&ctx, args.refresh, rig.clone(), rig, views);
    let stats = player.run(&mut screen, None);
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = listener.join();
    let stats = stats?;
    let flashes = flashes.lock().unwrap_or_else(|e| e.into_inner()).clone();
    let beeps = beeps.lock().unwrap_or_else(|e| e.into_inner()).clone();
    // Each flash with the beep nearest to it (within half a second).
    let offsets = flashes
        .iter()
        .filter_map(|f| {
            beeps
                .iter()
                .map(|b| signed_ms(*f, *b))
                .min_by(|a, b| a.abs().total_cmp(&b.abs()))
                .filter(|d| d.abs() < 500.0)
        })
        .collect();
    Ok(SyncRun {
        offsets_ms: offsets,
        flashes_seen: flashes.len(),
        beeps_heard: beeps.len(),
        audio_delay_ms: stats.media.as_ref().map_or(0.0, |m| m.audio_delay_ms),
        latency_ms_mean: stats.latency_ms_mean,
    })
}

/// `a − b` in ms.
fn signed_ms(a: Instant, b: Instant) -> f64 {
    if a >= b {
        (a - b).as_secs_f64() * 1e3
    } else {
        -((b - a).as_secs_f64() * 1e3)
    }
}

fn range(v: &[f64]) -> String {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if v.is_empty() {
        "—".into()
    } else if (hi - lo).abs() < 1e-9 {
        format!("{lo:.2}")
    } else {
        format!("{lo:.2}–{hi:.2}")
    }
}

fn markdown(r: &Report) -> String {
    let l = &r.live.stats;
    let s = &r.sync;
    format!(
        "# bench-media\n\nFilm: {}. Projector canvas {}x{}; {}.\n\n\
         | measure | value |\n|---|---|\n\
         | decode alone, ms per frame (frame period {:.1} ms) | {} |\n\
         | offline compensation to H.264, × real time | {} |\n\
         | live {} s at {} Hz: frames shown / held / dropped by the source / by the pipeline | {} / {} / {} / {} |\n\
         | live: pipeline ms mean / worst | {:.2} / {:.2} |\n\
         | live: picture latency, ms mean | {:.2} |\n\
         | live: CPU, cores busy | {:.2} |\n\
         | sync: flashes seen / beeps heard | {} / {} |\n\
         | sync: picture minus sound, ms (each mark) | {} |\n\
         | sync: sound delayed by, ms (measured latency) | {:.2} ({:.2}) |\n",
        r.film,
        r.projector.0,
        r.projector.1,
        r.adapter,
        r.frame_period_ms,
        range(&r.decode_ms_per_frame),
        range(&r.offline_realtime_factor),
        r.live.seconds,
        r.live.refresh_hz,
        l.shown,
        l.held,
        l.dropped_source,
        l.dropped_pipeline,
        l.pipeline_ms_mean,
        l.pipeline_ms_max,
        l.latency_ms_mean,
        r.live.cpu_cores_busy,
        s.flashes_seen,
        s.beeps_heard,
        s.offsets_ms
            .iter()
            .map(|o| format!("{o:+.1}"))
            .collect::<Vec<_>>()
            .join(", "),
        s.audio_delay_ms,
        s.latency_ms_mean,
    )
}
