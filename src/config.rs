//! Layered configuration: a TOML file < environment variables < command-line flags.
//!
//! The file's `[eval]`, `[watch]`, `[coordinator]`, `[worker]`, `[submit]`… tables give defaults
//! to the options of that subcommand; keys are its long flags as written on the command line
//! (`asset-root`, `judge`; `_` for `-` is accepted) and its positional arguments by name
//! (`paths`). Nested settings (`world-model`, `proxy`, `rank-ladder`, `generalization`) are
//! tables (`[eval.world-model]`), handed to the option as JSON and checked, like every value,
//! while the command line is read — before anything starts. Only the section of the subcommand that runs
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
//! when present. `assay eval` writes the run's resolved configuration ([`resolved`]) to
//! OUT/config.toml, a file of this form that `--config` reads back.

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
pub fn layer(cmd: Command, file: Option<&Path>, running: Option<&str>) -> Result<Command, String> {
    let cmd = with_environment(cmd);
    let (Some(path), Some(section)) = (file, running) else {
        return Ok(cmd);
    };
    let at = |what: String| format!("configuration file {}: {what}", path.display());
    let text = std::fs::read_to_string(path).map_err(|e| at(e.to_string()))?;
    let table: toml::Table = toml::from_str(&text).map_err(|e| at(e.to_string()))?;
    warn_other_sections(&cmd, &table, &at);
    let Some(values) = table.get(section) else {
        return Ok(cmd);
    };
    if cmd.find_subcommand(section).is_none() {
        return Ok(cmd);
    }
    let Some(values) = values.as_table() else {
        return Err(at(format!("{section} must be a table ([{section}])")));
    };
    let defaults = file_defaults(&cmd, section, values, &at)?;
    Ok(cmd.mut_subcommand(section, |mut sc| {
        for (id, list) in defaults {
            // A positional the file gives is no longer required on the command line.
            sc = sc.mut_arg(id, |a| a.required(false).default_values(list));
        }
        sc
    }))
}

/// Switches that accept `1/0/yes/no/on/off`, and the deployment commands' options readable from
/// `ASSAY_<OPTION>` (options that name their own variable keep it).
fn with_environment(mut cmd: Command) -> Command {
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
    cmd
}

/// Warns of sections of the file that are no subcommand's (said, not fatal: another command's
/// section is not this command's business).
fn warn_other_sections(cmd: &Command, table: &toml::Table, at: &dyn Fn(String) -> String) {
    let names: Vec<String> = cmd
        .get_subcommands()
        .map(|s| s.get_name().to_owned())
        .collect();
    for key in table.keys() {
        if !OTHER_SECTIONS.contains(&key.as_str()) && cmd.find_subcommand(key).is_none() {
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
}

/// The file's `[section]` values as defaults of the subcommand's options, by option id. An
/// unknown key, or a value of a type no option takes, is an error naming the key.
fn file_defaults(
    cmd: &Command,
    section: &str,
    values: &toml::Table,
    at: &dyn Fn(String) -> String,
) -> Result<Vec<(String, Vec<String>)>, String> {
    let sc = cmd.find_subcommand(section).expect("checked by the caller");
    // Keys are the long flags (`asset-root`), `_` accepted for `-`, and the positional
    // arguments by name (`paths`).
    let flags: Vec<(String, String)> = sc
        .get_arguments()
        .filter(|a| a.get_id() != "config")
        .filter_map(|a| {
            let id = a.get_id().to_string();
            match a.get_long() {
                Some(l) => Some((l.to_owned(), id)),
                None if a.is_positional() => Some((id.replace('_', "-"), id)),
                None => None,
            }
        })
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
                    "[{section}] {key}: expected a string, number, boolean, a list of them or a \
                     table, not {}",
                    other.type_str()
                ))),
            }
        };
        let list: Vec<String> = match value {
            toml::Value::Array(items) => items.iter().map(scalar).collect::<Result<_, _>>()?,
            // A nested setting (`[eval.world-model]`): the option takes it as JSON, and checks
            // it when the command line is read, before anything starts.
            toml::Value::Table(t) => vec![serde_json::to_string(t).map_err(|e| at(e.to_string()))?],
            v => vec![scalar(v)?],
        };
        defaults.push((id.clone(), list));
    }
    Ok(defaults)
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

/// Options a resolved configuration leaves out: the file itself, and what only makes sense once.
const NOT_RESOLVED: &[&str] = &["config", "force", "help", "version"];

