//! The manual pages, section 1: one for `rtu2mqtt` and one for each of its commands, each
//! closed by its "see also".

use std::io;
use std::path::{Path, PathBuf};

use clap_mangen::roff::{bold, roman, Roff};
use clap_mangen::Man;
use rtu2mqtt::cli::VERSION;

use crate::asset::{command, Asset, BIN_NAME};

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
