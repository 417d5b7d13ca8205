//! The `relocd` command line: parses arguments and calls one library function per subcommand.
//! Logs go to stderr; stdout carries only each command's result.

use std::io::IsTerminal;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use tracing::info;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

use relocd::bench::Stage;
use relocd::daemon::config::{Config, Listen, NO_MODEL, SensorInput, SourceSpec, log_filter};
use relocd::daemon::record::RecordOptions;
use relocd::frame::{Frame, YuyvImage};
use relocd::geometry::{CameraIntrinsics, CameraPose, FieldDimensions, FieldModel, Representation};
use relocd::pipeline::priors::simulate::PriorSpec;
use relocd::pipeline::{GlobalSearch, Pipeline};
use relocd::protocol::address::Address;
use relocd::protocol::message::Encoding;
use relocd::recording::{FrameFormat, Recording};
use relocd::relocaliser::{self, Backend, LoadOptions, Model};
use relocd::replay::ReplayOptions;
use relocd::sim::{DatasetSpec, Randomisation, render_dataset};

/// Relocalise a Nao on the SPL field from one camera image.
#[derive(Debug, Parser)]
#[command(name = "relocd", version, about, long_about = None)]
struct Cli {
    /// Log level for messages on stderr (error, warn, info, debug, trace), or targets and levels such
    /// as warn,relocd=debug [default: info, or the config's `log_level` for `run`].
    #[arg(long, global = true, env = "RELOCD_LOG")]
    log_level: Option<String>,

    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Render a recording of randomised, labelled frames as the Nao top camera sees them.
    Render(RenderArgs),
    /// Relocalise every frame of a recording: one JSON line per frame, and the thesis' metrics
    /// (on stderr, and with --metrics-json as a file) where the recording has true poses.
    Replay(ReplayArgs),
    /// Show the line percepts of image files or recordings, as a team checks a new hall: one JSON
    /// line per frame (carpet edge, line points in pixels and on the ground), overlays with --out.
    Inspect(InspectArgs),
    /// Print the field description relocd uses (TOML, metres); edit a copy for another field.
    Field(FieldArgs),
    /// Run the daemon: relocalise on a penalty return, a fall, a pick-up or a request, and publish the
    /// hypotheses. Flags override the config file's keys.
    Run(RunArgs),
    /// Record frames from the camera (V4L2) or the forwarded-frame socket into a recording, with
    /// capture times and camera poses, to replay later; stops after --count frames, --seconds, or
    /// Ctrl-C.
    Record(RecordArgs),
    /// Time each stage of a relocalisation on this machine (one thread): preprocessing a 640×480 YUYV
    /// frame, inference, unfolding, burst fusion and a whole frame; prints the medians.
    Bench(BenchArgs),
}

/// Which model, run by which engine.
#[derive(Debug, clap::Args)]
struct ModelArgs {
    /// ONNX model file [default: the built-in SqueezeNet half-point model for the engine]; `replay`
    /// and `run` also take `none`: no network, the field lines alone.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Inference engine: tract (built in) or onnxruntime (needs the onnxruntime feature and
    /// libonnxruntime.so; ORT_DYLIB_PATH names the file). Each has its own built-in model.
    #[arg(long, value_enum)]
    backend: Option<Backend>,
}

impl ModelArgs {
    /// Whether `--model none` asks for no network at all.
    fn is_none(&self) -> bool {
        self.model.as_deref() == Some(Path::new(NO_MODEL))
    }

    /// Loads the model; returns it with the name to report.
    fn load(&self) -> anyhow::Result<(Model, String)> {
        let options = LoadOptions { backend: self.backend.unwrap_or_default(), representation: None };
        Ok(relocaliser::load_model(self.model.as_deref(), options)?)
    }
}

