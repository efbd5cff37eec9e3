//! The manual pages and shell completions the package installs (crates/rtu2mqtt-assets) say
//! what the built executable's `--help` says: every command it lists has its page and is
//! completed by bash, zsh and fish, and every long option of every command is in that command's
//! page and completions. `--version` names the version, and the commit of a git checkout.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use rtu2mqtt_assets::{completions, manual_pages, Asset};

/// `rtu2mqtt <args> --help` of the built executable.
fn help(args: &[&str]) -> String {
    let output = Command::new(crate::support::child::gateway_binary())
        .args(args)
        .arg("--help")
        .output()
        .expect("the gateway binary runs");
    assert!(output.status.success(), "{args:?} --help failed");
    String::from_utf8(output.stdout).expect("UTF-8 help")
}

/// The entries of one section of a help text (`Commands:`, `Options:`): its lines up to the
/// next heading that are indented less than a description (which starts in column 10).
fn section_entries<'a>(help: &'a str, heading: &str) -> Vec<&'a str> {
    help.lines()
        .skip_while(|line| *line != heading)
        .skip(1)
        .take_while(|line| line.is_empty() || line.starts_with(' '))
        .filter(|line| {
            let indent = line.len() - line.trim_start().len();
            (2..10).contains(&indent)
        })
        .map(str::trim)
        .collect()
}

/// The commands `rtu2mqtt --help` lists, with their one-line descriptions (clap's `help`
/// command aside: `--help` is on every command).
fn commands() -> Vec<(String, String)> {
    let top = help(&[]);
    let commands: Vec<(String, String)> = section_entries(&top, "Commands:")
        .into_iter()
        .filter_map(|entry| {
            let (name, about) = entry.split_once(' ').unwrap_or((entry, ""));
            (name != "help").then(|| (name.to_string(), about.trim().to_string()))
        })
        .collect();
    assert!(commands.len() >= 7, "commands in --help: {commands:?}");
    commands
}

/// The long options of a help text's `Options:` section (`--config`, `--help`, …).
fn long_options(help: &str) -> Vec<String> {
    section_entries(help, "Options:")
        .into_iter()
        .filter_map(|entry| {
            entry
                .split([' ', ','])
                .find(|word| word.starts_with("--"))
                .map(|word| word.split(['=', '<']).next().unwrap_or(word).to_string())
        })
        .collect()
}

/// Every command (`""` for `rtu2mqtt` itself) with the long options its `--help` lists.
fn options_by_command() -> BTreeMap<String, Vec<String>> {
    let mut options = BTreeMap::from([(String::new(), long_options(&help(&[])))]);
    for (command, _) in commands() {
        let of_command = long_options(&help(&[&command]));
        assert!(
            of_command.contains(&"--help".to_string()),
            "{command}: {of_command:?}"
        );
        options.insert(command, of_command);
    }
    options
}

fn text(assets: &[Asset], path: &str) -> String {
    let asset = assets
        .iter()
        .find(|asset| asset.path == Path::new(path))
        .unwrap_or_else(|| panic!("no {path} among {:?}", paths(assets)));
    String::from_utf8(asset.contents.clone()).expect("UTF-8")
}

fn paths(assets: &[Asset]) -> Vec<String> {
    assets
        .iter()
        .map(|asset| asset.path.display().to_string())
        .collect()
}

/// A manual page as a reader sees its words: roff's escaped hyphens and font changes undone.
fn unroff(page: &str) -> String {
    page.replace("\\-", "-")
        .replace("\\fB", "")
        .replace("\\fI", "")
        .replace("\\fR", "")
        .replace("\\*(Aq", "'")
}

#[test]
fn every_command_and_long_option_has_its_manual_page() {
    let pages = manual_pages().expect("the manual pages render");
    let main_page = unroff(&text(&pages, "man/rtu2mqtt.1"));
    for (command, about) in commands() {
        let page = unroff(&text(&pages, &format!("man/rtu2mqtt-{command}.1")));
        assert!(
            main_page.contains(&format!("rtu2mqtt-{command}(1)")),
            "rtu2mqtt(1) does not list {command}"
        );
        assert!(
            page.contains(&format!("rtu2mqtt-{command} - {about}")),
            "rtu2mqtt-{command}(1) NAME does not say `{about}`"
        );
    }
    for (command, options) in options_by_command() {
        let page = if command.is_empty() {
            main_page.clone()
        } else {
            unroff(&text(&pages, &format!("man/rtu2mqtt-{command}.1")))
        };
        for option in options {
            // An OPTIONS entry: `--port <PORT>`, `--help`, or `-h, --help`.
            let entry = |line: &str| {
                let line = line.split_once(", ").map_or(line, |(_, long)| long);
                line == option || line.starts_with(&format!("{option} "))
            };
            assert!(
                page.lines().any(entry),
                "rtu2mqtt {command} {option} is not in its manual page's OPTIONS"
            );
        }
    }
    assert_eq!(
        pages.len(),
        commands().len() + 1,
        "one page per command and one for rtu2mqtt: {:?}",
        paths(&pages)
    );
}

