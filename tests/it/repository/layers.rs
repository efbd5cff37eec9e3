//! The layers point one way. Between crates the compiler keeps them (a crate cannot name one
//! that does not depend on it); what is checked here is what each manifest may depend on: the
//! wire crate on no MQTT, JSON or configuration crate, the profile crate on no runtime and no
//! MQTT, the daemon on no simulator, demo or broker. Inside the daemon a top-level module of
//! `src/` names only modules below it (`crate::<module>` anywhere in its files, the items behind
//! `#[cfg(test)]` and comments aside), in the order of `lib.rs`'s module map; an arrow pointing
//! up, and so any import circle between top-level modules, fails.

use std::collections::BTreeSet;
use std::path::Path;

use super::source_scan::{rust_files, skip_item};

/// Lowest first: each module may use only modules listed before it.
const LAYERS: &[&str] = &[
    "bus",
    "topics",
    "config",
    "health",
    "history",
    "bridge",
    "sparkplug",
    "cli",
    "web",
    "commissioning",
    "app",
];

/// The top-level modules `text` names as `crate::<module>`, in the whole file: comments and
/// the items behind `#[cfg(test)]` aside (test code may reach anywhere), and only those items:
/// code after an inline test module is read like the code before it.
fn named_modules(text: &str) -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    let mut lines = text.lines();
    while let Some(line) = lines.next() {
        let code = line.trim_start();
        if code.starts_with("#[cfg(test)]") {
            if let Some(first) = lines.next() {
                skip_item(first, &mut lines);
            }
            continue;
        }
        if code.starts_with("//") {
            continue;
        }
        for (at, _) in code.match_indices("crate::") {
            let rest = &code[at + "crate::".len()..];
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() {
                names.insert(name);
            }
        }
    }
    names
}

/// The top-level module a file of `src/` belongs to (None for `lib.rs` and `main.rs`).
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let relative = file.strip_prefix(src).ok()?;
    let first = relative.components().next()?.as_os_str().to_str()?;
    let name = first.strip_suffix(".rs").unwrap_or(first);
    (name != "lib" && name != "main").then(|| name.to_string())
}

#[test]
fn top_level_modules_only_use_the_layers_below_them() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut upward = Vec::new();
    let mut seen_modules = BTreeSet::new();
    for file in &files {
        let Some(module) = module_of(&src, file) else {
            continue;
        };
        if file.to_string_lossy().ends_with("tests.rs") {
            continue;
        }
        seen_modules.insert(module.clone());
        let rank = LAYERS.iter().position(|layer| *layer == module);
        let rank = rank.unwrap_or_else(|| panic!("{module} is not in LAYERS"));
        let text = std::fs::read_to_string(file).unwrap();
        for used in named_modules(&text) {
            if used == module {
                continue;
            }
            match LAYERS.iter().position(|layer| *layer == used) {
                Some(used_rank) if used_rank < rank => {}
                _ => upward.push(format!("{} uses crate::{used}", file.display())),
            }
        }
    }
    assert!(
        upward.is_empty(),
        "arrows pointing up:\n{}",
        upward.join("\n")
    );
    for layer in ["bus", "config", "health", "bridge"] {
        assert!(seen_modules.contains(layer), "{layer} was not scanned");
    }
}

#[test]
fn the_scan_sees_uses_and_paths_but_not_comments_or_tests() {
    let text = "use crate::bus::LineStats;\nlet x = crate::bridge::TICK;\n// crate::app\n\
                #[cfg(test)]\nmod tests { use crate::sim; }\n";
    let names: Vec<String> = named_modules(text).into_iter().collect();
    assert_eq!(names, vec!["bridge".to_string(), "bus".to_string()]);
}

#[test]
fn the_scan_reads_on_after_a_test_module() {
    let text = "use crate::bus::LineStats;\n#[cfg(test)]\nmod tests {\n    fn f() {\n        \
                use crate::web;\n    }\n}\n#[cfg(test)]\nmod more;\nuse crate::app::run;\n";
    let names: Vec<String> = named_modules(text).into_iter().collect();
    assert_eq!(names, vec!["app".to_string(), "bus".to_string()]);
}

/// The names of the dependencies a manifest's `[dependencies]` table declares (not its
/// dev-dependencies: tests may use anything).
fn dependencies(manifest: &str) -> Vec<String> {
    let mut names = Vec::new();
    let mut in_dependencies = false;
    for line in manifest.lines() {
        let line = line.trim();
        if line.starts_with('[') {
            in_dependencies = line == "[dependencies]";
            continue;
        }
        if in_dependencies && !line.starts_with('#') {
            if let Some(name) = line.split(['=', '.', ' ']).next().filter(|n| !n.is_empty()) {
                names.push(name.to_string());
            }
        }
    }
    names
}

#[test]
fn each_crate_depends_only_on_what_lies_below_it() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let never: &[(&str, &[&str])] = &[
        (
            "crates/rtu2mqtt-modbus",
            &[
                "rtu2mqtt",
                "rtu2mqtt-profile",
                "rumqttc",
                "rumqttd",
                "serde_json",
                "config",
            ],
        ),
        (
            "crates/rtu2mqtt-profile",
            &[
                "rtu2mqtt",
                "rtu2mqtt-sim",
                "tokio",
                "rumqttc",
                "rumqttd",
                "config",
            ],
        ),
        (
            "crates/rtu2mqtt-sim",
            &["rtu2mqtt", "rumqttc", "rumqttd", "config"],
        ),
        (
            ".",
            &[
                "rtu2mqtt-sim",
                "rtu2mqtt-demo",
                "rtu2mqtt-testkit",
                "rumqttd",
            ],
        ),
    ];
    for (krate, forbidden) in never {
        let manifest = std::fs::read_to_string(root.join(krate).join("Cargo.toml")).unwrap();
        let declared = dependencies(&manifest);
        assert!(declared.len() >= 3, "{krate}: {declared:?}");
        for name in *forbidden {
            assert!(
                !declared.iter().any(|d| d == name),
                "{krate} depends on {name}: {declared:?}"
            );
        }
    }
}

#[test]
fn the_wire_crate_names_nothing_above_it() {
    let wire = Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/rtu2mqtt-modbus");
    let mut files = Vec::new();
    rust_files(&wire, &mut files);
    assert!(files.len() > 5, "the wire crate's sources were not found");
    let naming_the_daemon: Vec<String> = files
        .iter()
        .filter(|file| {
            let text = std::fs::read_to_string(file).unwrap();
            text.contains("rtu2mqtt::")
        })
        .map(|file| file.display().to_string())
        .collect();
    assert!(
        naming_the_daemon.is_empty(),
        "the wire crate names the daemon in {naming_the_daemon:?}"
    );
}
