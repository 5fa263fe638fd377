//! Layered configuration: a TOML file < `ASSAY_*` environment variables < command-line flags.
//!
//! The file's `[eval]`, `[watch]`, `[coordinator]`, `[worker]`, `[submit]`… tables give defaults
//! to the options of that subcommand (keys are the long flags, `-` or `_`); every option can also
//! be set from the environment as `ASSAY_<OPTION>` (`ASSAY_WORKERS=4`, `ASSAY_LEASE_TTL_MS=…`);
//! a flag on the command line wins over both. The same file holds `[judges.*]` and
//! `[embedders.*]`, read by the judge and trainer roles. `examples/assay.toml` is the documented
//! example.
//!
//! The file is the subcommand's `--config FILE`, else `$ASSAY_CONFIG`, else `./assay.toml`
//! when present.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use clap::Command;

/// Variables that already mean something else (the model folder, the log filter, the file
/// itself): no option takes its value from them.
const RESERVED: &[&str] = &["ASSAY_MODELS", "ASSAY_LOG", "ASSAY_CONFIG"];

/// Sections of the file that are not a subcommand's options.
const OTHER_SECTIONS: &[&str] = &["judges", "embedders"];

/// The configuration file `args` name (`--config FILE`), else `$ASSAY_CONFIG`, else
/// `./assay.toml` if there is one.
pub fn file(args: &[OsString]) -> Option<PathBuf> {
    let mut it = args.iter().map(|a| a.to_string_lossy());
    while let Some(a) = it.next() {
        if a == "--config" {
            return it.next().map(|v| PathBuf::from(v.as_ref()));
        }
        if let Some(v) = a.strip_prefix("--config=") {
            return Some(PathBuf::from(v));
        }
    }
    if let Some(p) = std::env::var_os("ASSAY_CONFIG") {
        return Some(PathBuf::from(p));
    }
    let local = PathBuf::from("assay.toml");
    local.is_file().then_some(local)
}