/// Asserts, for one shell, that it completes every command, and every long option of each
/// command (`""` for rtu2mqtt itself) within the part of its script that `part_of` cuts out.
fn assert_completes(
    shell: &str,
    completes_command: impl Fn(&str) -> bool,
    part_of: impl Fn(&str) -> String,
    completes_option: impl Fn(&str, &str) -> bool,
) {
    for (command, options) in options_by_command() {
        assert!(
            command.is_empty() || completes_command(&command),
            "{shell} does not complete `{command}`"
        );
        let part = part_of(&command);
        for option in options {
            assert!(
                completes_option(&part, &option),
                "{shell} does not complete rtu2mqtt {command} {option}"
            );
        }
    }
}

#[test]
fn bash_completes_every_command_and_long_option() {
    let bash = text(&completions(), "completions/rtu2mqtt.bash");
    // Each command's case arm sets `opts` to the words it completes.
    let opts_of = |command: &str| -> String {
        let arm = match command {
            "" => "rtu2mqtt".to_string(),
            command => format!("rtu2mqtt__subcmd__{command}"),
        };
        let start = bash
            .find(&format!("\n        {arm})\n"))
            .unwrap_or_else(|| panic!("no case for {arm} in the bash completion"));
        let opts = bash[start..]
            .lines()
            .find_map(|line| line.trim().strip_prefix("opts=\""))
            .expect("an opts line");
        format!(" {} ", opts.trim_end_matches('"'))
    };
    let word = |opts: &str, word: &str| opts.contains(&format!(" {word} "));
    assert_completes("bash", |command| word(&opts_of(""), command), opts_of, word);
}

#[test]
fn zsh_completes_every_command_and_long_option() {
    let zsh = text(&completions(), "completions/_rtu2mqtt");
    // rtu2mqtt's own arguments come before the commands' states; each command's follow its
    // `(command)` arm.
    let arguments_of = |command: &str| -> String {
        if command.is_empty() {
            return zsh[..zsh.find("case $state in").expect("the command state")].to_string();
        }
        let arm = format!("({command})\n");
        let start = zsh
            .match_indices(&arm)
            .map(|(at, _)| at)
            .find(|at| zsh[..*at].ends_with(['\n', ' ']))
            .unwrap_or_else(|| panic!("no ({command}) in the zsh completion"));
        let end = zsh[start..].find("\n;;").expect("the end of its arguments");
        zsh[start..start + end].to_string()
    };
    assert_completes(
        "zsh",
        |command| zsh.contains(&format!("\n'{command}:")),
        arguments_of,
        |arguments, option| {
            ["'", ")"].iter().any(|before| {
                arguments.contains(&format!("{before}{option}["))
                    || arguments.contains(&format!("{before}{option}=["))
                    || arguments.contains(&format!("{before}*{option}=["))
            }) || arguments.contains(&format!("'*{option}=["))
        },
    );
}

#[test]
fn fish_completes_every_command_and_long_option() {
    let fish = text(&completions(), "completions/rtu2mqtt.fish");
    // Each completion is one `complete` line whose condition names the command.
    let lines_of = |command: &str| -> String {
        let condition = match command {
            "" => "\"__fish_rtu2mqtt_needs_command\"".to_string(),
            command => format!("\"__fish_rtu2mqtt_using_subcommand {command}\""),
        };
        fish.lines()
            .filter(|line| line.contains(&condition))
            .map(|line| format!("{line}\n"))
            .collect()
    };
    assert_completes(
        "fish",
        |command| lines_of("").contains(&format!(" -f -a \"{command}\"")),
        lines_of,
        |lines, option| lines.contains(&format!(" -l {} ", option.trim_start_matches("--"))),
    );
}

#[test]
fn version_names_the_commit_of_a_git_checkout() {
    let output = Command::new(crate::support::child::gateway_binary())
        .arg("--version")
        .output()
        .expect("the gateway binary runs");
    assert!(output.status.success());
    let shown = String::from_utf8_lossy(&output.stdout).trim().to_string();
    let root = env!("CARGO_MANIFEST_DIR");
    let commit = Command::new("git")
        .args(["-C", root, "rev-parse", "--short", "HEAD"])
        .output()
        .ok()
        .filter(|output| output.status.success())
        .map(|output| String::from_utf8_lossy(&output.stdout).trim().to_string());
    let expected = match commit {
        Some(commit) => format!("rtu2mqtt {} ({commit})", env!("CARGO_PKG_VERSION")),
        None => format!("rtu2mqtt {}", env!("CARGO_PKG_VERSION")),
    };
    assert_eq!(shown, expected);
    // The manual page's version is the executable's.
    let page = unroff(&text(
        &manual_pages().expect("the manual pages render"),
        "man/rtu2mqtt.1",
    ));
    let version = expected.trim_start_matches("rtu2mqtt ");
    assert!(page.contains(&format!("v{version}")), "{page}");
}