/// The resolved configuration of a `section` run: every option it ran with (from the command
/// line, the environment, the file or the option's default) as the `[section]` table of a file
/// that `--config` reads back, the file's `[judges.*]` and `[embedders.*]` tables (the workers
/// read them from the same file), and the command line in a comment.
pub fn resolved(
    cmd: &Command,
    matches: &clap::ArgMatches,
    section: &str,
    file: Option<&Path>,
    args: &[OsString],
) -> String {
    let mut table = toml::Table::new();
    if let (Some(sc), Some(m)) = (
        cmd.find_subcommand(section),
        matches.subcommand_matches(section),
    ) {
        for a in sc.get_arguments() {
            let id = a.get_id().as_str();
            if NOT_RESOLVED.contains(&id) || m.value_source(id).is_none() {
                continue;
            }
            let Ok(Some(raw)) = m.try_get_raw(id) else {
                continue;
            };
            let mut values: Vec<toml::Value> = raw.map(|v| typed(&v.to_string_lossy())).collect();
            let many = matches!(a.get_action(), clap::ArgAction::Append)
                || a.get_value_delimiter().is_some()
                || a.get_num_args().is_some_and(|r| r.max_values() > 1);
            let key = a
                .get_long()
                .map_or_else(|| id.replace('_', "-"), str::to_owned);
            match (values.len(), many) {
                (0, _) => {}
                (1, false) => {
                    table.insert(key, values.remove(0));
                }
                _ => {
                    table.insert(key, toml::Value::Array(values));
                }
            }
        }
    }
    let mut out = toml::Table::new();
    out.insert(section.to_owned(), toml::Value::Table(table));
    let original = file
        .and_then(|f| std::fs::read_to_string(f).ok())
        .and_then(|t| toml::from_str::<toml::Table>(&t).ok());
    for name in OTHER_SECTIONS {
        if let Some(t) = original.as_ref().and_then(|o| o.get(*name)) {
            out.insert((*name).to_owned(), t.clone());
        }
    }
    let line: Vec<String> = std::iter::once("assay".to_owned())
        .chain(
            args.iter()
                .skip(1)
                .map(|a| shell_word(&a.to_string_lossy())),
        )
        .collect();
    let cwd = std::env::current_dir()
        .map(|d| d.display().to_string())
        .unwrap_or_default();
    format!(
        "# The resolved configuration of this run: `assay {section} --config THIS_FILE` runs it again\n\
         # (flags still win: add --out DIR to run it into another folder). Relative paths are\n\
         # relative to the folder the run started in.\n\
         # Command line: {}\n\
         # Started in: {cwd}\n\n{}",
        line.join(" "),
        toml::to_string_pretty(&out).unwrap_or_default()
    )
}

/// A command-line value as TOML: JSON objects (nested settings) as tables, integers and booleans
/// as themselves, anything else (floats included: "0.02" stays as typed) as a string — the
/// option parses it either way.
fn typed(v: &str) -> toml::Value {
    if v.starts_with('{')
        && let Ok(serde_json::Value::Object(o)) = serde_json::from_str::<serde_json::Value>(v)
        && let Ok(toml::Value::Table(t)) = toml::Value::try_from(serde_json::Value::Object(o))
    {
        return toml::Value::Table(t);
    }
    if let Ok(i) = v.parse::<i64>()
        && i.to_string() == v
    {
        return toml::Value::Integer(i);
    }
    match v {
        "true" => toml::Value::Boolean(true),
        "false" => toml::Value::Boolean(false),
        _ => toml::Value::String(v.to_owned()),
    }
}

