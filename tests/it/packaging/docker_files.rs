//! The container files agree with the code and with each other (the default CI has no container
//! engine; `scripts/container-check` builds and runs the image): the health check reads the
//! file the daemon writes, the image runs the static edge build unprivileged in group dialout on
//! an empty base, its state has a home owned by its user, and the compose example keeps the
//! least-privilege settings and gives the status file and the state a writable place.

use std::path::Path;

const DOCKERFILE: &str = include_str!("../../../Dockerfile");
const EDGE_BUILD: &str = include_str!("../../../scripts/edge-build");
const DOCKERIGNORE: &str = include_str!("../../../.dockerignore");
const COMPOSE: &str = include_str!("../../../docker-compose.yml");

/// Dockerfile instructions with continuation lines joined.
fn instructions(dockerfile: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut current = String::new();
    for line in dockerfile.lines() {
        let trimmed = line.trim();
        if trimmed.starts_with('#') || (trimmed.is_empty() && current.is_empty()) {
            continue;
        }
        match trimmed.strip_suffix('\\') {
            Some(head) => {
                current.push_str(head);
                current.push(' ');
            }
            None => {
                current.push_str(trimmed);
                let joined = current.split_whitespace().collect::<Vec<_>>().join(" ");
                current.clear();
                out.push(joined);
            }
        }
    }
    out
}

fn instruction<'a>(all: &'a [String], keyword: &str) -> Vec<&'a str> {
    all.iter()
        .filter_map(|i| i.strip_prefix(keyword))
        .filter_map(|rest| rest.strip_prefix(' '))
        .collect()
}

/// The instructions of the runtime stage (after its `FROM`).
fn runtime_stage(all: &[String]) -> Vec<&String> {
    all.iter()
        .skip_while(|i| *i != "FROM scratch")
        .skip(1)
        .collect()
}

