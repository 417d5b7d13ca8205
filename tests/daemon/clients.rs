//! The clients teams integrate, each against a running daemon: the Rust `relocd::client` module, the
//! Python and C++ clients in `examples/` (the C++ one compiled here with g++), and the Python and C++
//! examples that forward a frame and a trigger.

use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use relocd::client::{Address, Control, Subscriber};
use relocd::protocol::message::TriggerKind;

use crate::harness::{Daemon, sample_yuyv};

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples").join(name)
}

/// A UDP port nothing listens on right now, for a client to bind.
fn free_udp_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// Compiles an example with g++ as a team would (C++17, warnings are errors); returns the binary.
fn compile_cpp(source: &str, out: &Path) -> PathBuf {
    let binary = out.join(source.trim_end_matches(".cpp"));
    let output = Command::new("g++")
        .args(["-std=c++17", "-O1", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-o"])
        .arg(&binary)
        .arg(example(source))
        .output()
        .expect("g++ runs (install g++ to test the C++ examples)");
    assert!(output.status.success(), "g++ {source}: {}", String::from_utf8_lossy(&output.stderr));
    binary
}

fn succeeded(output: &Output) -> String {
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    assert!(
        output.status.success(),
        "{}\nstdout: {stdout}\nstderr: {}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    stdout
}

#[test]
fn the_rust_client_asks_for_a_relocalisation_and_receives_its_answer() {
    let mut subscriber = Subscriber::bind(&"udp:127.0.0.1:0".parse().unwrap()).unwrap();
    let listen = format!("udp:{}", subscriber.local_udp_address().unwrap());
    let daemon =
        Daemon::start("replay:{sample}", &["--burst", "2", "--encoding", "msgpack", "--publish", &listen]);

    let control = Control::connect(&Address::Unix(daemon.socket("control"))).unwrap();
    let trigger = control.relocalise(Some("rust client"), Some(0.0)).unwrap();
    let message = subscriber.recv_answer(trigger, Duration::from_secs(30)).unwrap();
    assert_eq!(message.triggers[0].kind, TriggerKind::Request);
    assert_eq!(message.triggers[0].reason.as_deref(), Some("rust client"));
    assert_eq!(message.hypotheses.len(), 2, "a half-point model's symmetric pair");
    let total: f64 = message.hypotheses.iter().map(|h| h.weight).sum();
    assert!((total - 1.0).abs() < 1e-6, "{:?}", message.hypotheses);
    // Refinement is on by default: both twins carry the same line evidence.
    let evidence: Vec<_> = message.hypotheses.iter().map(|h| h.lines.expect("line evidence")).collect();
    assert_eq!(evidence[0], evidence[1], "the lines cannot tell point-symmetric twins apart");
    assert!(evidence[0].points > 0, "{evidence:?}");
    assert_eq!(control.status().unwrap()["published"], 1);
    daemon.stop();
}

#[test]
fn without_refinement_the_message_carries_no_line_evidence() {
    let daemon = Daemon::start("replay:{sample}", &["--burst", "1", "--no-refine"]);
    daemon.control(br#"{"relocalise": {"reason": "unrefined"}}"#);
    let message = daemon.message();
    assert!(message.hypotheses.iter().all(|h| h.lines.is_none()), "{:?}", message.hypotheses);
    assert_eq!(message.latency_ms.refine, 0.0);
    daemon.stop();
}

#[test]
fn the_python_client_prints_the_best_hypothesis() {
    let port = free_udp_port();
    let daemon =
        Daemon::start("replay:{sample}", &["--burst", "2", "--publish", &format!("udp:127.0.0.1:{port}")]);
    let output = Command::new("python3")
        .arg(example("relocd_client.py"))
        .args(["--listen", &format!("udp:127.0.0.1:{port}"), "--request", "python client", "--timeout", "30"])
        .args(["--control", &format!("unix:{}", daemon.socket("control").display())])
        .output()
        .expect("python3 runs");
    let stdout = succeeded(&output);
    assert!(stdout.starts_with("seq 1 triggers [1 request]: best x="), "{stdout}");
    assert!(stdout.contains("(2 hypotheses)"), "{stdout}");
    daemon.stop();
}

#[test]
fn the_cpp_client_compiles_and_prints_the_best_hypothesis() {
    let build = tempfile::tempdir().unwrap();
    let print_best = compile_cpp("relocd_print_best.cpp", build.path());
    let port = free_udp_port();
    let daemon =
        Daemon::start("replay:{sample}", &["--burst", "2", "--publish", &format!("udp:127.0.0.1:{port}")]);
    let output = Command::new(print_best)
        .args(["--listen", &format!("udp:127.0.0.1:{port}"), "--request", "cpp", "--timeout-ms", "30000"])
        .args(["--control", &format!("unix:{}", daemon.socket("control").display())])
        .output()
        .unwrap();
    let stdout = succeeded(&output);
    assert!(stdout.starts_with("seq 1 triggers [1 request]: best x="), "{stdout}");
    assert!(stdout.contains("(2 hypotheses)"), "{stdout}");
    daemon.stop();
}

/// Runs a frame sender beside a daemon on forwarded frames; the published message must answer the
/// trigger it printed, with frames it sent.
fn forward_a_frame_and_a_trigger(sender: impl FnOnce(&Daemon, &Path) -> Command) {
    let daemon = Daemon::start("frames:unix:{dir}/frames", &["--burst", "2"]);
    let frame = daemon.socket("frame.yuyv");
    std::fs::write(&frame, sample_yuyv().as_bytes()).unwrap();
    let child = sender(&daemon, &frame).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let message = daemon.message();
    let stdout = succeeded(&child.wait_with_output().unwrap());
    let trigger: u64 = stdout.trim().parse().expect("the sender prints the trigger id");
    assert_eq!(message.triggers[0].id, trigger);
    assert_eq!(message.frames.used, 2, "{:?}", message.failure);
    assert_eq!(message.hypotheses.len(), 2);
    daemon.stop();
}

#[test]
fn the_python_sender_forwards_a_frame_and_a_trigger() {
    forward_a_frame_and_a_trigger(|daemon, frame| {
        let mut command = Command::new("python3");
        command
            .arg(example("relocd_send_frame.py"))
            .args(["--yuyv", frame.to_str().unwrap(), "--seconds", "1.5", "--fps", "20"])
            .args(["--frames", daemon.socket("frames").to_str().unwrap()])
            .args(["--control", &format!("unix:{}", daemon.socket("control").display())])
            .args(["--camera", "0.5,0.3,0.0,0.0"]);
        command
    });
}

#[test]
fn the_cpp_sender_forwards_a_frame_and_a_trigger() {
    let build = tempfile::tempdir().unwrap();
    let send_frame = compile_cpp("relocd_send_frame.cpp", build.path());
    forward_a_frame_and_a_trigger(|daemon, frame| {
        let mut command = Command::new(&send_frame);
        command
            .arg(frame)
            .args(["640", "480"])
            .arg(daemon.socket("frames"))
            .args([&format!("unix:{}", daemon.socket("control").display()), "1.5"]);
        command
    });
}

#[test]
fn every_client_sends_context_and_beliefs_and_hears_what_was_left_out() {
    let daemon = Daemon::start("replay:{sample}", &["--burst", "1"]);
    let control = Control::connect(&Address::Unix(daemon.socket("control"))).unwrap();
    let pose = relocd::client::PoseInput {
        x: -2.0,
        y: 1.0,
        theta: 0.5,
        sigma: relocd::client::SigmaInput { x: 0.3, y: 0.3, theta: 0.2 },
        age_s: None,
    };
    control.belief(&pose).unwrap();
    let accepted = control
        .relocalise_with(&relocd::client::RelocaliseRequest {
            prior: Some(relocd::client::PriorInput { pose }),
            own_half: Some(true),
            ..Default::default()
        })
        .unwrap();
    assert!(accepted.context_errors.is_empty(), "{:?}", accepted.context_errors);
    assert_eq!(daemon.message().prior.as_deref().map(|p| p.starts_with("belief+own_half")), Some(true));

    let script = format!(
        "import sys; sys.path.insert(0, {examples:?}); from relocd_client import Control\n\
         c = Control('unix:{control}')\n\
         pose = {{'x': -2.0, 'y': 1.0, 'theta': 0.5, 'sigma': {{'x': 0.3, 'y': 0.3, 'theta': 0.2}}}}\n\
         c.belief(pose)\n\
         a = c.relocalise_with('py', prior={{'pose': pose}}, ball={{'own': {{'distance': 1.0, 'bearing': 0.1}}, 'team': {{'x': 9.0, 'y': 0.0, 'sigma': 0.3}}}})\n\
         print(a['trigger'], a['context_errors'][0])\n\
         c.close()",
        examples = example("").display().to_string(),
        control = daemon.socket("control").display()
    );
    let output = Command::new("python3").args(["-c", &script]).output().expect("python3 runs");
    let stdout = succeeded(&output);
    assert!(stdout.contains("relocalise.ball.team: (9, 0) m is off the carpet"), "{stdout}");
    assert!(daemon.message().prior.is_some_and(|prior| prior.starts_with("belief")));

    let build = tempfile::tempdir().unwrap();
    let source = build.path().join("context.cpp");
    std::fs::write(
        &source,
        format!(
            "#include \"relocd_client.hpp\"\n#include <iostream>\nint main() {{\n\
             relocd::Control control(\"unix:{}\");\n\
             relocd::PoseInput pose{{-2.0, 1.0, 0.5, {{0.3, 0.3, -0.2}}, std::nullopt}};\n\
             control.belief(pose);\n\
             relocd::Context context; context.prior = pose; context.own_half = true;\n\
             std::vector<std::string> errors;\n\
             auto trigger = control.relocalise(\"cpp\", context, &errors);\n\
             if (!trigger || errors.size() != 1) {{ std::cerr << control.error() << '\\n'; return 1; }}\n\
             std::cout << errors[0] << '\\n';\n}}\n",
            daemon.socket("control").display()
        ),
    )
    .unwrap();
    let binary = build.path().join("context");
    let compiled = Command::new("g++")
        .args(["-std=c++17", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-I"])
        .arg(example(""))
        .arg(&source)
        .arg("-o")
        .arg(&binary)
        .output()
        .expect("g++ runs");
    assert!(compiled.status.success(), "{}", String::from_utf8_lossy(&compiled.stderr));
    let stdout = succeeded(&Command::new(&binary).output().unwrap());
    assert!(stdout.starts_with("relocalise.prior.pose.sigma.theta: -0.2 is not a positive"), "{stdout}");
    assert!(daemon.message().prior.is_some_and(|prior| prior.starts_with("own_half")));
    // Three beliefs, none answered: the C++ one, with its negative σ, was refused and counted.
    assert_eq!(daemon.status()["rejected"]["control"], 1);
    daemon.stop();
}
