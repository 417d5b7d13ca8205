//! `relocd run`: the daemon. The only async part of relocd: a single-threaded tokio runtime runs
//! the inputs (GameController, sensors, control socket, forwarded frames) and signals; one plain
//! thread owns the frame source and the network and does all blocking work.

pub mod config;
pub mod context;
pub mod publish;
pub mod queue;
pub mod record;
pub mod sockets;
pub mod source;
pub mod status;
pub mod triggers;
pub mod worker;

use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, bail};
use tokio::signal::unix::{SignalKind, signal};
use tracing::{info, warn};

use self::config::{Config, Listen, NO_MODEL, SensorInput, SourceSpec};
use self::publish::Publisher;
use self::queue::TriggerQueue;
use self::sockets::Datagram;
use self::source::forwarded::FrameQueue;
use self::source::{FrameSource, SourceSettings};
use self::status::Status;
use self::triggers::{Sensed, Triggers};
use self::worker::{ModelSlot, Worker};
use crate::geometry::{CameraIntrinsics, FieldDimensions, FieldModel};
use crate::pipeline::Pipeline;
use crate::posture::{PostureConfig, PostureDetector};
use crate::protocol::address::Address;
use crate::protocol::gamecontroller::PenaltyWatch;
use crate::refine::CalibrationTracker;
use crate::relocaliser::{self, Backend, Model};

/// Triggers waiting for the relocalisation thread on their own; more join a waiting one of their kind.
const TRIGGER_QUEUE: usize = 64;

/// Runs the daemon until SIGTERM or SIGINT.
pub fn run(config: Config) -> anyhow::Result<()> {
    config.validate()?;
    apply_process_settings(&config)?;
    let model = if config.lines_only() {
        info!("no network (model = \"{NO_MODEL}\"): the field lines alone, searched all over the field");
        None
    } else {
        Some(load_model(&config)?)
    };
    let contract = model.as_ref().map(Model::contract);
    let field = match &config.field {
        Some(path) => {
            let dimensions = FieldDimensions::load(path).context("the config's `field`")?;
            info!("field lines from {}", path.display());
            FieldModel::new(dimensions)
        }
        None => contract.map_or_else(FieldModel::default, |contract| FieldModel::new(contract.field.clone())),
    };
    let camera = contract.map_or_else(CameraIntrinsics::nao_top, |contract| contract.camera);
    let intrinsics = config.camera.intrinsics(camera).expect("validated with the config");
    let model_id = contract.map_or_else(|| NO_MODEL.to_string(), |contract| contract.model_id.clone());
    let status = Arc::new(Status::new(config.source.to_string(), model_id));
    let publisher = Publisher::new(config.publish.targets.clone(), config.publish.encoding)
        .context("cannot create the publishing sockets")?;

    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    let stop = Arc::new(AtomicBool::new(false));
    let queue = Arc::new(TriggerQueue::new(TRIGGER_QUEUE));
    let triggers = Triggers::new(queue.clone(), status.clone(), config.priors.belief_max_age_s);
    let sensed = Arc::new(Sensed::default());

    // Sockets are bound inside the runtime and owned by their tasks, which remove Unix socket files
    // when the runtime drops them at shutdown.
    // Signal handlers come first, so that a SIGTERM during start-up is a clean stop too.
    let (source, mut terminate, mut interrupt, mut hangup) = runtime.block_on(async {
        let terminate = signal(SignalKind::terminate())?;
        let interrupt = signal(SignalKind::interrupt())?;
        let hangup = signal(SignalKind::hangup())?;
        let source = open_source(&config, &field, &status)?;
        start_inputs(&config, &triggers, &sensed, &status)?;
        anyhow::Ok((source, terminate, interrupt, hangup))
    })?;
    drop(triggers);
    let replacement = Arc::new(ModelSlot::default());

    let pipeline = match model {
        Some(model) => {
            let pipeline = Pipeline::new(model);
            let pipeline = match intrinsics {
                Some(intrinsics) => pipeline.with_intrinsics(intrinsics),
                None => pipeline,
            };
            if config.refine {
                pipeline
                    .with_lines(&field)
                    .with_camera_correction(config.camera_correction)
                    .with_global_search(config.global_search)
            } else {
                pipeline
            }
        }
        None => Pipeline::lines_only(&field, intrinsics.unwrap_or(camera))
            .with_camera_correction(config.camera_correction),
    };
    let worker = Worker {
        pipeline,
        source,
        publisher,
        burst: config.burst.clone(),
        mounting: config.camera.mounting()?,
        sensed,
        status: status.clone(),
        stop: stop.clone(),
        replacement: replacement.clone(),
        priors: config.priors.clone(),
        goalkeeper: config.player.is_some_and(|player| player == config.priors.goalkeeper),
        calibration: (config.refine && config.camera_correction && config.learn_calibration)
            .then(CalibrationTracker::default),
    };
    // The sender drops when the thread ends, however it ends: a thread that died is noticed at once.
    let (alive, mut exited) = tokio::sync::oneshot::channel::<()>();
    let worker = std::thread::Builder::new()
        .name("relocalise".into())
        .spawn(move || {
            let _alive = alive;
            worker.run(&queue);
        })
        .context("cannot start the relocalisation thread")?;
    info!("relocd running: source {}, publishing to {}", config.source, targets(&config));

    let worker_died = runtime.block_on(async {
        loop {
            tokio::select! {
                _ = terminate.recv() => { info!("SIGTERM: shutting down"); break false }
                _ = interrupt.recv() => { info!("SIGINT: shutting down"); break false }
                _ = hangup.recv() => reload_model(&config, &replacement, &status),
                _ = &mut exited => break true,
            }
        }
    });
    stop.store(true, Ordering::Relaxed);
    // Dropping the runtime ends the input tasks, which closes the trigger channel.
    drop(runtime);
    if worker.join().is_err() || worker_died {
        bail!(
            "the relocalisation thread stopped unexpectedly (see the log above); exiting so the service restarts"
        );
    }
    info!("stopped");
    Ok(())
}

