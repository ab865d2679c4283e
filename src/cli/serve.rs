//! `compend serve` (the service), its clients (`status`, `recalibrate`, `pause`, `stop`,
//! `play` without `--model`, `ctl`) and `compend config check`.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use compend::config::{Config, RigKind};
use compend::service::protocol::{Reply, Request, State, Status};
use compend::service::socket;

#[derive(clap::Args, Clone, Debug)]
pub struct ServeArgs {
    /// The configuration file (TOML; config/compend.toml documents every key) [default: every
    /// key at its default: the virtual rig, state in $STATE_DIRECTORY or /var/lib/compend].
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Overrides [socket] path.
    #[arg(long, value_name = "PATH")]
    pub socket: Option<PathBuf>,
    /// Overrides [paths] state (and the data and model folders under it, unless the file names
    /// them).
    #[arg(long, value_name = "DIR")]
    pub state: Option<PathBuf>,
    /// Overrides [rig]: `virtual[:SCENE]`.
    #[arg(long, value_name = "virtual[:SCENE]")]
    pub rig: Option<String>,
    /// Overrides [playback] source.
    #[arg(long, value_name = "SRC")]
    pub source: Option<String>,
}

#[derive(clap::Args, Debug)]
pub struct ClientArgs {
    /// The service's socket [default: the one --config names, else /run/compend/compend.sock].
    #[arg(long, value_name = "PATH")]
    pub socket: Option<PathBuf>,
    /// The service's configuration file, to find its socket.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
pub struct SeekArgs {
    /// The time to go to, seconds from the film's start.
    #[arg(value_name = "SECONDS")]
    pub position_s: f64,
    #[command(flatten)]
    pub client: ClientArgs,
}

#[derive(clap::Args, Debug)]
pub struct StatusArgs {
    #[command(flatten)]
    pub client: ClientArgs,
    /// Print the status as one JSON object.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct RecalibrateArgs {
    #[command(flatten)]
    pub client: ClientArgs,
    /// Wait until the calibration has ended and print its outcome (exit 1 if no new model was
    /// installed).
    #[arg(long)]
    pub wait: bool,
    /// With --wait: give up after this many seconds.
    #[arg(long, default_value_t = 1800.0, value_name = "S")]
    pub timeout: f64,
    /// A fast refit instead: the `linear` rung from `[monitoring] refit_ntrain` sampling
    /// images, in a new run (what drift's `on_drift = "refit"` runs); installed only if it
    /// verifies.
    #[arg(long)]
    pub refit: bool,
}

#[derive(clap::Args, Debug)]
pub struct CtlArgs {
    #[command(flatten)]
    pub client: ClientArgs,
    /// One request line, e.g. '{"cmd":"model","path":"/var/lib/compend/model"}'.
    pub request: String,
}

#[derive(clap::Args, Debug)]
pub struct ConfigArgs {
    #[command(subcommand)]
    pub command: ConfigCommand,
}

#[derive(clap::Subcommand, Debug)]
pub enum ConfigCommand {
    /// Check a configuration file: every error at once, each with its line (exit 2 if any); then
    /// what `serve` would refuse of the file's surroundings (the scene, the paths, the token
    /// file), without writing anything.
    Check {
        file: PathBuf,
        /// Print the configuration with every default filled in, as JSON.
        #[arg(long)]
        json: bool,
    },
}

/// The configuration with the command line's overrides.
fn configure(a: &ServeArgs) -> Result<Config> {
    let mut c = match &a.config {
        Some(f) => Config::load(f)?,
        None => Config::defaults(),
    };
    if let Some(s) = &a.socket {
        c.socket.path = s.clone();
    }
    if let Some(dir) = &a.state {
        let old = c.paths.state.clone();
        if c.paths.data == old.join("calibration") {
            c.paths.data = dir.join("calibration");
        }
        if c.paths.model == old.join("model") {
            c.paths.model = dir.join("model");
        }
        c.paths.state = dir.clone();
    }
    if let Some(rig) = &a.rig {
        let scene = match rig.split_once(':') {
            None if rig == "virtual" => None,
            Some(("virtual", s)) if !s.is_empty() => Some(s.to_string()),
            _ => {
                return Err(compend::Error::Input(format!(
                    "--rig {rig:?}: expected `virtual` or `virtual:SCENE`; a camera rig is set \
                     in the configuration file ([rig] kind = \"camera\")"
                ))
                .into());
            }
        };
        c.rig.kind = RigKind::Virtual;
        if let Some(s) = scene {
            c.rig.scene = s;
        }
    }
    if let Some(s) = &a.source {
        compend::source::SourceSpec::parse(s)?;
        c.playback.source = compend::source::Playlist::single(s.clone());
    }
    Ok(c)
}

/// The media line of `status`: the playlist item, the position in the film, its rate and
/// size, the sound, problems.
fn media_line(m: &compend::media::MediaStatus) -> String {
    let mut parts = Vec::new();
    if let Some(i) = &m.item {
        parts.push(format!(
            "item {} of {} ({}){}",
            i.index,
            i.count,
            i.source,
            if i.pass > 1 {
                format!(", pass {}", i.pass)
            } else {
                String::new()
            }
        ));
    }
    match (m.position_s, m.duration_s) {
        (Some(p), Some(d)) => parts.push(format!("at {p:.1} of {d:.1} s")),
        (Some(p), None) => parts.push(format!("at {p:.1} s")),
        _ => {}
    }
    if let (Some(f), Some((w, h))) = (m.fps, m.size) {
        parts.push(format!("{w}x{h} at {f:.3} fps"));
    }
    parts.push(if m.audio {
        format!(
            "sound delayed {:.0} ms to meet the picture",
            m.audio_delay_ms
        )
    } else {
        "no sound".into()
    });
    if m.paused {
        parts.push("paused".into());
    }
    if m.reconnects > 0 {
        parts.push(format!("{} reconnection(s)", m.reconnects));
    }
    if m.warnings > 0 {
        parts.push(format!("{} decoder warning(s)", m.warnings));
    }
    let mut line = format!("media: {}\n", parts.join(", "));
    if let Some(p) = &m.last_problem {
        line += &format!("media problem: {p}\n");
    }
    line
}

pub fn serve(a: ServeArgs) -> Result<()> {
    let config = configure(&a)?;
    let reload: Option<compend::service::Reload> = a.config.is_some().then(|| {
        let a = a.clone();
        Box::new(move || {
            let c = configure(&a).map_err(|e| match e.downcast::<compend::Error>() {
                Ok(e) => e,
                Err(e) => compend::Error::Input(format!("{e:#}")),
            })?;
            // What `config check` refuses is refused here too, so that a reload the next
            // restart would fail on is not applied (the running service keeps its own).
            compend::service::preflight(&c, true)?;
            Ok(c)
        }) as compend::service::Reload
    });
    compend::service::serve(config, reload, compend::service::terminated()).context("compend serve")
}

fn socket_of(c: &ClientArgs) -> Result<PathBuf> {
    Ok(socket::resolve(c.socket.clone(), c.config.as_deref())?)
}

/// Sends a request; a refusal is an error (exit 1: the service said no).
fn send(c: &ClientArgs, req: &Request) -> Result<Reply> {
    let path = socket_of(c)?;
    let reply = socket::request(&path, req)?;
    if !reply.ok {
        return Err(compend::Error::Failed(format!(
            "the service refused: {}",
            reply.error.as_deref().unwrap_or("no reason given")
        ))
        .into());
    }
    Ok(reply)
}

fn print_message(reply: &Reply) {
    if let Some(m) = &reply.message {
        println!("{m}");
    }
}

pub fn status(a: StatusArgs) -> Result<()> {
    let reply = send(&a.client, &Request::Status)?;
    let status = reply
        .status
        .ok_or_else(|| compend::Error::Failed("the service sent no status".into()))?;
    if a.json {
        println!("{}", serde_json::to_string(&status)?);
    } else {
        print!("{}", describe(&status));
    }
    Ok(())
}

/// The status for a person.
fn describe(s: &Status) -> String {
    let mut out = format!(
        "state: {}\nrig: {}\nuptime: {:.0} s (compend {}, pid {})\n",
        s.state.name(),
        s.rig,
        s.uptime_s,
        s.version,
        s.pid
    );
    match &s.model {
        Some(m) => {
            out += &format!("model: {} ({})\n", m.path.display(), m.method);
            if !m.why.is_empty() {
                out += &format!(
                    "  served for {:.0} s: {}\n",
                    (compend::service::protocol::now_unix_s() - m.since_unix_s).max(0.0),
                    m.why
                );
            }
            if let Some(v) = &m.verification {
                out += &format!(
                    "  verified: {:.2} dB / SSIM {:.3} ({:+.2} dB over uncompensated): when it was \
                     installed, the camera's view of held-out images it compensated against the \
                     views they should give\n",
                    v.psnr, v.ssim, v.gain_db
                );
            }
            if let Some(v) = &m.set {
                let alone: Vec<String> = v.alone_psnr.iter().map(|p| format!("{p:.2}")).collect();
                out += &format!(
                    "  the whole set verified: {:.2} dB / SSIM {:.3}, {:+.2} dB over its best \
                     projector alone ({} dB){}\n",
                    v.psnr,
                    v.ssim,
                    v.gain_db,
                    alone.join(", "),
                    v.seam.as_ref().map_or(String::new(), |f| format!(
                        "; seam ratio {:.2} (at most {:.2})",
                        f.ratio(),
                        v.seam_limit
                    ))
                );
            }
        }
        None => out += "model: none installed\n",
    }
    for (k, p) in s.projectors.iter().enumerate() {
        out += &format!(
            "projector {}: {} ({}){}\n",
            k + 1,
            p.output,
            p.size,
            p.verification.as_ref().map_or(String::new(), |v| format!(
                ", verified alone {:.2} dB",
                v.psnr
            ))
        );
    }
    if let Some(c) = &s.calibration {
        out += &format!(
            "calibration: {} {}/{} ({:.0} s)\n",
            c.phase, c.done, c.total, c.seconds
        );
    }
    if let Some(src) = &s.source {
        let f = &s.frames;
        out += &format!(
            "source: {src}\nframes: {} shown, {} held, {} dropped by the source, {} by the \
             pipeline ({} shown in all)\n",
            f.shown, f.held, f.dropped_source, f.dropped_pipeline, f.shown_total
        );
    }
    if let Some(m) = &s.media {
        out += &media_line(m);
    }
    let m = &s.monitoring;
    if let Some(p) = m.psnr {
        out += &format!(
            "monitoring: {p:.2} dB (baseline {:.2} dB) {:.0} s ago, {} checks{}: now, the \
             camera's view of what plays against what should show; a fall past the threshold \
             below the baseline is drift\n",
            m.baseline_psnr.unwrap_or(f64::NAN),
            m.age_s.unwrap_or(0.0),
            m.checks,
            if m.drift { ", DRIFT" } else { "" }
        );
    }
    if !m.projectors_psnr.is_empty() {
        let each: Vec<String> = m
            .projectors_psnr
            .iter()
            .map(|p| p.map_or("-".to_string(), |p| format!("{p:.2} dB")))
            .collect();
        out += &format!(
            "monitoring: each projector's part of the area: {}\n",
            each.join(", ")
        );
    }
    if let Some(r) = m.seam_ratio {
        out += &format!(
            "monitoring: seam ratio {r:.2} (baseline {:.2}): the error along the projectors' \
             overlap edges over the error away from them; a seam shows when it rises past {:.2} \
             from under it\n",
            m.seam_baseline.unwrap_or(f64::NAN),
            compend::calibrate::set::SEAM_LIMIT
        );
    }
    if m.unseen > 0 {
        out += &format!(
            "monitoring: {} checks unseen (the content changed within the projector-to-camera \
             latency)\n",
            m.unseen
        );
    }
    if let Some(c) = &s.last_calibration {
        out += &format!("last calibration: {}\n", c.message);
    }
    if let Some(c) = &s.last_climb {
        out += &format!("last climb: {}\n", c.message);
    }
    if let Some(e) = &s.last_error {
        out += &format!("last error: {e}\n");
    }
    out
}

pub fn recalibrate(a: RecalibrateArgs) -> Result<()> {
    if !(a.timeout.is_finite() && (0.0..=1e9).contains(&a.timeout)) {
        return Err(compend::Error::Input(format!(
            "--timeout {}: expected seconds from 0 to 1e9",
            a.timeout
        ))
        .into());
    }
    let before = send(&a.client, &Request::Status)?
        .status
        .map_or(0, |s| s.calibrations);
    let asked = if a.refit {
        Request::Refit
    } else {
        Request::Recalibrate
    };
    let reply = send(&a.client, &asked)?;
    print_message(&reply);
    if !a.wait {
        return Ok(());
    }
    let deadline = Instant::now() + Duration::from_secs_f64(a.timeout);
    // The service's progress as it goes: a bar on a terminal, lines otherwise.
    let report = super::progress::Progress::new("recalibrate", false);
    loop {
        std::thread::sleep(Duration::from_millis(250));
        let s = send(&a.client, &Request::Status)?
            .status
            .ok_or_else(|| compend::Error::Failed("the service sent no status".into()))?;
        let busy = matches!(
            s.state,
            State::Calibrating | State::Training | State::Verifying
        );
        if busy {
            match &s.calibration {
                Some(p) => report.update(&p.phase, p.done, p.total),
                None => report.update(s.state.name(), 0, 1),
            }
        }
        if s.calibrations > before && !busy {
            report.finish();
            match &s.last_calibration {
                Some(o) if o.installed => {}
                Some(o) => {
                    return Err(
                        compend::Error::Failed(format!("recalibration: {}", o.message)).into(),
                    );
                }
                None => {
                    return Err(compend::Error::Failed(
                        "recalibration: the service reports no outcome".into(),
                    )
                    .into());
                }
            }
            print!("{}", describe(&s));
            return Ok(());
        }
        if Instant::now() > deadline {
            return Err(compend::Error::Failed(format!(
                "recalibration still running after {} s ({})",
                a.timeout,
                s.state.name()
            ))
            .into());
        }
    }
}

pub fn simple(c: &ClientArgs, req: Request) -> Result<()> {
    print_message(&send(c, &req)?);
    Ok(())
}

pub fn ctl(a: CtlArgs) -> Result<()> {
    let req = Request::parse(a.request.as_bytes()).map_err(compend::Error::Input)?;
    let path = socket_of(&a.client)?;
    let reply = socket::request(&path, &req)?;
    println!("{}", serde_json::to_string(&reply)?);
    if !reply.ok {
        // The reply (with its error) is on stdout; the exit code says it was refused.
        return Err(compend::Error::Failed(format!(
            "the service refused: {}",
            reply.error.as_deref().unwrap_or("no reason given")
        ))
        .into());
    }
    Ok(())
}

pub fn config(a: ConfigArgs) -> Result<()> {
    match a.command {
        ConfigCommand::Check { file, json } => check(&file, json),
    }
}

fn check(file: &Path, json: bool) -> Result<()> {
    let c = Config::load(file)?;
    // What `serve` would refuse at its start, besides the file itself.
    compend::service::preflight(&c, false).with_context(|| format!("{}", file.display()))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&c)?);
    } else {
        println!(
            "{}: OK (rig {}, state {}, socket {})",
            file.display(),
            compend::rigs::rig_name(&c.rig),
            c.paths.state.display(),
            c.socket.path.display()
        );
        // The shipped file tries compend on the virtual rig; a projection PC changes it.
        let simulated = match c.rig.kind {
            compend::config::RigKind::Virtual => {
                Some(("virtual", "a simulated projector and camera"))
            }
            compend::config::RigKind::Window => Some((
                "window",
                "the projector window watched by a simulated camera",
            )),
            compend::config::RigKind::Camera => None,
        };
        if let Some((kind, what)) = simulated {
            println!(
                "note: [rig] kind = \"{kind}\" is {what}, for trying compend; for the \
                 projector and a camera set kind = \"camera\", camera and monitor (`compend \
                 cameras` lists the cameras)"
            );
        }
    }
    Ok(())
}