#[derive(Debug, clap::Args)]
struct BenchArgs {
    #[command(flatten)]
    model: ModelArgs,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    /// Timed runs per stage.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    iterations: u32,
    /// Time only these stages (repeatable): preprocess, inference, unfold, fusion, lines, refine, search,
    /// total, burst.
    #[arg(long)]
    stage: Vec<Stage>,
    /// Relocalise this image (PNG or JPEG) instead of a rendered 640×480 YUYV frame; timed as the
    /// camera streams it (YUYV) where its width is even.
    #[arg(long)]
    frame: Option<PathBuf>,
    /// Height of the --frame's camera above the ground, metres [default: a standing Nao's, 0.5].
    #[arg(long, requires = "frame")]
    camera_height: Option<f64>,
    /// Pitch of the --frame's camera, degrees, positive looks down [default: a standing Nao's, 1.2].
    #[arg(long, requires = "frame", allow_negative_numbers = true)]
    camera_pitch: Option<f64>,
    /// Roll of the --frame's camera, degrees [default: 0].
    #[arg(long, requires = "frame", allow_negative_numbers = true)]
    camera_roll: Option<f64>,
    /// Frames of line points the refine and search stages fit: the benchmark frame's, repeated, as a
    /// standing robot's burst gives them (the daemon fits a burst of five).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=16))]
    line_frames: u32,
}