/// Loads the configured model and logs which it is and what runs it.
fn load_model(config: &Config) -> anyhow::Result<Model> {
    let (model, _) = relocaliser::load_model(config.model.as_deref(), config.load_options())?;
    let contract = model.contract();
    match config.backend {
        Backend::Tract => info!(
            "model {} ({}), tract kernels for {}",
            contract.model_id,
            contract.representation,
            relocaliser::kernel_isa()
        ),
        Backend::Onnxruntime => {
            info!("model {} ({}), ONNX Runtime", contract.model_id, contract.representation)
        }
    }
    Ok(model)
}

/// SIGHUP: loads the configured model file again and offers it to the relocalisation thread. A file
/// that cannot be used leaves the running model in place, and the log and `status` say why. Inputs
/// wait while the file loads (their datagrams queue in the kernel).
fn reload_model(config: &Config, replacement: &ModelSlot, status: &Status) {
    if config.lines_only() {
        warn!("SIGHUP: no model to reload (model = \"{NO_MODEL}\": the field lines alone)");
        return;
    }
    let Some(path) = &config.model else {
        warn!("SIGHUP: no model file to reload (the built-in model is in use)");
        return;
    };
    match relocaliser::load_model(Some(path), config.load_options()) {
        Ok((model, _)) => {
            let id = model.contract().model_id.clone();
            info!("SIGHUP: loaded {} ({id}); the next burst uses it", path.display());
            status.update(|report| {
                report.model = id;
                report.model_error = None;
            });
            replacement.offer(model);
        }
        Err(error) => {
            warn!("SIGHUP: keeping the running model: {error}");
            status.update(|report| report.model_error = Some(error.to_string()));
        }
    }
}

fn targets(config: &Config) -> String {
    config.publish.targets.iter().map(ToString::to_string).collect::<Vec<_>>().join(", ")
}

/// Niceness and CPU affinity, set before any other thread starts so that every thread inherits them.
fn apply_process_settings(config: &Config) -> anyhow::Result<()> {
    // SAFETY: setpriority only reads its integer arguments.
    if unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, config.process.nice) } != 0 {
        warn!("cannot set niceness {}: {}", config.process.nice, std::io::Error::last_os_error());
    }
    if let Some(cpu) = config.process.cpu {
        // SAFETY: the set is a plain bit mask on the stack, sized by the type passed in.
        let pinned = unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(cpu, &mut set);
            libc::sched_setaffinity(0, size_of::<libc::cpu_set_t>(), &set)
        };
        if pinned != 0 {
            bail!("cannot pin relocd to CPU {cpu}: {}", std::io::Error::last_os_error());
        }
        info!("pinned to CPU {cpu}");
    }
    Ok(())
}

