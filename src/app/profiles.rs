//! `rtu2mqtt profiles [NAME|FILE]…`: lists built-in profiles and profile files with their
//! fields, blocks and write rules.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use rtu2mqtt_profile::registry::{
    built_in, built_in_names, describe, library_names, load_file, LoadError,
};
use rtu2mqtt_profile::Profile;

/// What one argument of `rtu2mqtt profiles` names: a built-in profile by its name, else a
/// profile file by its path.
fn load_listed(argument: &Path) -> Result<(Profile, Option<&Path>), LoadError> {
    if let Some(name) = argument
        .to_str()
        .filter(|name| built_in_names().contains(name))
    {
        return built_in(name).map(|profile| (profile, None));
    }
    match std::fs::metadata(argument) {
        Ok(_) => load_file(argument).map(|profile| (profile, Some(argument))),
        Err(source) if source.kind() == std::io::ErrorKind::NotFound => {
            Err(LoadError::NeitherBuiltInNorFile {
                name: argument.display().to_string(),
                known: built_in_names().join(", "),
            })
        }
        Err(source) => Err(LoadError::Read {
            path: argument.display().to_string(),
            source,
        }),
    }
}

/// `rtu2mqtt profiles [NAME|FILE]…`: with no argument every built-in profile, otherwise only
/// the built-ins named and the files given, in argument order, each with its fields. Any
/// argument that cannot be listed is reported on stderr and makes the exit status 1.
pub fn print_profiles(arguments: &[PathBuf]) -> anyhow::Result<ExitCode> {
    use std::io::Write as _;
    let listed: Vec<PathBuf> = if arguments.is_empty() {
        built_in_names().into_iter().map(PathBuf::from).collect()
    } else {
        arguments.to_vec()
    };
    let mut listing = String::new();
    let mut problems = String::new();
    for argument in &listed {
        match load_listed(argument) {
            Ok((profile, None)) if library_names().contains(&profile.name()) => {
                listing.push_str(&format!(
                    "{}  device library: config/profiles/{}.toml names its register map\n\n",
                    describe(&profile),
                    profile.name()
                ))
            }
            Ok((profile, None)) => listing.push_str(&format!("{}\n", describe(&profile))),
            Ok((profile, Some(path))) => listing.push_str(&format!(
                "{}  file: {}\n\n",
                describe(&profile),
                path.display()
            )),
            Err(err) => problems.push_str(&format!("{err}\n")),
        }
    }
    // A closed pipe (`rtu2mqtt profiles | head`) is not an error worth a panic.
    let _ = std::io::stdout().lock().write_all(listing.as_bytes());
    let _ = std::io::stderr().lock().write_all(problems.as_bytes());
    Ok(if problems.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}
