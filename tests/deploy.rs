//! The deploy files: the installer's dry run prints exactly the commands a real run executes (run
//! here against stand-in `ssh` and `rsync` that only log), a dry run executes nothing, and the
//! systemd unit starts what the installer installs.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use relocd::daemon::config::Config;

fn repository() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A directory with stand-in `ssh` and `rsync` that append their arguments to `calls.log` beside
/// them, one command per line, each word ended by a NUL: no quoting to get wrong.
fn stand_in_tools() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let script = format!(
        "#!/bin/sh\n{{ printf '%s\\0' \"$(basename \"$0\")\" \"$@\"; printf '\\n'; }} >> '{}'\n",
        dir.path().join("calls.log").display()
    );
    for tool in ["ssh", "rsync"] {
        let path = dir.path().join(tool);
        std::fs::write(&path, &script).unwrap();
        Command::new("chmod").arg("+x").arg(&path).status().unwrap();
    }
    dir
}

/// The words of each command a dry run printed, as the shell parses them (NUL-ended, one per line).
fn parsed(dry_run: &str) -> String {
    let mut words = String::new();
    for line in commands(dry_run) {
        let output = Command::new("bash")
            .args(["-c", r#"words() { printf '%s\0' "$@"; }; eval "words $1""#, "-"])
            .arg(line.strip_prefix("+ ").unwrap())
            .output()
            .unwrap();
        assert!(output.status.success(), "bash cannot parse {line:?}");
        words.push_str(&String::from_utf8(output.stdout).unwrap());
        words.push('\n');
    }
    words
}

fn install(tools: &Path, args: &[&str]) -> Output {
    let path = format!("{}:{}", tools.display(), std::env::var("PATH").unwrap_or_default());
    Command::new(repository().join("deploy/install.sh")).args(args).env("PATH", path).output().unwrap()
}

fn stdout(output: &Output) -> String {
    assert!(output.status.success(), "{}: {}", output.status, String::from_utf8_lossy(&output.stderr));
    String::from_utf8(output.stdout.clone()).unwrap()
}

fn commands(text: &str) -> Vec<&str> {
    text.lines().filter(|line| line.starts_with("+ ")).collect()
}

#[test]
fn the_dry_run_prints_what_the_installer_runs_and_runs_nothing() {
    let tools = stand_in_tools();
    let binary = tools.path().join("relocd");
    std::fs::write(&binary, "a binary").unwrap();
    let args = ["nao@10.0.0.42", "--binary", binary.to_str().unwrap(), "--after", "hulk.service"];

    let dry = stdout(&install(tools.path(), &[&args[..], &["--dry-run"]].concat()));
    assert!(!tools.path().join("calls.log").exists(), "a dry run executes nothing");
    let real = install(tools.path(), &args);
    stdout(&real);
    let executed = std::fs::read_to_string(tools.path().join("calls.log")).unwrap();
    assert_eq!(parsed(&dry), executed, "the dry run's commands, parsed by bash, are the ones run");

    let dry = commands(&dry).join("\n");
    for expected in [
        &format!("rsync -tp --chmod=F755 {} nao@10.0.0.42:/home/nao/relocd/relocd", binary.display()),
        "models/squeezenet-half-point.w8.onnx nao@10.0.0.42:/home/nao/relocd/model.onnx",
        "--ignore-existing deploy/relocd.toml nao@10.0.0.42:/home/nao/relocd/relocd.toml",
        "sudo -n install -m 0644 /home/nao/relocd/relocd.service /etc/systemd/system/relocd.service",
        "After=%s",
        "systemctl enable relocd.service && sudo -n systemctl restart relocd.service",
    ] {
        assert!(dry.contains(expected), "{expected:?} missing from\n{dry}");
    }
}

#[test]
fn the_installer_builds_unless_given_a_binary_and_uninstalls() {
    let tools = stand_in_tools();
    let dry = stdout(&install(tools.path(), &["10.0.0.7", "--robot", "v5", "--dry-run"]));
    let dry = commands(&dry);
    assert_eq!(dry[0], "+ deploy/build-nao.sh v5");
    assert!(dry[2].contains("i686-unknown-linux-gnu/nao/relocd nao@10.0.0.7:"), "{dry:?}");
    assert!(!dry.join("\n").contains("After="), "no ordering drop-in without --after");

    let root = stdout(&install(tools.path(), &["root@10.0.0.7", "--uninstall", "--dry-run"]));
    assert!(root.contains("+ ssh root@10.0.0.7 'systemctl disable --now relocd.service || true'"), "{root}");
    assert!(root.contains("rm -rf /etc/systemd/system/relocd.service /etc/systemd/system/relocd.service.d"));
    assert!(!root.contains("sudo"), "root needs no sudo");
    let root_install =
        stdout(&install(tools.path(), &["root@10.0.0.7", "--binary", "Cargo.toml", "--dry-run"]));
    assert!(root_install.contains("'chown -R nao:nao /home/nao/relocd'"), "nao owns what root copied");
    assert!(!tools.path().join("calls.log").exists());

    let bad_arguments: [&[&str]; 5] = [
        &[],
        &["10.0.0.7", "--robot", "v7"],
        &["10.0.0.7", "--after", "x; reboot"],
        &["10.0.0.7", "--after", "--dry-run"],
        &["a", "b"],
    ];
    for bad in bad_arguments {
        let output = install(tools.path(), bad);
        assert_eq!(output.status.code(), Some(2), "{bad:?}: {}", String::from_utf8_lossy(&output.stderr));
    }
    let missing = install(tools.path(), &["10.0.0.7", "--binary", "/no/such/relocd", "--dry-run"]);
    assert!(!missing.status.success());
    assert!(String::from_utf8_lossy(&missing.stderr).contains("/no/such/relocd: no such file"));
}

#[test]
fn the_unit_runs_the_installed_files_as_nao_at_low_priority() {
    let unit = std::fs::read_to_string(repository().join("deploy/relocd.service")).unwrap();
    let value = |key: &str| {
        unit.lines()
            .find_map(|line| line.strip_prefix(key)?.strip_prefix('='))
            .unwrap_or_else(|| panic!("relocd.service has no {key}="))
    };
    assert_eq!(
        value("ExecStart"),
        "/home/nao/relocd/relocd run --config /home/nao/relocd/relocd.toml --model /home/nao/relocd/model.onnx"
    );
    assert_eq!(value("User"), "nao");
    assert_eq!(value("Restart"), "on-failure");
    assert_eq!(value("Nice"), Config::default().process.nice.to_string(), "the unit and relocd agree");
    assert!(value("After").contains(r"dev-video\x2dtop.device"), "after the top camera");

    // The files the unit names are the ones the installer copies.
    let dry =
        stdout(&install(&PathBuf::from("/nonexistent"), &["robot", "--binary", "Cargo.toml", "--dry-run"]));
    for file in ["/home/nao/relocd/relocd", "/home/nao/relocd/relocd.toml", "/home/nao/relocd/model.onnx"] {
        assert!(dry.contains(&format!(":{file}\n")), "the installer does not copy {file}:\n{dry}");
    }
}

/// Where systemd's tools are installed: the unit is valid, and its hardening keeps systemd's exposure
/// score "OK" (≤ 3.0; without the hardening it is 9.0, "UNSAFE").
#[test]
fn the_unit_verifies_and_is_hardened() {
    let analyze = Path::new("/usr/bin/systemd-analyze");
    if !analyze.exists() {
        eprintln!("systemd-analyze not installed: unit not verified");
        return;
    }
    // `verify` checks that ExecStart's binary exists: point it at the one cargo built.
    let unit = std::fs::read_to_string(repository().join("deploy/relocd.service"))
        .unwrap()
        .replace("/home/nao/relocd/relocd run", &format!("{} run", env!("CARGO_BIN_EXE_relocd")));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("relocd.service");
    std::fs::write(&path, unit).unwrap();
    let verify = Command::new(analyze).arg("verify").arg(&path).output().unwrap();
    assert!(verify.status.success(), "{}", String::from_utf8_lossy(&verify.stderr));
    assert!(verify.stderr.is_empty(), "{}", String::from_utf8_lossy(&verify.stderr));

    let security = Command::new(analyze).args(["security", "--offline=yes"]).arg(&path).output().unwrap();
    let report = String::from_utf8_lossy(&security.stdout);
    let exposure: f64 = report
        .lines()
        .find_map(|line| line.split("Overall exposure level for relocd.service: ").nth(1))
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|score| score.parse().ok())
        .unwrap_or_else(|| panic!("no exposure level in {report}"));
    assert!(exposure <= 3.0, "exposure {exposure}:\n{report}");
}

#[test]
fn cross_builds_the_nao_targets_statically_for_their_atoms() {
    let text = std::fs::read_to_string(repository().join("cross.toml")).unwrap();
    let cross: toml::Table = text.parse().expect("cross.toml is TOML");
    let flags = |target: &str| {
        let passthrough = cross["target"][target]["env"]["passthrough"].as_array().unwrap();
        let variable = format!("CARGO_TARGET_{}_RUSTFLAGS=", target.to_uppercase().replace('-', "_"));
        passthrough
            .iter()
            .find_map(|entry| entry.as_str()?.strip_prefix(variable.as_str()))
            .unwrap_or_else(|| panic!("cross.toml sets no {variable} for {target}"))
            .to_owned()
    };
    let v6 = flags("x86_64-unknown-linux-gnu");
    let v5 = flags("i686-unknown-linux-gnu");
    assert!(v6.contains("-C target-cpu=silvermont") && v6.contains("+crt-static"), "{v6}");
    assert!(v5.contains("-C target-cpu=atom") && v5.contains("+crt-static"), "{v5}");
    assert!(!v6.contains("native") && !v5.contains("native"));

    let build = std::fs::read_to_string(repository().join("deploy/build-nao.sh")).unwrap();
    assert!(
        build.contains("cpu=silvermont") && build.contains("cpu=bonnell") && build.contains("+crt-static")
    );
}