#[derive(Debug, clap::Args)]
struct RecordArgs {
    /// Directory to write the recording to (created; must not already hold one).
    #[arg(long)]
    out: PathBuf,
    /// Frame source: v4l:DEVICE, frames:unix:PATH (a team's process forwards frames) or sim.
    #[arg(long, default_value = "v4l:/dev/video-top")]
    source: SourceSpec,
    /// Stop after this many frames.
    #[arg(long, default_value_t = 100)]
    count: u64,
    /// Stop after this many seconds.
    #[arg(long)]
    seconds: Option<f64>,
    /// Frames kept per second (the camera runs at its own rate).
    #[arg(long, default_value_t = 5.0)]
    fps: f64,
    /// Frame file format: raw YUYV keeps the camera's bytes; PNG and JPEG are smaller.
    #[arg(long, value_enum, default_value_t = FormatArg::Yuyv)]
    format: FormatArg,
    /// TOML config whose [camera] section sets the V4L2 size and rate (see deploy/relocd.toml).
    #[arg(long, short)]
    config: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct RunArgs {
    /// TOML config (see deploy/relocd.toml); without it, every key has its Nao default.
    #[arg(long, short)]
    config: Option<PathBuf>,
    /// Frame source: v4l:DEVICE, frames:unix:PATH, replay:DIR or sim.
    #[arg(long)]
    source: Option<SourceSpec>,
    #[command(flatten)]
    model: ModelArgs,
    /// Field description file (TOML or JSON, see `relocd field`) whose lines the frames are checked
    /// against (config `field`) [default: the model contract's field].
    #[arg(long, value_name = "FILE")]
    field: Option<PathBuf>,
    /// Decode the model's outputs in this representation instead of its contract's.
    #[arg(long)]
    representation: Option<Representation>,
    /// Our team number (turns the GameController trigger on, with --player).
    #[arg(long)]
    team: Option<u8>,
    /// Our player number, 1-20.
    #[arg(long)]
    player: Option<u8>,
    /// GameController UDP port.
    #[arg(long)]
    gc_port: Option<u16>,
    /// Sensor input: unix:PATH, udp:IP:PORT, lola:PATH or off.
    #[arg(long)]
    sensors: Option<SensorInput>,
    /// Control socket: unix:PATH, udp:IP:PORT or off.
    #[arg(long)]
    control: Option<Listen>,
    /// Publish target, udp:IP:PORT or unix:PATH; repeat for several (replaces the config's list).
    #[arg(long)]
    publish: Vec<Address>,
    /// Message encoding: json or msgpack.
    #[arg(long)]
    encoding: Option<Encoding>,
    /// Frames per burst.
    #[arg(long)]
    burst: Option<usize>,
    /// Head yaw assumed when the trigger and frame give none, degrees.
    #[arg(long, allow_negative_numbers = true)]
    head_yaw: Option<f64>,
    /// Publish the network's hypotheses without checking them against the field lines (config
    /// `refine = false`).
    #[arg(long)]
    no_refine: bool,
}

#[derive(Debug, clap::Args)]
struct RenderArgs {
    /// Directory to write the recording to (created; must not already hold one).
    #[arg(long, default_value = "relocd-render")]
    out: PathBuf,
    /// Number of frames.
    #[arg(long, default_value_t = 16)]
    count: u64,
    /// Seed: the same seed renders the same frames.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Image width in pixels (the field of view stays the Nao's).
    #[arg(long, default_value_t = 640)]
    width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// What lies beyond the carpet.
    #[arg(long, value_enum, default_value_t = SurroundingsArg::Black)]
    surroundings: SurroundingsArg,
    /// Add what real halls show: shadows, a textured and worn carpet, motion blur, exposure and
    /// white-balance errors, robots at the border and the cluttered hall (implies asymmetric).
    #[arg(long)]
    hall_realism: bool,
    /// Frame file format.
    #[arg(long, value_enum, default_value_t = FormatArg::Png)]
    format: FormatArg,
    /// Rays per pixel along each axis, for anti-aliasing (1 to 8).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=8))]
    supersample: u32,
    /// Most other robots on the carpet per frame.
    #[arg(long, default_value_t = 6)]
    max_robots: usize,
    /// Probability that the ball is on the carpet.
    #[arg(long, default_value_t = 0.7)]
    ball_probability: f64,
    /// Probability that the goals have nets.
    #[arg(long, default_value_t = 0.5)]
    net_probability: f64,
    /// Largest head yaw in degrees (uniform in ±this); 0 looks along the robot's heading.
    #[arg(long, default_value_t = 0.0)]
    max_head_yaw: f64,
    /// Where poses are drawn: uniform over the carpet, or where a robot is put back after a penalty.
    #[arg(long, value_enum, default_value_t = PosesArg::Uniform)]
    poses: PosesArg,
    /// Frames per pose: bursts of a standing robot (camera sway, head yaw and noise vary) for testing
    /// burst fusion with `replay --burst N`.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    burst: u16,
    /// Camera height range in metres, MIN,MAX.
    #[arg(long, default_value = "0.45,0.53", value_parser = parse_range)]
    camera_height: RangeInclusive<f64>,
    /// Camera pitch range in degrees (positive looks down), MIN,MAX.
    #[arg(long, default_value = "0,20", value_parser = parse_range)]
    camera_pitch: RangeInclusive<f64>,
    /// Largest camera roll in degrees (uniform in ±this).
    #[arg(long, default_value_t = 3.0)]
    max_camera_roll: f64,
    /// Horizontal field of view in degrees.
    #[arg(long, default_value_t = 54.7)]
    horizontal_fov: f64,
    /// Vertical field of view in degrees.
    #[arg(long, default_value_t = 42.5)]
    vertical_fov: f64,
    /// Field description file (TOML or JSON, see `relocd field`); default: SPL 2025.
    #[arg(long)]
    field: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct ReplayArgs {
    /// Recording directory (frames.jsonl and frames); default: the sample recording in tests/data/sample.
    recording: Option<PathBuf>,
    #[command(flatten)]
    model: ModelArgs,
    /// Write the metrics as JSON to this file.
    #[arg(long)]
    metrics_json: Option<PathBuf>,
    /// Also fuse every N consecutive frames (one standing robot, e.g. `render --burst N`) and write one
    /// more line per burst.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    burst: u16,
    /// Re-weight each burst's hypotheses (each frame's when --burst is 1) with a game-context prior;
    /// repeat to combine. `penalty-return`, `own-half`, `belief:X,Y,THETA_DEG[,SIGMA_M[,SIGMA_DEG]]`,
    /// or drawn around the recording's true pose: `belief-near:ERR_M,ERR_DEG` (a right belief),
    /// `belief-flipped:ERR_M,ERR_DEG` (its point reflection), `ball:NOISE_M[,TEAMMATES]` and
    /// `ball-flipped:NOISE_M[,TEAMMATES]` (own ball 0.5–4 m ahead, team ball within NOISE_M). The
    /// metrics gain a `twins` block: how often the heaviest hypothesis is the right twin.
    #[arg(long, value_name = "SPEC")]
    prior: Vec<PriorSpec>,
    /// Seed for the priors drawn around the true pose.
    #[arg(long, default_value_t = 0)]
    prior_seed: u64,
    /// The priors' floor: no hypothesis ends below min(its weight before the priors, this).
    #[arg(long, default_value_t = relocd::pipeline::priors::DEFAULT_MIN_SHARE)]
    min_share: f64,
    /// Verify and refine each burst's hypotheses (each frame's when --burst is 1) against the field
    /// lines in its frames; needs the recording's camera poses. The metrics gain a `refined` block.
    #[arg(long)]
    refine: bool,
    /// With --refine: when the lines also look for places all over the field (never, when_unsure:
    /// when the network's heaviest hypothesis is not refined, or always).
    #[arg(long, default_value = "when_unsure", value_name = "WHEN")]
    global_search: GlobalSearch,
    /// With --refine: the field description file (TOML or JSON, see `relocd field`) whose lines the
    /// frames are checked against, e.g. a lab's field [default: the model contract's field].
    #[arg(long, value_name = "FILE")]
    field: Option<PathBuf>,
    #[command(flatten)]
    field_of_view: FieldOfViewArgs,
    /// With --refine: the recorded camera poses are exact (rendered frames), so the line fits estimate
    /// no correction of the camera's pitch and roll (they do by default, as on a robot).
    #[arg(long)]
    exact_camera: bool,
    /// Added to every recorded camera pitch, degrees (positive looks down): a robot's calibration, or
    /// a deliberate error to see what one costs.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_name = "DEG")]
    camera_pitch_offset: f64,
    /// Added to every recorded camera roll, degrees.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_name = "DEG")]
    camera_roll_offset: f64,
    /// Standard deviation of a further pitch and roll error drawn for every burst, degrees (seeded by
    /// --prior-seed): a robot's stance moving its camera between bursts, on top of the offsets.
    #[arg(long, default_value_t = 0.0, value_name = "DEG")]
    camera_jitter: f64,
    /// With --refine: every burst starts from the recorded camera poses; by default the camera's
    /// calibration error is learnt over the bursts (one robot's recording), as the daemon does.
    #[arg(long)]
    fixed_calibration: bool,
    /// With --refine: also check the lines at each burst's recorded true pose (verdict, shares, the
    /// points off the lines and the expected lines unseen, the fit from it): whether the percepts and
    /// the verification accept the right answer, e.g. in a new hall with ground truth.
    #[arg(long)]
    check_truth: bool,
    /// Write plots (error scatter, field map with true and predicted poses) as PNG into this directory.
    #[cfg(feature = "report")]
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
}

/// The robot camera's field of view, where it is not the one the model was trained for.
#[derive(Debug, clap::Args)]
struct FieldOfViewArgs {
    /// Horizontal field of view of the camera that took the frames, degrees [default: the model
    /// contract's; the Nao top camera's 54.7 without a model].
    #[arg(long, value_name = "DEG")]
    horizontal_fov: Option<f64>,
    /// Its vertical field of view, degrees [default: as --horizontal-fov; 42.5].
    #[arg(long, value_name = "DEG")]
    vertical_fov: Option<f64>,
}

impl FieldOfViewArgs {
    /// `base` with the field of view the flags give.
    fn applied_to(&self, base: CameraIntrinsics) -> anyhow::Result<CameraIntrinsics> {
        base.with_field_of_view(self.horizontal_fov, self.vertical_fov).map_err(|(axis, degrees)| {
            anyhow::anyhow!("--{axis}-fov {degrees}: expected degrees in (1, 170)")
        })
    }
}

#[derive(Debug, clap::Args)]
struct InspectArgs {
    /// Image files (PNG or JPEG) or recording directories.
    #[arg(required = true)]
    paths: Vec<PathBuf>,
    /// Camera height above the ground, metres [default: the recording's camera, else the config's].
    #[arg(long)]
    camera_height: Option<f64>,
    /// Camera pitch, degrees, positive looks down [default: as --camera-height].
    #[arg(long, allow_negative_numbers = true)]
    camera_pitch: Option<f64>,
    /// Camera roll, degrees [default: as --camera-height].
    #[arg(long, allow_negative_numbers = true)]
    camera_roll: Option<f64>,
    /// The camera pose is unknown: image stage only (carpet and line crossings, no ground-width
    /// gate, no ground points).
    #[arg(long, conflicts_with_all = ["camera_height", "camera_pitch", "camera_roll"])]
    no_camera: bool,
    #[command(flatten)]
    field_of_view: FieldOfViewArgs,
    /// TOML config whose [camera] section gives the default camera pose.
    #[arg(long, short)]
    config: Option<PathBuf>,
    /// Field description file (TOML or JSON, see `relocd field`): its line width gates the points and
    /// its lines are drawn under a recording's true poses; default: SPL 2025.
    #[arg(long)]
    field: Option<PathBuf>,
    /// Write an overlay PNG per frame into this directory: carpet edge (yellow), line points
    /// (magenta), crossings the ground gate dropped (red), field lines under the true pose (cyan).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct FieldArgs {
    /// Print this field file's description (validated) instead of the default.
    #[arg(long)]
    field: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum SurroundingsArg {
    /// Black beyond the carpet, as in the thesis: the field's symmetry holds.
    Black,
    /// A hall with random coloured wall panels: breaks the symmetry.
    Asymmetric,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum PosesArg {
    /// Uniform over the carpet, any heading.
    Uniform,
    /// Beside either touchline in the own half, facing the field (the penalty-return placement).
    PenaltyReturn,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum FormatArg {
    /// PNG (RGB).
    Png,
    /// JPEG (RGB).
    Jpeg,
    /// Raw packed YUYV 4:2:2, as the camera streams.
    Yuyv,
}

impl From<FormatArg> for FrameFormat {
    fn from(format: FormatArg) -> Self {
        match format {
            FormatArg::Png => FrameFormat::Png,
            FormatArg::Jpeg => FrameFormat::Jpeg,
            FormatArg::Yuyv => FrameFormat::Yuyv,
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Run(args) => run(args, cli.log_level),
        command => match init_logging(cli.log_level.as_deref().unwrap_or("info")) {
            Ok(()) => match command {
                Command::Render(args) => render(args),
                Command::Replay(args) => replay(args),
                Command::Field(args) => field(args),
                Command::Inspect(args) => inspect(args),
                Command::Record(args) => record(args),
                Command::Bench(args) => bench(args),
                Command::Run(_) => unreachable!("handled above"),
            },
            Err(error) => Err(error),
        },
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {error:#}");
            ExitCode::FAILURE
        }
    }
}

fn init_logging(filter: &str) -> anyhow::Result<()> {
    let filter = log_filter(filter).map_err(|error| {
        anyhow::anyhow!("bad --log-level {filter:?}: {error}; expected e.g. info, debug or warn,relocd=trace")
    })?;
    let output = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal());
    tracing_subscriber::registry().with(output).with(filter).init();
    Ok(())
}

fn run(args: RunArgs, log_level: Option<String>) -> anyhow::Result<()> {
    let mut config = match &args.config {
        Some(path) => Config::load(path)?,
        None => Config::default(),
    };
    let RunArgs {
        source,
        model: ModelArgs { model, backend },
        representation,
        team,
        player,
        gc_port,
        sensors,
        control,
        ..
    } = args;
    config.source = source.unwrap_or(config.source);
    config.model = model.or(config.model);
    config.backend = backend.unwrap_or(config.backend);
    config.representation = representation.or(config.representation);
    config.team = team.or(config.team);
    config.player = player.or(config.player);
    config.gamecontroller.port = gc_port.unwrap_or(config.gamecontroller.port);
    config.sensors = sensors.unwrap_or(config.sensors);
    config.control = control.unwrap_or(config.control);
    config.publish.encoding = args.encoding.unwrap_or(config.publish.encoding);
    config.burst.frames = args.burst.unwrap_or(config.burst.frames);
    config.camera.head_yaw_deg = args.head_yaw.unwrap_or(config.camera.head_yaw_deg);
    config.field = args.field.or(config.field);
    if args.no_refine {
        config.refine = false;
    }
    config.log_level = log_level.unwrap_or(config.log_level);
    if !args.publish.is_empty() {
        config.publish.targets = args.publish;
    }
    config.validate()?;
    init_logging(&config.log_level)?;
    relocd::daemon::run(config)
}

fn record(args: RecordArgs) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => Config::load(path)?,
        None => Config::default(),
    };
    config.validate()?;
    let duration = match args.seconds {
        Some(seconds) if !(seconds > 0.0 && seconds <= 86_400.0) => {
            bail!("--seconds {seconds}: expected a duration in (0, 86400]")
        }
        seconds => seconds.map(std::time::Duration::from_secs_f64),
    };
    let options = RecordOptions {
        source: args.source,
        out: args.out,
        count: args.count,
        duration,
        fps: args.fps,
        format: args.format.into(),
        camera: config.camera,
        queue: config.frames.queue,
    };
    let progress = ProgressBar::new(options.count).with_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} frames")
            .expect("valid progress template")
            .progress_chars("=> "),
    );
    let summary = relocd::daemon::record::record(&options, |frames| progress.set_position(frames))?;
    progress.finish_and_clear();
    info!(frames = summary.frames, seconds = summary.seconds, rejected = summary.rejected, "recorded");
    println!(
        "{}",
        serde_json::json!({
            "recording": options.out.display().to_string(),
            "frames": summary.frames,
            "seconds": summary.seconds,
        })
    );
    Ok(())
}

fn bench(args: BenchArgs) -> anyhow::Result<()> {
    let (model, name) = args.model.load()?;
    let frame = match &args.frame {
        Some(path) => {
            let image = image::open(path).with_context(|| format!("--frame {}", path.display()))?;
            let standing = CameraPose::STANDING;
            let camera = CameraPose::new(
                args.camera_height.unwrap_or(standing.height()),
                args.camera_pitch.map_or(standing.pitch(), f64::to_radians),
                args.camera_roll.map_or(standing.roll(), f64::to_radians),
                0.0,
            )
            .context("--camera-height/--camera-pitch/--camera-roll")?;
            let rgb = image.to_rgb8();
            let frame = match YuyvImage::from_rgb(&rgb) {
                Ok(yuyv) => Frame::Yuyv(yuyv),
                Err(_) => Frame::Rgb(rgb),
            };
            Some((frame, camera))
        }
        None => None,
    };
    let stages = if args.stage.is_empty() { Stage::ALL.to_vec() } else { args.stage };
    let report =
        relocd::bench::run(model, name, frame, &stages, args.iterations as usize, args.line_frames as usize)?;
    if args.json {
        println!("{}", serde_json::to_string(&report).expect("the report serialises"));
    } else {
        print!("{report}");
    }
    Ok(())
}

fn load_field(path: Option<&Path>) -> anyhow::Result<FieldModel> {
    let dimensions = match path {
        Some(path) => FieldDimensions::load(path)?,
        None => FieldDimensions::spl_2025(),
    };
    Ok(FieldModel::new(dimensions))
}

fn render(args: RenderArgs) -> anyhow::Result<()> {
    if args.width < 2 || args.height < 1 || args.width % 2 != 0 {
        bail!(
            "--width {} --height {}: the width must be even (YUYV pairs pixels) and both positive",
            args.width,
            args.height
        );
    }
    for (name, value) in
        [("--ball-probability", args.ball_probability), ("--net-probability", args.net_probability)]
    {
        if !(0.0..=1.0).contains(&value) {
            bail!("{name} {value}: expected a probability in [0, 1]");
        }
    }
    if !(0.0..180.0).contains(&args.max_head_yaw) {
        bail!("--max-head-yaw {}: expected degrees in [0, 180)", args.max_head_yaw);
    }
    if !(0.0..90.0).contains(&args.max_camera_roll) {
        bail!("--max-camera-roll {}: expected degrees in [0, 90)", args.max_camera_roll);
    }
    if *args.camera_height.start() <= 0.0 || *args.camera_height.end() > 5.0 {
        bail!("--camera-height {:?}: expected metres in (0, 5]", args.camera_height);
    }
    if *args.camera_pitch.start() <= -90.0 || *args.camera_pitch.end() >= 90.0 {
        bail!("--camera-pitch {:?}: expected degrees in (-90, 90)", args.camera_pitch);
    }
    for (name, value) in [("--horizontal-fov", args.horizontal_fov), ("--vertical-fov", args.vertical_fov)] {
        if !(value > 1.0 && value < 170.0) {
            bail!("{name} {value}: expected degrees in (1, 170)");
        }
    }
    let spec = DatasetSpec {
        field: load_field(args.field.as_deref())?,
        intrinsics: CameraIntrinsics {
            width: args.width,
            height: args.height,
            horizontal_fov: args.horizontal_fov.to_radians(),
            vertical_fov: args.vertical_fov.to_radians(),
        },
        randomisation: Randomisation {
            max_robots: args.max_robots,
            ball_probability: args.ball_probability,
            net_probability: args.net_probability,
            max_head_yaw: args.max_head_yaw.to_radians(),
            camera_height: args.camera_height.clone(),
            camera_pitch: args.camera_pitch.start().to_radians()..=args.camera_pitch.end().to_radians(),
            camera_roll: -args.max_camera_roll.to_radians()..=args.max_camera_roll.to_radians(),
            asymmetric_surroundings: matches!(args.surroundings, SurroundingsArg::Asymmetric),
            penalty_return: matches!(args.poses, PosesArg::PenaltyReturn),
            hall_realism: args.hall_realism,
            ..Randomisation::default()
        },
        supersample: args.supersample,
        format: args.format.into(),
        count: args.count,
        seed: args.seed,
        burst: args.burst.into(),
        frames_per_second: 30.0,
    };
    info!(out = %args.out.display(), count = args.count, seed = args.seed, width = args.width, height = args.height, "rendering");
    let progress = ProgressBar::new(args.count).with_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} frames, {per_sec}, eta {eta}")
            .expect("valid progress template")
            .progress_chars("=> "),
    );
    let started = std::time::Instant::now();
    render_dataset(&spec, &args.out, || progress.inc(1))
        .with_context(|| format!("rendering into {}", args.out.display()))?;
    progress.finish_and_clear();
    let seconds = started.elapsed().as_secs_f64();
    info!(seconds, frames_per_second = args.count as f64 / seconds.max(1e-9), "done");
    println!(
        "{}",
        serde_json::json!({
            "recording": args.out,
            "frames": args.count,
            "width": args.width,
            "height": args.height,
            "seed": args.seed,
        })
    );
    Ok(())
}

