//! The files a package installs beside `rtu2mqtt` that are made from its command line's own
//! definition ([`rtu2mqtt::cli::Cli`]): a manual page for `rtu2mqtt` and one for each of its
//! commands (`rtu2mqtt-run(1)`, …), and completions for bash, zsh and fish. Generated from the
//! same definition `--help` prints, they cannot describe another command line.
//!
//! This is a crate of its own so that the generators stay out of the daemon's executable.

use std::io;
use std::path::{Path, PathBuf};

use clap::CommandFactory;
use clap_complete::Shell;
use clap_mangen::roff::{bold, roman, Roff};
use clap_mangen::Man;
use rtu2mqtt::cli::VERSION;

/// The executable's name, in every generated file.
pub const BIN_NAME: &str = "rtu2mqtt";

/// One generated file: where it goes below the output directory, and its contents.
#[derive(Debug, Clone)]
pub struct Asset {
    pub path: PathBuf,
    pub contents: Vec<u8>,
}

/// Where each completion script goes below the output directory, named as its shell looks for
/// it once installed (bash: `rtu2mqtt`, zsh: `_rtu2mqtt`, fish: `rtu2mqtt.fish`).
pub const COMPLETIONS: [(Shell, &str); 3] = [
    (Shell::Bash, "completions/rtu2mqtt.bash"),
    (Shell::Zsh, "completions/_rtu2mqtt"),
    (Shell::Fish, "completions/rtu2mqtt.fish"),
];

/// The command line as the executable sees it: built, named, without clap's `help` command
/// (every command has `--help`, and a manual page for `help` would say nothing).
fn command() -> clap::Command {
    let mut command = rtu2mqtt::cli::Cli::command()
        .bin_name(BIN_NAME)
        .disable_help_subcommand(true);
    command.build();
    command
}

/// The manual pages, section 1: `man/rtu2mqtt.1` and `man/rtu2mqtt-<command>.1` for each
/// command.
pub fn manual_pages() -> io::Result<Vec<Asset>> {
    let command = command();
    let mut pages = vec![Asset {
        path: PathBuf::from(format!("man/{BIN_NAME}.1")),
        contents: main_page(&command)?,
    }];
    for subcommand in command.get_subcommands().filter(|s| !s.is_hide_set()) {
        // A command has no version of its own: its page's footer names the executable's.
        let man = Man::new(subcommand.clone()).source(format!("{BIN_NAME} {VERSION}"));
        let mut contents = Vec::new();
        man.render(&mut contents)?;
        see_also(&[format!("{BIN_NAME}(1)")]).to_writer(&mut contents)?;
        pages.push(Asset {
            path: Path::new("man").join(man.get_filename()),
            contents,
        });
    }
    Ok(pages)
}

/// `rtu2mqtt(1)`: what clap knows (name, synopsis, options, commands), then what a manual page
/// of a daemon also says: the files it reads and writes, and where to read on.
fn main_page(command: &clap::Command) -> io::Result<Vec<u8>> {
    let man = Man::new(command.clone());
    let mut page = Vec::new();
    man.render_title(&mut page)?;
    man.render_name_section(&mut page)?;
    man.render_synopsis_section(&mut page)?;
    man.render_description_section(&mut page)?;
    man.render_options_section(&mut page)?;
    man.render_subcommands_section(&mut page)?;
    files_section().to_writer(&mut page)?;
    let mut related: Vec<String> = command
        .get_subcommands()
        .filter(|s| !s.is_hide_set())
        .map(|s| format!("{BIN_NAME}-{}(1)", s.get_name()))
        .collect();
    related.extend(["systemctl(1)", "journalctl(1)", "systemd.exec(5)"].map(String::from));
    see_also(&related).to_writer(&mut page)?;
    man.render_version_section(&mut page)?;
    Ok(page)
}

/// FILES: the paths the packaged service uses.
fn files_section() -> Roff {
    let mut roff = Roff::default();
    roff.control("SH", ["FILES"]);
    for (path, what) in [
        (
            "/etc/rtu2mqtt/config.toml",
            "The configuration (TOML). After editing it, \"systemctl reload rtu2mqtt\" applies \
             it; \"rtu2mqtt check\" validates it first.",
        ),
        (
            "/etc/rtu2mqtt/mqtt-password",
            "The broker's password, readable by root only, handed to the service as the \
             systemd credential \"mqtt-password\".",
        ),
        (
            "/var/lib/rtu2mqtt/",
            "The service's state directory: the history journal and the Sparkplug bdSeq.",
        ),
        (
            "/run/rtu2mqtt/health",
            "The status file the daemon rewrites every few seconds and \"rtu2mqtt health\" \
             reads.",
        ),
        (
            "/usr/share/doc/rtu2mqtt/",
            "The changelog and the copyright; the configuration keys and every topic are \
             described in the project's documentation.",
        ),
    ] {
        roff.control("TP", []);
        roff.text([bold(path)]);
        roff.text([roman(what)]);
    }
    roff
}

/// SEE ALSO: the related pages, comma-separated.
fn see_also(pages: &[String]) -> Roff {
    let mut roff = Roff::default();
    roff.control("SH", ["SEE ALSO"]);
    roff.text([roman(pages.join(", "))]);
    roff
}

/// The completion scripts for bash, zsh and fish.
pub fn completions() -> Vec<Asset> {
    COMPLETIONS
        .iter()
        .map(|(shell, path)| {
            let mut contents = Vec::new();
            clap_complete::generate(*shell, &mut command(), BIN_NAME, &mut contents);
            Asset {
                path: PathBuf::from(path),
                contents,
            }
        })
        .collect()
}

/// Every asset, written below `dir` (directories made as needed); returns the paths written.
pub fn write_all(dir: &Path) -> io::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    for asset in manual_pages()?.into_iter().chain(completions()) {
        let path = dir.join(&asset.path);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::write(&path, &asset.contents)?;
        written.push(path);
    }
    Ok(written)
}