/// `w` quoted for a POSIX shell when it needs to be.
fn shell_word(w: &str) -> String {
    if !w.is_empty()
        && w.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,@+".contains(c))
    {
        w.to_owned()
    } else {
        format!("'{}'", w.replace('\'', "'\\''"))
    }
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
    fn the_demo_profiles_are_valid_for_the_real_command_line() {
        for name in ["demo", "paper"] {
            let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("examples/{name}.toml"));
            let cmd = layer(crate::Cli::command(), Some(&path), Some("eval")).unwrap();
            let m = cmd
                .try_get_matches_from(["assay", "eval"])
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            let Some(("eval", sub)) = m.subcommand() else {
                panic!("no eval subcommand");
            };
            // Task folders or task files, all of them there, and every group the ranking or
            // the generalization names among their tasks' groups.
            let paths: Vec<PathBuf> = sub
                .get_many::<PathBuf>("paths")
                .unwrap()
                .map(|p| Path::new(env!("CARGO_MANIFEST_DIR")).join(p))
                .collect();
            for p in &paths {
                assert!(p.exists(), "{name}: {}", p.display());
            }
            let docs = assay_run::docs::collect(&paths).unwrap();
            let (tasks, invalid) = assay_plan::plan_tasks(&docs, &[]);
            assert!(invalid.is_empty(), "{name}: {invalid:?}");
            let groups: Vec<&str> = tasks.iter().map(|t| t.info.group.as_str()).collect();
            let mut named: Vec<String> = sub
                .get_many::<String>("rank_groups")
                .into_iter()
                .flatten()
                .cloned()
                .collect();
            if let Some(g) = sub.get_one::<String>("generalization") {
                let plan: assay_model::generalization::GeneralizationPlan =
                    serde_json::from_str(g).unwrap();
                named.extend(plan.groups);
            }
            for g in &named {
                assert!(
                    groups.contains(&g.as_str()),
                    "{name}: group {g} in {groups:?}"
                );
            }
        }
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
        // A table is a nested setting (JSON to the option), which a number refuses.
        let e = parse(Some("[run]\nworkers = { a = 1 }\n"), &["run"]).unwrap_err();
        assert!(e.contains("'{\"a\":1}'") && e.contains("--workers"), "{e}");
        let e = parse(Some("[run]\nworkers = 2024-01-01\n"), &["run"]).unwrap_err();
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

    /// The real command line with `file` as its configuration file.
    fn eval_matches(file: &str, args: &[&str]) -> (Command, Result<clap::ArgMatches, String>) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("assay.toml");
        std::fs::write(&path, file).unwrap();
        let cmd = layer(crate::Cli::command(), Some(&path), Some("eval")).unwrap();
        let m = cmd.clone().try_get_matches_from(args).map_err(|e| {
            let said = blame(Some(&path), Some("eval"), &e).unwrap_or_default();
            format!("{said}\n{e}")
        });
        (cmd, m)
    }

    #[test]
    fn nested_settings_are_tables_checked_before_anything_starts() {
        let file = "[eval]\npaths = [\"examples/tasks\"]\n\
                    [eval.world-model]\nsteps = 300\nimage_size = 32\n\
                    [eval.generalization]\nepisodes = 10\nconfig = { steps = 200 }\n";
        let (_, m) = eval_matches(file, &["assay", "eval"]);
        let m = m.unwrap();
        let Some(("eval", sub)) = m.subcommand() else {
            panic!("no eval")
        };
        let wm: serde_json::Value =
            serde_json::from_str(sub.get_one::<String>("world_model").unwrap()).unwrap();
        assert_eq!(wm, serde_json::json!({"steps": 300, "image_size": 32}));
        let g: serde_json::Value =
            serde_json::from_str(sub.get_one::<String>("generalization").unwrap()).unwrap();
        assert_eq!(g["config"]["steps"], 200);
        // A misspelt key deep inside a table: refused while the command line is read, naming
        // the file, the key and serde's reason with the field's path.
        let bad = "[eval]\npaths = [\"x\"]\n[eval.generalization]\nconfig = { stepz = 200 }\n";
        let e = eval_matches(bad, &["assay", "eval"]).1.unwrap_err();
        assert!(
            e.contains("configuration file ")
                && e.contains("[eval] generalization")
                && e.contains("config.stepz: unknown field `stepz`"),
            "{e}"
        );
        let e = eval_matches(
            "[eval.world-model]\nsteps = \"many\"\n",
            &["assay", "eval", "x"],
        )
        .1
        .unwrap_err();
        assert!(e.contains("steps: invalid type: string \"many\""), "{e}");
        // The same on the command line, without a file.
        let e = crate::Cli::command()
            .try_get_matches_from(["assay", "eval", "x", "--proxy", "{\"judge_stepz\": 1}"])
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown field `judge_stepz`"), "{e}");
    }

    #[test]
    fn a_resolved_configuration_reads_back_as_the_same_run() {
        let args = [
            "assay",
            "eval",
            "examples/tasks/stacking",
            "--seeds",
            "2",
            "--policy",
            "oracle",
            "--policy",
            "oracle:noise=0.02",
            "--world-model",
            "{\"steps\": 10, \"image_size\": 32}",
            "--dynamics-budgets",
            "2,4",
            "--out",
            "runs/first",
            "--force",
        ];
        let (cmd, m) = eval_matches("[judges.x]\nbackend = \"offline\"\n", &args);
        let dir = tempfile::tempdir().unwrap();
        let original = dir.path().join("original.toml");
        std::fs::write(&original, "[judges.x]\nbackend = \"offline\"\n").unwrap();
        let os: Vec<OsString> = args.iter().map(OsString::from).collect();
        let first = resolved(&cmd, &m.unwrap(), "eval", Some(&original), &os);
        assert!(first.contains("# Command line: assay eval examples/tasks/stacking --seeds 2"));
        assert!(
            first.contains("'{\"steps\": 10, \"image_size\": 32}'"),
            "{first}"
        );
        let t: toml::Table = toml::from_str(&first).unwrap();
        assert_eq!(t["eval"]["seeds"].as_integer(), Some(2));
        assert_eq!(t["eval"]["world-model"]["steps"].as_integer(), Some(10));
        assert_eq!(
            t["eval"]["paths"][0].as_str(),
            Some("examples/tasks/stacking")
        );
        assert_eq!(t["judges"]["x"]["backend"].as_str(), Some("offline"));
        assert!(t["eval"].get("force").is_none(), "--force is not repeated");
        // Read back, the file gives the same run, and resolves to the same file.
        let (cmd, m) = eval_matches(&first, &["assay", "eval"]);
        let again = resolved(
            &cmd,
            &m.unwrap(),
            "eval",
            Some(&original),
            &["assay", "eval"].map(OsString::from),
        );
        let body = |s: &str| {
            s.lines()
                .filter(|l| !l.starts_with('#'))
                .collect::<Vec<_>>()
                .join("\n")
        };
        assert_eq!(body(&again), body(&first));
    }
}
