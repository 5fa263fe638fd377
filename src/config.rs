//! Layered configuration: a TOML file < environment variables < command-line flags.
//!
//! The file's `[eval]`, `[watch]`, `[coordinator]`, `[worker]`, `[submit]`… tables give defaults
//! to the options of that subcommand; keys are its long flags as written on the command line
//! (`asset-root`, `judge`; `_` for `-` is accepted). Only the section of the subcommand that runs
//! is read and checked — a mistake in `[worker]` never stops `assay eval` — and `--help`,
//! `--version` and `help` read no file at all. A bad key or value is an error naming the file,
//! the section, the key and the reason. The same file holds `[judges.*]` and `[embedders.*]`,
//! read by the judge and trainer roles. `examples/assay.toml` is the documented example.
//!
//! Environment variables are scoped: the deployment commands (`coordinator`, `worker`) read
//! every option from `ASSAY_<OPTION>` (`ASSAY_LEASE_TTL_MS`, `ASSAY_CAPACITY`, …), as container
//! manifests set them; every other command reads only the variables its `--help` lists
//! (`[env: …]`: `ASSAY_COORDINATOR`, `ASSAY_CONFIG`, `ASSAY_ARTIFACTS`, …), so a variable set for
//! one command (`ASSAY_SEED`, `ASSAY_OUT`) never changes another. Switches read from a variable
//! or the file accept `1/0`, `true/false`, `yes/no`, `on/off`.
//!
//! The file is the subcommand's `--config FILE`, else `$ASSAY_CONFIG`, else `./assay.toml`
//! when present.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use clap::Command;

/// The commands whose every option is also an `ASSAY_<OPTION>` variable.
const DEPLOYED: &[&str] = &["coordinator", "worker"];

/// Variables that already mean something else (the model folder, the log filter, the file
/// itself): no option takes its value from them.
const RESERVED: &[&str] = &["ASSAY_MODELS", "ASSAY_LOG", "ASSAY_CONFIG"];

/// Sections of the file that are not a subcommand's options.
const OTHER_SECTIONS: &[&str] = &["judges", "embedders"];