/// The sample recording checked into the repository, used when `replay` gets no recording.
const SAMPLE_RECORDING: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/sample");

fn replay(args: ReplayArgs) -> anyhow::Result<()> {
    let directory = args.recording.unwrap_or_else(|| PathBuf::from(SAMPLE_RECORDING));
    let recording = Recording::open(&directory).with_context(|| {
        format!(
            "opening recording {} (pass a recording directory as the first argument)",
            directory.display()
        )
    })?;
    anyhow::ensure!(
        (0.0..=0.5).contains(&args.min_share),
        "--min-share {} is not in [0, 0.5]: it is the weight share a prior cannot push a hypothesis below",
        args.min_share
    );
    for (flag, offset) in [
        ("--camera-pitch-offset", args.camera_pitch_offset),
        ("--camera-roll-offset", args.camera_roll_offset),
    ] {
        anyhow::ensure!(offset.abs() <= 30.0, "{flag} {offset}: expected degrees within ±30");
    }
    anyhow::ensure!(
        (0.0..=10.0).contains(&args.camera_jitter),
        "--camera-jitter {}: expected a standard deviation of 0 to 10 degrees",
        args.camera_jitter
    );
    anyhow::ensure!(
        !args.check_truth || args.refine || args.model.is_none(),
        "--check-truth checks the lines at the true pose: add --refine"
    );
    let lab_field = args.field.as_deref().map(|path| load_field(Some(path))).transpose()?;
    let (pipeline, field) = if args.model.is_none() {
        info!(recording = %directory.display(), frames = recording.records().len(), "replaying with the lines alone");
        let field = lab_field.unwrap_or_default();
        let intrinsics = args.field_of_view.applied_to(CameraIntrinsics::nao_top())?;
        (Pipeline::lines_only(&field, intrinsics).with_camera_correction(!args.exact_camera), field)
    } else {
        let (model, _) = args.model.load()?;
        let contract = model.contract();
        info!(
            model = %contract.model_id,
            representation = %contract.representation,
            isa = %relocaliser::kernel_isa(),
            recording = %directory.display(),
            frames = recording.records().len(),
            "replaying"
        );
        let intrinsics = args.field_of_view.applied_to(contract.camera)?;
        let field = lab_field.unwrap_or_else(|| FieldModel::new(contract.field.clone()));
        let pipeline = Pipeline::new(model).with_intrinsics(intrinsics);
        let pipeline = if args.refine { pipeline.with_lines(&field) } else { pipeline };
        (pipeline.with_camera_correction(!args.exact_camera).with_global_search(args.global_search), field)
    };
    let stdout = std::io::stdout();
    let summary = relocd::replay::replay(
        &recording,
        &pipeline,
        &ReplayOptions {
            burst: args.burst.into(),
            priors: args.prior.clone(),
            prior_seed: args.prior_seed,
            min_share: args.min_share,
            camera_offset: (args.camera_pitch_offset.to_radians(), args.camera_roll_offset.to_radians()),
            camera_jitter: args.camera_jitter.to_radians(),
            learn_calibration: !args.fixed_calibration,
            check_truth: args.check_truth,
        },
        &mut stdout.lock(),
    )
    .context("writing results")?;
    if let Some(calibration) = &summary.calibration {
        info!(%calibration, "camera calibration learnt");
    }
    // The field is only drawn in the report plots.
    #[cfg(not(feature = "report"))]
    drop(field);
    #[cfg(feature = "report")]
    if let Some(directory) = &args.report {
        let written =
            relocd::report::write_report(directory, &summary.evaluations, &field).context("--report")?;
        info!(plots = ?written, "report written");
    }
    if let Some(metrics) = &summary.metrics {
        eprintln!("{}", metrics.table());
        if let Some(path) = &args.metrics_json {
            let json = serde_json::to_string_pretty(metrics).expect("metrics serialise");
            std::fs::write(path, json + "\n").with_context(|| format!("writing {}", path.display()))?;
        }
    } else if let Some(lines) = &summary.lines_alone {
        eprintln!("{} bursts, lines alone: {}", lines.bursts, lines.verdicts());
        if let Some(at_truth) = &lines.at_truth {
            eprintln!("{}", at_truth.line());
        }
        if let Some(path) = &args.metrics_json {
            let json = serde_json::to_string_pretty(lines).expect("metrics serialise");
            std::fs::write(path, json + "\n").with_context(|| format!("writing {}", path.display()))?;
        }
    } else if args.metrics_json.is_some() {
        bail!("--metrics-json: the recording has no true poses to measure against");
    }
    if summary.failed > 0 {
        bail!(
            "{} of {} frames could not be relocalised (see their lines and the log)",
            summary.failed,
            summary.frames
        );
    }
    Ok(())
}

