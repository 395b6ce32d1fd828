//! `marionette studio`: the browser UI over the running loop.

use std::io::Write;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, TcpListener};
use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::{Arc, OnceLock};

use super::error::CliError;
use super::play::{finish, BusArg, LoopArgs, NoFigures};
use crate::control::Solve;
use crate::formats::{amc, asf};
use crate::profile::{Drive, Profile};
use crate::session::Session;
use crate::studio::access::{host_name, url_host, Access, AccessOptions};
use crate::studio::scene::Scene;
use crate::studio::server::Server;
use crate::studio::{server, Feed, ServoInfo, Studio, StudioSource};
use clap::Args;
use std::path::PathBuf;

/// Options of `marionette studio`.
#[derive(Debug)]
pub struct StudioArgs<'a> {
    /// Rig profile.
    pub profile: &'a Path,
    /// Skeleton.
    pub asf: &'a Path,
    /// Clip for the timeline.
    pub amc: Option<&'a Path>,
    /// Port on the listening address.
    pub port: u16,
    /// Address to listen on (default loopback).
    pub listen: Option<IpAddr>,
    /// Host names, origins and the token.
    pub access: AccessOptions,
}

/// Runs `marionette studio` until a stop request (or the loop's own end).
///
/// # Errors
/// [`CliError`].
pub fn studio_cmd(
    a: &StudioArgs<'_>,
    args: &LoopArgs,
    allocations: Option<fn() -> u64>,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    let profile = Profile::load(a.profile)?;
    let skeleton = Arc::new(asf::load(a.asf)?.skeleton);
    let clip = a.amc.map(|p| amc::load(&skeleton, p)).transpose()?;
    let addr = SocketAddr::new(a.listen.unwrap_or(IpAddr::V4(Ipv4Addr::LOCALHOST)), a.port);
    let listener =
        TcpListener::bind(addr).map_err(|e| CliError::Usage(format!("cannot listen on {addr}: {e}")))?;
    let local = listener.local_addr().map_err(CliError::Output)?;
    let access = Arc::new(Access::new(local.ip(), local.port(), &a.access).map_err(CliError::Usage)?);
    let servos = profile
        .servos
        .iter()
        .map(|s| ServoInfo {
            name: s.name.clone(),
            bone: match &s.drive {
                Drive::Bone { bone, .. } => Some(bone.clone()),
                Drive::Joint(_) => None,
            },
        })
        .collect();
    let scene = Scene::new(Arc::clone(&skeleton), clip.as_ref());
    let live = Arc::new(crate::control::live::LiveView::default());
    let session = Session::new(args.spec(false, Some(Arc::clone(&live)), allocations, out)?)?;
    let bus = match &args.bus {
        BusArg::Virtual => "the virtual chain".to_string(),
        BusArg::Sim => "the simulator".to_string(),
        BusArg::Port(p) => p.clone(),
    };
    // In real time the drags go straight into the loop's channel; in lockstep through the
    // source, which the simulator's clock drains.
    let (feed, lockstep) = if args.bus == BusArg::Sim {
        let (ptx, prx) = crossbeam_channel::bounded(256);
        (Feed::Lockstep(ptx), Some(prx))
    } else {
        (
            Feed::Direct {
                tx: session.input(),
                clock: OnceLock::new(),
            },
            None,
        )
    };
    let mut studio = Studio::new(scene, feed, servos, args.rate, bus).with_live_view(live);
    // A profile of robot joints: the robot is drawn beside the human.
    if profile.servos.iter().any(|s| matches!(s.drive, Drive::Joint(_))) {
        let setup = crate::retarget::Setup::new(&profile, &skeleton)?;
        let floor = match &clip {
            Some(m) => crate::retarget::floor_of_clip(&skeleton, m, &setup.map.human),
            None => crate::retarget::floor_of_rest(&skeleton, &setup.map.human),
        };
        studio = studio.with_robot(crate::studio::robot::RobotView::new(&setup, &skeleton, floor));
    }
    let studio = Arc::new(studio);
    let source = Box::new(StudioSource::new(Arc::clone(&studio), lockstep));
    let web = Arc::new(Server::new(Arc::clone(&studio), Arc::clone(&access)));
    let s = Arc::clone(&web);
    let http = std::thread::Builder::new()
        .name("studio-server".into())
        .spawn(move || server::serve(s, listener))
        .map_err(CliError::Output)?;
    // The URL to open: with the token when there is one (printed this once), under the
    // machine's name when the studio listens on every address.
    let host = if local.ip().is_unspecified() {
        host_name().unwrap_or_else(|| "127.0.0.1".into())
    } else {
        url_host(local.ip())
    };
    let url = match access.token() {
        Some(token) => format!("http://{host}:{}/?token={token}", local.port()),
        None => format!("http://{host}:{}/", local.port()),
    };
    if !access.loopback() {
        writeln!(
            out,
            "studio: listening on {local}, reachable from other machines: every request needs the token in the URL below"
        )?;
    }
    writeln!(
        out,
        "studio: {url} — {} effectors, {}; Ctrl-C stops (ramp to rest, torque off)",
        studio.scene().effectors.len(),
        if clip.is_some() {
            "timeline on the clip"
        } else {
            "rest pose"
        }
    )?;
    out.flush()?;
    let outcome = session.run(&profile, skeleton, Solve::Frames, clip.as_ref(), source, out);
    studio.stop.store(true, Ordering::Relaxed);
    let served = http.join();
    let outcome = outcome?;
    if let Ok(Err(e)) = served {
        writeln!(out, "studio server: {e}")?;
    }
    if web.access.refused.total() > 0 {
        writeln!(out, "studio refused: {}", web.access.refused.json())?;
    }
    let (l, r) = studio.latency();
    writeln!(
        out,
        "drag → Sync Write: {} drags carried, p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs from the browser's event (p50 {:.0} µs, p99 {:.0} µs from the server's receipt)",
        l.n, l.p50, l.p99, l.max, r.p50, r.p99
    )?;
    finish(&outcome, args, NoFigures {}, out)
}