/// The configuration file `args` name (`--config FILE`), else `$ASSAY_CONFIG`, else
/// `./assay.toml` if there is one.
pub fn file(args: &[OsString]) -> Option<PathBuf> {
    let asks_help = args.iter().skip(1).any(|a| {
        matches!(
            a.to_str(),
            Some("--help" | "-h" | "--version" | "-V" | "help")
        )
    });
    if asks_help || subcommand(args).is_none() {
        return None;
    }
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

/// The subcommand `args` run: the first argument after the program that is not an option.
pub fn subcommand(args: &[OsString]) -> Option<String> {
    args.iter()
        .skip(1)
        .filter_map(|a| a.to_str())
        .find(|a| !a.starts_with('-'))
        .map(str::to_owned)
}

/// `cmd` with the options of the deployment commands readable from `ASSAY_<OPTION>` (options
/// that name their own variable keep it), switches that accept `1/0/yes/no/on/off`, and, when
/// `file` is given, the file's `[running]` section as the defaults of that subcommand's options.
/// An unknown key, or a value the option refuses, is an error naming the file, the section and
/// the key.
pub fn layer(
    mut cmd: Command,
    file: Option<&Path>,
    running: Option<&str>,
) -> Result<Command, String> {
    let names: Vec<String> = cmd
        .get_subcommands()
        .map(|s| s.get_name().to_owned())
        .collect();
    for name in &names {
        let deployed = DEPLOYED.contains(&name.as_str());
        cmd = cmd.mut_subcommand(name, |mut sc| {
            let args: Vec<(String, bool, bool)> = sc
                .get_arguments()
                .filter(|a| a.get_long().is_some())
                .map(|a| {
                    (
                        a.get_id().to_string(),
                        a.get_env().is_none(),
                        matches!(a.get_action(), clap::ArgAction::SetTrue),
                    )
                })
                .collect();
            for (id, no_env, switch) in args {
                if switch {
                    sc = sc.mut_arg(&id, |a| {
                        a.value_parser(clap::builder::BoolishValueParser::new())
                    });
                }
                let var = format!("ASSAY_{}", id.to_uppercase());
                if deployed && no_env && !RESERVED.contains(&var.as_str()) {
                    sc = sc.mut_arg(&id, |a| a.env(var));
                }
            }
            sc
        });
    }
    let (Some(path), Some(section)) = (file, running) else {
        return Ok(cmd);
    };
    let at = |what: String| format!("configuration file {}: {what}", path.display());
    let text = std::fs::read_to_string(path).map_err(|e| at(e.to_string()))?;
    let table: toml::Table = toml::from_str(&text).map_err(|e| at(e.to_string()))?;
    for key in table.keys() {
        if !OTHER_SECTIONS.contains(&key.as_str()) && cmd.find_subcommand(key).is_none() {
            // Said, not fatal: another command's section is not this command's business.
            eprintln!(
                "warning: {}",
                at(format!(
                    "[{key}] is not a subcommand and is ignored (sections: {}, {})",
                    names.join(", "),
                    OTHER_SECTIONS.join(", ")
                ))
            );
        }
    }
    let Some(values) = table.get(section) else {
        return Ok(cmd);
    };
    let Some(sc) = cmd.find_subcommand(section) else {
        return Ok(cmd);
    };
    let Some(values) = values.as_table() else {
        return Err(at(format!("{section} must be a table ([{section}])")));
    };
    // Keys are the long flags (`asset-root`), `_` accepted for `-`.
    let flags: Vec<(String, String)> = sc
        .get_arguments()
        .filter(|a| a.get_id() != "config")
        .filter_map(|a| a.get_long().map(|l| (l.to_owned(), a.get_id().to_string())))
        .collect();
    let mut defaults: Vec<(String, Vec<String>)> = Vec::new();
    for (key, value) in values {
        let flag = key.replace('_', "-");
        let Some((_, id)) = flags.iter().find(|(l, _)| *l == flag) else {
            return Err(at(format!(
                "[{section}] has no option '{key}' (options: {})",
                flags
                    .iter()
                    .map(|(l, _)| l.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        };
        let scalar = |v: &toml::Value| -> Result<String, String> {
            match v {
                toml::Value::String(s) => Ok(s.clone()),
                toml::Value::Integer(i) => Ok(i.to_string()),
                toml::Value::Float(f) => Ok(f.to_string()),
                toml::Value::Boolean(b) => Ok(b.to_string()),
                other => Err(at(format!(
                    "[{section}] {key}: expected a string, number, boolean or a list of them, \
                     not {}",
                    other.type_str()
                ))),
            }
        };
        let list: Vec<String> = match value {
            toml::Value::Array(items) => items.iter().map(scalar).collect::<Result<_, _>>()?,
            v => vec![scalar(v)?],
        };
        defaults.push((id.clone(), list));
    }
    cmd = cmd.mut_subcommand(section, |mut sc| {
        for (id, list) in defaults {
            sc = sc.mut_arg(id, |a| a.default_values(list));
        }
        sc
    });
    Ok(cmd)
}

/// When a command line fails on a value, the file key that gave it, if the file did:
/// `configuration file F: [section] key = "v"`, for the error to name the file rather than
/// only the flag.
pub fn blame(file: Option<&Path>, section: Option<&str>, err: &clap::Error) -> Option<String> {
    use clap::error::{ContextKind, ContextValue, ErrorKind};
    if !matches!(
        err.kind(),
        ErrorKind::InvalidValue | ErrorKind::ValueValidation
    ) {
        return None;
    }
    let (path, section) = (file?, section?);
    let flag = match err.get(ContextKind::InvalidArg)? {
        ContextValue::String(s) => s
            .trim_start_matches('-')
            .split([' ', '='])
            .next()?
            .to_owned(),
        _ => return None,
    };
    let value = match err.get(ContextKind::InvalidValue) {
        Some(ContextValue::String(v)) => Some(v.clone()),
        _ => None,
    };
    let table: toml::Table = toml::from_str(&std::fs::read_to_string(path).ok()?).ok()?;
    let (key, given) = table
        .get(section)?
        .as_table()?
        .iter()
        .find(|(k, _)| k.replace('_', "-") == flag)?;
    let shown = match (value, given) {
        (Some(v), _) => format!("{v:?}"),
        (None, g) => g.to_string(),
    };
    Some(format!(
        "configuration file {}: [{section}] {key} = {shown}",
        path.display()
    ))
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
            #[arg(long = "model", value_delimiter = ',')]
            models: Vec<String>,
            #[arg(long)]
            quiet: bool,
            #[arg(long, env = "ASSAY_TEST_OWN_VAR", default_value = "x")]
            own: String,
        },
        Worker {
            #[arg(long, default_value_t = 1)]
            capacity: u32,
        },
    }

    fn parse(file: Option<&str>, args: &[&str]) -> Result<Sub, String> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("assay.toml");
        if let Some(text) = file {
            std::fs::write(&path, text).unwrap();
        }
        let cmd = layer(
            Cli::command(),
            file.map(|_| path.as_path()),
            args.first().copied(),
        )?;
        let m = cmd
            .try_get_matches_from(std::iter::once("assay").chain(args.iter().copied()))
            .map_err(|e| e.to_string())?;
        Ok(Cli::from_arg_matches(&m)
            .map_err(|e| e.to_string())?
            .command)
    }

    #[test]
    fn the_file_gives_defaults_and_flags_win() {
        let file = "[run]\nworkers = 4\nroles = \"sim\"\nmodel = [\"minilm\", \"mpnet\"]\nquiet = true\n\
                    [judges.gpt]\nbackend = \"openai\"\n";
        let Sub::Run {
            workers,
            roles,
            models,
            quiet,
            ..
        } = parse(Some(file), &["run"]).unwrap()
        else {
            panic!()
        };
        assert_eq!((workers, roles.as_str(), quiet), (4, "sim", true));
        assert_eq!(models, ["minilm", "mpnet"]);
        let Sub::Run { workers, roles, .. } =
            parse(Some(file), &["run", "--workers", "8"]).unwrap()
        else {
            panic!()
        };
        assert_eq!((workers, roles.as_str()), (8, "sim"));
        let Sub::Run { workers, .. } = parse(None, &["run"]).unwrap() else {
            panic!()
        };
        assert_eq!(workers, 2);
    }

    #[test]
    fn keys_are_the_flags_and_switches_read_like_people_write_them() {
        // `--model` is the flag (its field is `models`): the flag is the key.
        let e = parse(Some("[run]\nmodels = [\"a\"]\n"), &["run"]).unwrap_err();
        assert!(
            e.contains("[run] has no option 'models'") && e.contains("model"),
            "{e}"
        );
        for yes in ["1", "yes", "on", "true"] {
            let Sub::Run { quiet, .. } =
                parse(Some(&format!("[run]\nquiet = \"{yes}\"\n")), &["run"]).unwrap()
            else {
                panic!()
            };
            assert!(quiet, "{yes}");
        }
        let Sub::Run { quiet, .. } = parse(Some("[run]\nquiet = \"no\"\n"), &["run"]).unwrap()
        else {
            panic!()
        };
        assert!(!quiet);
    }

    #[test]
    fn only_the_running_command_reads_its_section() {
        // A mistake in [worker] does not stop `run`; `worker` itself refuses it.
        let file = "[worker]\ncapcity = 2\n[run]\nworkers = 3\n[wroker]\nx = 1\n";
        let Sub::Run { workers, .. } = parse(Some(file), &["run"]).unwrap() else {
            panic!()
        };
        assert_eq!(workers, 3);
        let e = parse(Some(file), &["worker"]).unwrap_err();
        assert!(e.contains("[worker] has no option 'capcity'"), "{e}");
        // --help and --version read no file.
        let args = |v: &[&str]| v.iter().map(OsString::from).collect::<Vec<_>>();
        assert_eq!(file_for_test(&args(&["assay", "--version"])), None);
        assert_eq!(file_for_test(&args(&["assay", "eval", "--help"])), None);
        assert_eq!(
            subcommand(&args(&["assay", "--quiet", "eval", "x"])).as_deref(),
            Some("eval")
        );
    }

    /// [`file`] with `--config` given, so the answer does not depend on the working folder.
    fn file_for_test(args: &[OsString]) -> Option<PathBuf> {
        let mut with = args.to_vec();
        with.extend([OsString::from("--config"), OsString::from("x.toml")]);
        file(&with)
    }

    #[test]
    fn the_documented_example_is_valid_for_the_real_command_line() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/assay.toml");
        for name in crate::Cli::command()
            .get_subcommands()
            .map(|s| s.get_name().to_owned())
        {
            layer(crate::Cli::command(), Some(&path), Some(&name))
                .unwrap_or_else(|e| panic!("{name}: {e}"));
        }
        let cmd = layer(crate::Cli::command(), Some(&path), Some("coordinator")).unwrap();
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
    fn deployment_commands_read_every_option_from_the_environment_and_others_do_not() {
        let cmd = layer(Cli::command(), None, None).unwrap();
        let env = |sub: &str, id: &str| {
            cmd.find_subcommand(sub)
                .unwrap()
                .get_arguments()
                .find(|a| a.get_id() == id)
                .and_then(|a| a.get_env())
                .map(|e| e.to_string_lossy().into_owned())
        };
        assert_eq!(env("worker", "capacity").as_deref(), Some("ASSAY_CAPACITY"));
        assert_eq!(env("run", "workers"), None, "ASSAY_WORKERS is not run's");
        assert_eq!(env("run", "quiet"), None);
        assert_eq!(env("run", "own").as_deref(), Some("ASSAY_TEST_OWN_VAR"));
    }

    #[test]
    fn bad_keys_and_values_are_errors_that_name_the_file_and_the_key() {
        let e = parse(Some("[run]\nwokers = 4\n"), &["run"]).unwrap_err();
        assert!(
            e.contains("[run] has no option 'wokers'") && e.contains("workers"),
            "{e}"
        );
        let e = parse(Some("[run]\nworkers = { a = 1 }\n"), &["run"]).unwrap_err();
        assert!(e.contains("workers: expected a string"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("assay.toml");
        std::fs::write(&path, "[run]\nworkers = \"many\"\n").unwrap();
        let e = layer(Cli::command(), Some(&path), Some("run"))
            .unwrap()
            .try_get_matches_from(["assay", "run"])
            .unwrap_err();
        let said = blame(Some(&path), Some("run"), &e).expect("the file is blamed");
        assert!(
            said.starts_with("configuration file ") && said.contains("[run] workers = \"many\""),
            "{said}"
        );
        let e = parse(Some("run = 3"), &["run"]).unwrap_err();
        assert!(e.contains("must be a table"), "{e}");
    }
}
