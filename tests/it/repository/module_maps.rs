//! Maps that cannot drift: every module map of the repository (a `lib.rs`, `main.rs` or
//! `mod.rs`) names, in its `//!` documentation, every module it declares, and each of its
//! bullets that starts with a module's name (`` - [`name`]: `` or `` - `name`: ``) names one it
//! declares. Modules behind `#[cfg(test)]` are the tests of the map's own code and need no entry.
//! A `lib.rs` or `mod.rs` is a map and nothing else: it declares modules and re-exports their
//! items, and defines none itself (tests and doctests aside).

use std::path::{Path, PathBuf};

use super::source_scan::{rust_files, skip_item};

/// The folders whose maps are checked, from the repository's root.
const ROOTS: &[&str] = &[
    "src",
    "crates",
    "testkit/src",
    "demo/src",
    "demo/tests",
    "tests/it",
    "fuzz/fuzz_targets",
];

/// The module maps below `dir`: its `lib.rs`, `main.rs` and `mod.rs` files.
fn maps(dir: &Path, found: &mut Vec<PathBuf>) {
    let mut files = Vec::new();
    rust_files(dir, &mut files);
    found.extend(files.into_iter().filter(|path| {
        path.file_name()
            .is_some_and(|name| name == "lib.rs" || name == "main.rs" || name == "mod.rs")
    }));
}

/// The modules `text` declares (`mod name;`, with any visibility), those behind
/// `#[cfg(test)]` aside.
fn declared(text: &str) -> Vec<String> {
    let mut names = Vec::new();
    let mut test_only = false;
    for line in text.lines() {
        let code = line.trim();
        if code.starts_with("#[cfg(test)]") {
            test_only = true;
            continue;
        }
        let after_visibility = code
            .strip_prefix("pub(crate) ")
            .or_else(|| code.strip_prefix("pub(super) "))
            .or_else(|| code.strip_prefix("pub "))
            .unwrap_or(code);
        if let Some(name) = after_visibility
            .strip_prefix("mod ")
            .and_then(|rest| rest.strip_suffix(';'))
        {
            if !test_only {
                names.push(name.trim().to_string());
            }
        }
        if !code.starts_with("#[") {
            test_only = false;
        }
    }
    names
}