/// The arguments of `marionette studio`.
#[cfg(feature = "studio")]
#[derive(Debug, Args)]
pub(super) struct StudioCmd {
    /// The rig profile.
    pub(super) profile: PathBuf,
    /// Skeleton (.asf).
    pub(super) asf: PathBuf,
    /// A clip (.amc) for the timeline: play, scrub, pin limbs while it plays.
    pub(super) amc: Option<PathBuf>,
    /// Port to serve on (0: any free one; the URL is printed).
    #[arg(long, default_value_t = 8080)]
    pub(super) port: u16,
    /// Listen on this address instead of loopback; other machines then need the token
    /// (printed in the URL once).
    #[arg(long)]
    pub(super) listen: Option<std::net::IpAddr>,
    /// Another host name the page may be reached by (NAME or NAME:PORT; a proxy's, an SSH
    /// tunnel's); repeatable.
    #[arg(long, value_name = "NAME")]
    pub(super) allow_host: Vec<String>,
    /// Another origin whose pages may drive the rig (scheme://host[:port]); repeatable.
    #[arg(long, value_name = "ORIGIN")]
    pub(super) allow_origin: Vec<String>,
    /// The token requests must carry (default: a random one per run when --listen is not
    /// loopback, none on loopback); better given in the environment than on the command
    /// line.
    #[arg(long, env = "MARIONETTE_STUDIO_TOKEN", hide_env_values = true)]
    pub(super) token: Option<String>,
    #[command(flatten)]
    pub(super) loop_args: LoopArgs,
}

#[cfg(feature = "studio")]
impl StudioCmd {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self, allocations: Option<fn() -> u64>) -> Result<(), CliError> {
        let StudioCmd {
            profile,
            asf,
            amc,
            port,
            listen,
            allow_host,
            allow_origin,
            token,
            loop_args,
        } = self;
        studio_cmd(
            &StudioArgs {
                profile: &profile,
                asf: &asf,
                amc: amc.as_deref(),
                port,
                listen,
                access: crate::studio::access::AccessOptions {
                    allow_hosts: allow_host,
                    allow_origins: allow_origin,
                    token,
                },
            },
            &loop_args,
            allocations,
            &mut std::io::stdout().lock(),
        )
    }
}
