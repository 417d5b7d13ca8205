//! The fuzz corpus (`fuzz/corpus/TARGET/`) replayed as ordinary tests: every seed and every input the
//! fuzzer kept or crashed on goes through the same check as in `fuzz/`, so a regression fails
//! `cargo test` on stable Rust. `cargo test --test fuzz_corpus -- --ignored` rewrites the seeds.

use std::path::{Path, PathBuf};

use relocd::fuzzing::TARGETS;
use relocd::protocol::frame_header::FrameHeader;
use relocd::protocol::gamecontroller::{
    GameControlData, GamePhase, GameState, MAX_PLAYERS, Penalty, RobotInfo, SetPlay, TeamInfo,
};

fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus")
}

#[test]
fn every_corpus_input_keeps_its_decoder_s_contract() {
    let mut checked = 0;
    for (target, check) in TARGETS {
        let directory = corpus().join(target);
        let mut files: Vec<PathBuf> = std::fs::read_dir(&directory)
            .unwrap_or_else(|error| panic!("{}: {error}", directory.display()))
            .map(|entry| entry.unwrap().path())
            .collect();
        files.sort();
        assert!(!files.is_empty(), "no seeds for {target}");
        for file in files {
            let bytes = std::fs::read(&file).unwrap();
            check(&bytes);
            checked += 1;
        }
    }
    assert!(checked >= TARGETS.len());
}

/// Writes the seed corpus: small valid inputs for each decoder, made with relocd's own encoders or
/// copied from files in the repository.
#[test]
#[ignore = "rewrites fuzz/corpus seeds; run by hand"]
fn write_seed_corpus() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let write = |target: &str, name: &str, bytes: &[u8]| {
        let directory = corpus().join(target);
        std::fs::create_dir_all(&directory).unwrap();
        std::fs::write(directory.join(name), bytes).unwrap();
    };
    let copy = |target: &str, name: &str, source: &str| {
        write(target, name, &std::fs::read(root.join(source)).unwrap())
    };

    let team = |number: u8, penalty: Penalty| TeamInfo {
        team_number: number,
        field_player_colour: 0,
        goalkeeper_colour: 1,
        goalkeeper: 1,
        score: 2,
        penalty_shot: 0,
        single_shots: 0,
        message_budget: 1200,
        players: [RobotInfo { penalty, secs_till_unpenalised: 15 }; MAX_PLAYERS],
    };
    let packet = GameControlData {
        packet_number: 42,
        players_per_team: 7,
        competition_phase: 0,
        competition_type: 0,
        game_phase: GamePhase::Normal,
        state: GameState::Playing,
        set_play: SetPlay::None,
        first_half: true,
        kicking_team: Some(5),
        secs_remaining: 300,
        secondary_time: 0,
        teams: [team(5, Penalty::RequestForPickup), team(12, Penalty::None)],
    };
    write("gamecontroller", "playing-pickup", &packet.to_bytes());

    let state = serde_json::json!({
        "Angles": [0.01, -0.02], "Gyroscope": [0.0, 0.1, 0.0], "FSR": vec![0.3; 8], "Battery": [1.0, 0.0, 0.0, 0.0],
    });
    write("lola", "standing", &rmp_serde::to_vec_named(&state).unwrap());

    write("control", "relocalise", br#"{"relocalise": {"reason": "lost", "head_yaw": 0.3}}"#);
    write("control", "status", br#"{"status": {}}"#);
    write("control", "relocalise-context", br#"{"relocalise": {"reason": "fell", "prior": {"pose": {"x": -2.0, "y": 1.0, "theta": 0.5, "sigma": {"x": 0.3, "y": 0.3, "theta": 0.2}, "age_s": 0.4}}, "own_half": true, "ball": {"own": {"distance": 1.8, "bearing": 0.2}, "team": {"x": -0.5, "y": 0.8, "sigma": 0.3, "teammates": 3}}}}"#);
    write("control", "relocalise-bad-context", br#"{"relocalise": {"prior": {"pose": {"x": -9.0, "y": 1.0, "theta": 0.5, "sigma": {"x": -0.3, "y": 0.3, "theta": 0.2}, "z": 1}}, "own_half": "yes", "ball": {"own": {"distance": 99, "bearing": 9}, "team": {"x": 0, "y": 0, "sigma": 0, "teammates": 0}}}}"#);
    write("control", "belief", br#"{"belief": {"x": -2.0, "y": 1.0, "theta": 0.5, "sigma": {"x": 0.3, "y": 0.3, "theta": 0.2}, "age_s": 0.1}}"#);
    write(
        "control",
        "belief-bad-sigma",
        br#"{"belief": {"x": 0, "y": 0, "theta": 0, "sigma": {"x": 0, "y": 0.3, "theta": 0.2}}}"#,
    );

    let header = FrameHeader { width: 4, height: 2, timestamp: 12.5, camera: None };
    write("frame", "tiny", &[&header.to_bytes()[..], &[128u8; 16][..]].concat());

    copy("model", "valid.onnx", "models/fixtures/tiny/valid.onnx");
    let sample = std::fs::read_to_string(root.join("tests/data/sample/frames.jsonl")).unwrap();
    write("recording", "sample-line", sample.lines().next().unwrap().as_bytes());
    copy("config", "relocd.toml", "deploy/relocd.toml");
}