/// The configured frame source; a forwarded-frame listener is started for `frames:`.
fn open_source(
    config: &Config,
    field: &FieldModel,
    status: &Arc<Status>,
) -> anyhow::Result<Box<dyn FrameSource>> {
    let frames = match &config.source {
        SourceSpec::Frames(path) => {
            let listener = sockets::bind_stream(path)
                .with_context(|| format!("cannot listen for forwarded frames on {}", path.display()))?;
            info!("forwarded frames: unix:{}", path.display());
            let queue = Arc::new(FrameQueue::new(config.frames.queue));
            tokio::spawn(source::forwarded::listen(listener, queue.clone(), status.clone()));
            Some(queue)
        }
        _ => None,
    };
    let settings = SourceSettings {
        camera: config.camera.clone(),
        sim: config.sim.clone(),
        field: field.clone(),
        looping: config.replay.looping,
    };
    source::open(&config.source, &settings, frames)
}

/// How far a listener reaches, for the start-up log: anything beyond loopback is a config choice
/// (the GameController's default is every interface, since its packets are broadcast on the team's
/// network), and the log says so.
fn reach(ip: IpAddr) -> &'static str {
    if ip.is_loopback() {
        "loopback only"
    } else if ip.is_unspecified() {
        "every interface: reachable from the network"
    } else {
        "reachable from the network"
    }
}

/// A listener and its reach.
fn described(address: &Address) -> String {
    match address {
        Address::Udp(socket) => format!("{address} ({})", reach(socket.ip())),
        Address::Unix(_) => format!("{address} (this machine, owner and group only)"),
    }
}

/// Binds the trigger inputs and starts their tasks.
fn start_inputs(
    config: &Config,
    triggers: &Triggers,
    sensed: &Arc<Sensed>,
    status: &Arc<Status>,
) -> anyhow::Result<()> {
    let gamecontroller = &config.gamecontroller;
    match (config.team, config.player) {
        (Some(team), Some(player)) if gamecontroller.enabled => {
            let address = SocketAddr::new(gamecontroller.address, gamecontroller.port);
            let socket = sockets::bind_udp(address, true)
                .with_context(|| format!("cannot listen for the GameController on {address}"))?;
            info!("GameController: team {team}, player {player}, on {address} ({})", reach(address.ip()));
            let watch = PenaltyWatch::new(team, player, gamecontroller.min_penalty_s);
            tokio::spawn(triggers::gamecontroller(
                Datagram::Udp(socket),
                config.max_datagram_bytes,
                watch,
                team,
                triggers.clone(),
                status.clone(),
            ));
        }
        _ if !gamecontroller.enabled => info!("GameController trigger off (gamecontroller.enabled = false)"),
        _ => info!("GameController trigger off (give team and player to turn it on)"),
    }

    let detector = PostureDetector::new(PostureConfig::default());
    match &config.sensors {
        SensorInput::Forwarded(Listen::Off) => info!("sensor input off: no fall or pick-up trigger"),
        SensorInput::Forwarded(Listen::At(address)) => {
            let socket =
                Datagram::bind(address).with_context(|| format!("cannot listen for sensors on {address}"))?;
            info!("sensors: {}", described(address));
            tokio::spawn(triggers::sensor_datagrams(
                socket,
                config.max_datagram_bytes,
                detector,
                sensed.clone(),
                triggers.clone(),
                status.clone(),
            ));
        }
        SensorInput::Lola(path) => {
            tokio::spawn(triggers::lola_stream(
                path.clone(),
                detector,
                sensed.clone(),
                triggers.clone(),
                status.clone(),
            ));
        }
    }

    if let Listen::At(address) = &config.control {
        let socket =
            Datagram::bind(address).with_context(|| format!("cannot open the control socket {address}"))?;
        info!("control: {}", described(address));
        tokio::spawn(triggers::control(socket, config.max_datagram_bytes, triggers.clone(), status.clone()));
    }
    Ok(())
}