/// The map's `//!` text.
fn documentation(text: &str) -> String {
    text.lines()
        .filter_map(|line| line.trim_start().strip_prefix("//!"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Whether `doc` names `module` in code style: `` `module` ``, `` [`module`] ``,
/// `` [`mod@module`] ``, or as a part of a path (`` `crate::bus::module` ``,
/// `` `module::Item` ``), a folder (`` `module/` ``) or a file (`` `module.rs` ``).
fn names(doc: &str, module: &str) -> bool {
    doc.split('`').skip(1).step_by(2).any(|quoted| {
        let quoted = quoted.strip_prefix("mod@").unwrap_or(quoted);
        let quoted = quoted.strip_suffix("()").unwrap_or(quoted);
        quoted == module
            || quoted.split("::").any(|part| part == module)
            || quoted
                .strip_suffix("/")
                .is_some_and(|folder| folder == module)
            || quoted
                .strip_suffix(".rs")
                .is_some_and(|file| file == module)
    })
}

/// The names that open the doc's bullets: `` - [`name`]: `` or `` - `name`: ``, lower-case
/// names only (a bullet may open with a type).
fn bullet_heads(doc: &str) -> Vec<String> {
    doc.lines()
        .filter_map(|line| {
            let rest = line.trim_start().strip_prefix("- ")?;
            let rest = rest.strip_prefix('[').unwrap_or(rest);
            let name = rest.strip_prefix('`')?.split('`').next()?;
            let lower = name
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
            (lower && !name.is_empty()).then(|| name.to_string())
        })
        .collect()
}

fn problems_of(path: &Path, text: &str) -> Vec<String> {
    let doc = documentation(text);
    let declared = declared(text);
    let mut problems: Vec<String> = declared
        .iter()
        .filter(|module| !names(&doc, module))
        .map(|module| {
            format!(
                "{}: declares `{module}` and does not name it",
                path.display()
            )
        })
        .collect();
    problems.extend(
        bullet_heads(&doc)
            .into_iter()
            .filter(|head| !declared.contains(head))
            .map(|head| {
                format!(
                    "{}: a bullet names `{head}`, which it does not declare",
                    path.display()
                )
            }),
    );
    problems
}

#[test]
fn every_module_map_names_exactly_the_modules_it_declares() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut found = Vec::new();
    for dir in ROOTS {
        maps(&root.join(dir), &mut found);
    }
    assert!(found.len() > 20, "maps found: {found:?}");
    let mut problems = Vec::new();
    for path in &found {
        let Ok(text) = std::fs::read_to_string(path) else {
            problems.push(format!("{}: unreadable", path.display()));
            continue;
        };
        let relative = path.strip_prefix(root).unwrap_or(path);
        problems.extend(problems_of(relative, &text));
    }
    assert!(
        problems.is_empty(),
        "maps out of step:\n{}",
        problems.join("\n")
    );
}

/// The items `text` defines itself (functions, types, impls, constants…), outside the items
/// behind `#[cfg(test)]` or `#[cfg(doctest)]`: their first lines.
fn homed_items(text: &str) -> Vec<String> {
    const ITEMS: &[&str] = &[
        "fn ",
        "async fn ",
        "struct ",
        "enum ",
        "union ",
        "impl ",
        "impl<",
        "trait ",
        "const ",
        "static ",
        "type ",
        "macro_rules!",
    ];
    let mut found = Vec::new();
    let mut lines = text.lines();
    while let Some(line) = lines.next() {
        let code = line.trim();
        if code.starts_with("#[cfg(test)]") || code.starts_with("#[cfg(doctest)]") {
            if let Some(first) = lines.next() {
                skip_item(first, &mut lines);
            }
            continue;
        }
        let after_visibility = code
            .strip_prefix("pub(crate) ")
            .or_else(|| code.strip_prefix("pub(super) "))
            .or_else(|| code.strip_prefix("pub "))
            .unwrap_or(code);
        if ITEMS.iter().any(|item| after_visibility.starts_with(item)) {
            found.push(code.to_string());
            skip_item(line, &mut lines);
        }
    }
    found
}

#[test]
fn a_lib_rs_or_mod_rs_is_a_map_not_a_home() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut found = Vec::new();
    for dir in ROOTS {
        maps(&root.join(dir), &mut found);
    }
    let mut homes = Vec::new();
    for path in found.iter().filter(|path| !path.ends_with("main.rs")) {
        let text = std::fs::read_to_string(path).unwrap_or_default();
        let items = homed_items(&text);
        if let Some(first) = items.first() {
            let relative = path.strip_prefix(root).unwrap_or(path);
            homes.push(format!(
                "{}: {} item(s) of its own, first `{first}`",
                relative.display(),
                items.len()
            ));
        }
    }
    assert!(
        homes.is_empty(),
        "maps that are homes:\n{}",
        homes.join("\n")
    );
}

#[test]
fn an_item_of_a_map_is_found_and_its_tests_are_not() {
    let text = "//! Map.\nmod a;\npub use a::X;\n#[cfg(test)]\nmod tests {\n    fn t() {}\n}\n\
                #[cfg(doctest)]\npub struct Readme;\npub fn home() {\n    let x = 1;\n}\n";
    assert_eq!(homed_items(text), vec!["pub fn home() {".to_string()]);
}

#[test]
fn a_missing_or_an_extra_entry_is_found() {
    let text = "//! The map: [`alpha`] does one thing.\n//!\n//! - `gamma`: gone.\n\
                pub mod alpha;\nmod beta;\n#[cfg(test)]\nmod tests;\n";
    let problems = problems_of(Path::new("x/mod.rs"), text);
    assert_eq!(
        problems,
        vec![
            "x/mod.rs: declares `beta` and does not name it".to_string(),
            "x/mod.rs: a bullet names `gamma`, which it does not declare".to_string(),
        ]
    );
    let named = "//! - [`alpha`]: one.\n//! - `beta`: two.\npub mod alpha;\nmod beta;\n";
    assert!(problems_of(Path::new("y/mod.rs"), named).is_empty());
}