/// `cmd` with every long option of every subcommand readable from `ASSAY_<OPTION>` (options
/// that name their own variable keep it) and, when `file` is given, with the file's values as
/// the defaults of its subcommand's options. An unknown section or key is an error naming the
/// file, the section and the key, with the keys it could have meant.
pub fn layer(mut cmd: Command, file: Option<&Path>) -> Result<Command, String> {
    let table = match file {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| format!("configuration file {}: {e}", path.display()))?;
            let value: toml::Table = toml::from_str(&text)
                .map_err(|e| format!("configuration file {}: {e}", path.display()))?;
            Some((path, value))
        }
        None => None,
    };
    let names: Vec<String> = cmd
        .get_subcommands()
        .map(|s| s.get_name().to_owned())
        .collect();
    for name in &names {
        cmd = cmd.mut_subcommand(name, |mut sc| {
            let ids: Vec<String> = sc
                .get_arguments()
                .filter(|a| a.get_long().is_some() && a.get_env().is_none())
                .map(|a| a.get_id().to_string())
                .collect();
            for id in ids {
                let var = format!("ASSAY_{}", id.to_uppercase());
                if !RESERVED.contains(&var.as_str()) {
                    sc = sc.mut_arg(id, |a| a.env(var));
                }
            }
            sc
        });
    }
    let Some((path, table)) = table else {
        return Ok(cmd);
    };
    for (section, values) in &table {
        if OTHER_SECTIONS.contains(&section.as_str()) {
            continue;
        }
        let Some(sc) = cmd.find_subcommand(section) else {
            return Err(format!(
                "configuration file {}: [{section}] is not a subcommand (sections: {}, {})",
                path.display(),
                names.join(", "),
                OTHER_SECTIONS.join(", ")
            ));
        };
        let Some(values) = values.as_table() else {
            return Err(format!(
                "configuration file {}: {section} must be a table ([{section}])",
                path.display()
            ));
        };
        let known: Vec<String> = sc
            .get_arguments()
            .filter(|a| a.get_long().is_some() && a.get_id() != "config")
            .map(|a| a.get_id().to_string())
            .collect();
        let mut defaults: Vec<(String, Vec<String>)> = Vec::new();
        for (key, value) in values {
            let id = key.replace('-', "_");
            if !known.contains(&id) {
                return Err(format!(
                    "configuration file {}: [{section}] has no option '{key}' (options: {})",
                    path.display(),
                    known
                        .iter()
                        .map(|k| k.replace('_', "-"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
            let scalar = |v: &toml::Value| -> Result<String, String> {
                match v {
                    toml::Value::String(s) => Ok(s.clone()),
                    toml::Value::Integer(i) => Ok(i.to_string()),
                    toml::Value::Float(f) => Ok(f.to_string()),
                    toml::Value::Boolean(b) => Ok(b.to_string()),
                    other => Err(format!(
                        "configuration file {}: [{section}] {key}: expected a string, number, \
                         boolean or a list of them, not {}",
                        path.display(),
                        other.type_str()
                    )),
                }
            };
            let list = match value {
                toml::Value::Array(items) => items.iter().map(scalar).collect::<Result<_, _>>()?,
                v => vec![scalar(v)?],
            };
            defaults.push((id, list));
        }
        cmd = cmd.mut_subcommand(section, |mut sc| {
            for (id, list) in defaults {
                sc = sc.mut_arg(id, |a| a.default_values(list));
            }
            sc
        });
    }
    Ok(cmd)
}

#[cfg(test)]
mod tests {
    use clap::{CommandFactory, FromArgMatches};

    use super::*;

    #[derive(clap::Parser, Debug)]
    struct Cli {
        #[command(subcommand)]
        command: Sub,
    }

    #[derive(clap::Subcommand, Debug)]
    enum Sub {
        Run {
            #[arg(long, default_value_t = 2)]
            workers: u32,
            #[arg(long, default_value = "sim,render")]
            roles: String,
            #[arg(long, value_delimiter = ',')]
            models: Vec<String>,
            #[arg(long)]
            quiet: bool,
            #[arg(long, env = "ASSAY_TEST_OWN_VAR", default_value = "x")]
            own: String,
        },
    }

    fn parse(file: Option<&str>, args: &[&str]) -> Result<Sub, String> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("assay.toml");
        if let Some(text) = file {
            std::fs::write(&path, text).unwrap();
        }
        let cmd = layer(Cli::command(), file.map(|_| path.as_path()))?;
        let m = cmd
            .try_get_matches_from(std::iter::once("assay").chain(args.iter().copied()))
            .map_err(|e| e.to_string())?;
        Ok(Cli::from_arg_matches(&m)
            .map_err(|e| e.to_string())?
            .command)
    }

    #[test]
    fn the_file_gives_defaults_and_flags_win() {
        let file = "[run]\nworkers = 4\nroles = \"sim\"\nmodels = [\"minilm\", \"mpnet\"]\nquiet = true\n\
                    [judges.gpt]\nbackend = \"openai\"\n";
        let Sub::Run {
            workers,
            roles,
            models,
            quiet,
            ..
        } = parse(Some(file), &["run"]).unwrap();
        assert_eq!((workers, roles.as_str(), quiet), (4, "sim", true));
        assert_eq!(models, ["minilm", "mpnet"]);
        let Sub::Run { workers, roles, .. } =
            parse(Some(file), &["run", "--workers", "8"]).unwrap();
        assert_eq!((workers, roles.as_str()), (8, "sim"));
        let Sub::Run { workers, .. } = parse(None, &["run"]).unwrap();
        assert_eq!(workers, 2);
    }

    #[test]
    fn the_documented_example_is_valid_for_the_real_command_line() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/assay.toml");
        let cmd = layer(crate::Cli::command(), Some(&path)).unwrap();
        let m = cmd.try_get_matches_from(["assay", "coordinator"]).unwrap();
        let Some(("coordinator", sub)) = m.subcommand() else {
            panic!("no coordinator subcommand");
        };
        assert_eq!(
            sub.get_one::<String>("metrics_listen").map(String::as_str),
            Some("0.0.0.0:9464")
        );
    }

    #[test]
    fn every_option_gets_an_assay_variable_and_own_variables_are_kept() {
        let cmd = layer(Cli::command(), None).unwrap();
        let run = cmd.find_subcommand("run").unwrap();
        let env = |id: &str| {
            run.get_arguments()
                .find(|a| a.get_id() == id)
                .and_then(|a| a.get_env())
                .map(|e| e.to_string_lossy().into_owned())
        };
        assert_eq!(env("workers").as_deref(), Some("ASSAY_WORKERS"));
        assert_eq!(env("quiet").as_deref(), Some("ASSAY_QUIET"));
        assert_eq!(env("own").as_deref(), Some("ASSAY_TEST_OWN_VAR"));
    }

    #[test]
    fn unknown_sections_keys_and_values_are_errors_that_name_them() {
        let e = parse(Some("[run]\nwokers = 4\n"), &["run"]).unwrap_err();
        assert!(
            e.contains("[run] has no option 'wokers'") && e.contains("workers"),
            "{e}"
        );
        let e = parse(Some("[walk]\nworkers = 4\n"), &["run"]).unwrap_err();
        assert!(e.contains("[walk] is not a subcommand"), "{e}");
        let e = parse(Some("[run]\nworkers = { a = 1 }\n"), &["run"]).unwrap_err();
        assert!(e.contains("workers: expected a string"), "{e}");
        let e = parse(Some("[run]\nworkers = \"many\"\n"), &["run"]).unwrap_err();
        assert!(e.contains("many"), "{e}");
        let e = parse(Some("run = 3"), &["run"]).unwrap_err();
        assert!(e.contains("must be a table"), "{e}");
    }
}