#[test]
fn image_builds_in_two_stages_and_runs_unprivileged_on_an_empty_base() {
    let all = instructions(DOCKERFILE);
    let from = instruction(&all, "FROM");
    assert_eq!(from, vec!["rust:1-bookworm AS builder", "scratch"]);
    // uid 10001, group dialout (gid 20), named in the image's own passwd and group.
    assert_eq!(instruction(&all, "USER"), vec!["10001:20"]);
    assert!(DOCKERFILE.contains("rtu2mqtt:x:10001:20:"));
    assert!(DOCKERFILE.contains("dialout:x:20:"));
    assert_eq!(instruction(&all, "STOPSIGNAL"), vec!["SIGTERM"]);
    assert_eq!(
        instruction(&all, "ENTRYPOINT"),
        vec![r#"["/usr/local/bin/rtu2mqtt"]"#]
    );
    assert_eq!(
        instruction(&all, "CMD"),
        vec![r#"["run", "--config", "/etc/rtu2mqtt/config.toml"]"#]
    );
    // Nothing runs in the runtime stage (it has no shell): one COPY of the tree the build
    // stage assembled, which holds the static edge build.
    let runtime = runtime_stage(&all);
    assert!(
        runtime.iter().all(|i| !i.starts_with("RUN ")),
        "{runtime:?}"
    );
    assert_eq!(
        runtime
            .iter()
            .filter(|i| i.starts_with("COPY "))
            .map(|i| i.as_str())
            .collect::<Vec<_>>(),
        ["COPY --from=builder /rootfs/ /"]
    );
    assert!(DOCKERFILE.contains("RUN scripts/edge-build"));
    // Its dependency layer is built as scripts/edge-build builds, or the build would not
    // reuse it.
    assert!(EDGE_BUILD.contains(r#""${RUSTFLAGS:-} -C target-feature=+crt-static""#));
    let dependencies = instruction(&all, "RUN")
        .into_iter()
        .find(|run| run.contains("placeholder-sources.sh"))
        .expect("a dependency layer");
    for flag in [
        r#"RUSTFLAGS="-C target-feature=+crt-static""#,
        "--release --locked -p rtu2mqtt --target \"$target\"",
    ] {
        assert!(dependencies.contains(flag), "{flag} not in {dependencies}");
    }
}

#[test]
fn the_state_has_a_home_owned_by_the_daemons_user() {
    let all = instructions(DOCKERFILE);
    let state = "/var/lib/rtu2mqtt";
    assert_eq!(instruction(&all, "VOLUME"), vec![state]);
    let env = instruction(&all, "ENV").join(" ");
    assert!(env.contains(&format!("STATE_DIRECTORY={state}")), "{env}");
    // The trust store the daemon reads for mqtts:// without ca_file.
    assert!(
        env.contains("SSL_CERT_FILE=/etc/ssl/certs/ca-certificates.crt"),
        "{env}"
    );
    assert!(DOCKERFILE.contains("/rootfs/etc/ssl/certs/ca-certificates.crt"));
    let status_dir = Path::new(rtu2mqtt::health::DEFAULT_STATUS_FILE)
        .parent()
        .expect("a directory");
    let made = format!(
        "install -d -m 0770 -o 10001 -g 20 /rootfs{} /rootfs{state}",
        status_dir.display()
    );
    assert!(DOCKERFILE.contains(&made), "no {made:?}");
    // The compose file keeps it in a named volume; its configuration journals there.
    assert!(COMPOSE.contains(&format!("- rtu2mqtt-state:{state}\n")));
    assert!(COMPOSE.contains("volumes:\n  mosquitto-data:\n  rtu2mqtt-state:\n"));
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docker/rtu2mqtt.toml");
    let config = match rtu2mqtt::config::load(&path) {
        Ok(config) => config,
        Err(problems) => panic!("docker/rtu2mqtt.toml: {problems}"),
    };
    let history = config
        .history
        .expect("the compose configuration keeps history");
    assert!(
        history.path.starts_with(state),
        "{}",
        history.path.display()
    );
    // So does the example configuration, when its history is switched on.
    let example = include_str!("../../../config/rtu2mqtt.toml");
    assert!(example.contains(&format!("# path = \"{state}/history\"")));
}

#[test]
fn health_check_reads_the_daemons_status_file() {
    let all = instructions(DOCKERFILE);
    let check = instruction(&all, "HEALTHCHECK");
    assert_eq!(check.len(), 1);
    let expected = format!(
        r#"CMD ["/usr/local/bin/rtu2mqtt", "health", "--status-file", "{}", "--max-age", "30s"]"#,
        rtu2mqtt::health::DEFAULT_STATUS_FILE
    );
    assert!(check[0].ends_with(&expected), "{}", check[0]);
}

#[test]
fn compose_keeps_least_privilege_and_a_writable_status_directory() {
    for needed in [
        "image: eclipse-mosquitto:2",
        "read_only: true",
        "cap_drop:\n      - ALL",
        "no-new-privileges:true",
        "devices:",
        "./docker/rtu2mqtt.toml:/etc/rtu2mqtt/config.toml:ro",
    ] {
        assert!(
            COMPOSE.contains(needed),
            "docker-compose.yml lacks {needed:?}"
        );
    }
    let status_dir = Path::new(rtu2mqtt::health::DEFAULT_STATUS_FILE)
        .parent()
        .expect("a directory");
    // The tmpfs belongs to the image's user (uid 10001) and group dialout (gid 20).
    let tmpfs = format!("- {}:uid=10001,gid=20,", status_dir.display());
    assert!(COMPOSE.contains(&tmpfs), "no tmpfs {tmpfs:?}");
    assert!(!COMPOSE.contains("privileged: true"));
}

#[test]
fn compose_configuration_is_valid() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docker/rtu2mqtt.toml");
    let config = match rtu2mqtt::config::load(&path) {
        Ok(config) => config,
        Err(problems) => panic!("docker/rtu2mqtt.toml: {problems}"),
    };
    assert_eq!(config.mqtt.host, "mosquitto");
    let ports: Vec<&str> = config
        .lines
        .iter()
        .map(|l| l.serial.path.as_str())
        .collect();
    assert_eq!(ports, vec!["/dev/ttyRS485A", "/dev/ttyRS485B"]);
    for port in ports {
        assert!(
            COMPOSE.contains(&format!(":{port}\n")),
            "{port} not passed in"
        );
    }
}

#[test]
fn the_image_and_the_edge_build_leave_the_demo_out() {
    let builds: Vec<&str> = DOCKERFILE
        .lines()
        .chain(EDGE_BUILD.lines())
        .filter(|line| !line.trim_start().starts_with('#') && line.contains("cargo build"))
        .collect();
    // The image's dependency layer; its sources are built by scripts/edge-build itself.
    assert_eq!(builds.len(), 2, "{builds:?}");
    for build in builds {
        assert!(build.contains("-p rtu2mqtt "), "{build}");
    }
}

#[test]
fn the_dependency_layer_copies_what_it_runs_and_its_placeholders_satisfy_the_manifest() {
    let all = instructions(DOCKERFILE);
    let builder: Vec<&String> = all.iter().take_while(|i| *i != "FROM scratch").collect();
    let first_run = builder
        .iter()
        .position(|i| i.starts_with("RUN "))
        .expect("a RUN in the build stage");
    let copied_before: Vec<&str> = builder[..first_run]
        .iter()
        .filter_map(|i| i.strip_prefix("COPY "))
        .collect();
    let needed = "docker/placeholder-sources.sh";
    assert!(
        builder[first_run].contains(needed),
        "the dependency layer runs {needed}: {}",
        builder[first_run]
    );
    assert!(
        copied_before.iter().any(|copy| copy.starts_with(needed)),
        "{needed} is copied before the dependency layer runs it: {copied_before:?}"
    );
    // docker/ stays out of the build context, all but the script the image runs.
    let ignored: Vec<&str> = DOCKERIGNORE
        .lines()
        .filter(|line| !line.starts_with('#'))
        .collect();
    let excluded_at = ignored.iter().position(|line| *line == "docker/");
    let included_at = ignored
        .iter()
        .position(|line| *line == format!("!{needed}"));
    assert!(
        matches!((excluded_at, included_at), (Some(out), Some(back)) if back > out)
            || excluded_at.is_none(),
        ".dockerignore keeps {needed} out of the build context: {ignored:?}"
    );

    // The placeholders, made from the files the image copies before them as it does, satisfy
    // cargo: every [[bench]], the binary and the workspace's member have a source, so the
    // manifest parses.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().expect("temp dir");
    let sources = copied_before.iter().flat_map(|copy| {
        let words: Vec<&str> = copy.split_whitespace().collect();
        words[..words.len().saturating_sub(1)].to_vec()
    });
    for file in sources.filter(|file| *file != needed) {
        let target = dir.path().join(file);
        std::fs::create_dir_all(target.parent().expect("a file in a folder")).expect("mkdir");
        std::fs::copy(root.join(file), target).expect("copy what the image copies");
    }
    let members = std::fs::read_dir(root.join("crates"))
        .expect("the workspace's crates")
        .flatten()
        .map(|entry| format!("crates/{}/Cargo.toml", entry.file_name().to_string_lossy()))
        .chain([
            "demo/Cargo.toml".to_string(),
            "testkit/Cargo.toml".to_string(),
        ]);
    for manifest in ["Cargo.toml".to_string(), "Cargo.lock".to_string()]
        .into_iter()
        .chain(members)
    {
        assert!(
            dir.path().join(&manifest).exists(),
            "{manifest} is copied before the dependency layer: {copied_before:?}"
        );
    }
    let made = std::process::Command::new("sh")
        .arg(root.join("docker/placeholder-sources.sh"))
        .current_dir(dir.path())
        .status()
        .expect("sh runs");
    assert!(made.success());
    let probe = std::process::Command::new(env!("CARGO"))
        .args(["check", "--locked", "--offline", "--bin", "no-such-target"])
        .current_dir(dir.path())
        .env("CARGO_TARGET_DIR", dir.path().join("target"))
        .output()
        .expect("cargo runs");
    let stderr = String::from_utf8_lossy(&probe.stderr);
    assert!(
        stderr.contains("no bin target named `no-such-target`"),
        "the manifest must parse with the placeholders alone:\n{stderr}"
    );
}