/// Parses `MIN,MAX` into an inclusive range of finite numbers with MIN <= MAX.
fn parse_range(text: &str) -> Result<RangeInclusive<f64>, String> {
    let (low, high) = text.split_once(',').ok_or_else(|| format!("expected MIN,MAX, found {text:?}"))?;
    let number = |part: &str| {
        part.trim()
            .parse::<f64>()
            .ok()
            .filter(|value| value.is_finite())
            .ok_or_else(|| format!("{part:?} is not a number"))
    };
    let (low, high) = (number(low)?, number(high)?);
    if low > high {
        return Err(format!("MIN {low} is greater than MAX {high}"));
    }
    Ok(low..=high)
}

fn inspect(args: InspectArgs) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => Config::load(path)?,
        None => Config::default(),
    };
    config.validate()?;
    let mut camera = config.camera;
    let overridden =
        args.camera_height.is_some() || args.camera_pitch.is_some() || args.camera_roll.is_some();
    camera.height_m = args.camera_height.unwrap_or(camera.height_m);
    camera.pitch_deg = args.camera_pitch.unwrap_or(camera.pitch_deg);
    camera.roll_deg = args.camera_roll.unwrap_or(camera.roll_deg);
    let pose =
        camera.mounting().context("--camera-height/--camera-pitch/--camera-roll")?.pose_on(None, None)?;
    let image_files = args.paths.iter().any(|path| !Recording::is_at(path));
    if image_files && !overridden && !args.no_camera {
        eprintln!(
            "relocd inspect: an image file carries no camera pose; its line points are gated under the \
             config's camera with the head at zero (height {:.2} m, pitch {:.1}°, roll {:.1}°). Give \
             --camera-height/--camera-pitch as the robot held its head, or --no-camera for the image \
             stage alone.",
            camera.height_m, camera.pitch_deg, camera.roll_deg
        );
    }
    let options = relocd::inspect::InspectOptions {
        intrinsics: args.field_of_view.applied_to(CameraIntrinsics::nao_top())?,
        camera: (!args.no_camera).then_some(pose),
        override_recorded_camera: overridden || args.no_camera,
        field: load_field(args.field.as_deref())?,
        out: args.out,
    };
    let mut stdout = std::io::stdout().lock();
    relocd::inspect::inspect(&args.paths, &options, |inspection| {
        use std::io::Write;
        let line = serde_json::to_string(&inspection).expect("an inspection serialises");
        // A closed stdout (e.g. `| head`) ends the output, not the command with a panic.
        let _ = writeln!(stdout, "{line}");
    })?;
    Ok(())
}

fn field(args: FieldArgs) -> anyhow::Result<()> {
    let model = load_field(args.field.as_deref())?;
    print!("{}", model.dimensions().to_toml());
    Ok(())
}
