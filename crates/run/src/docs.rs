//! Reading task documents from files and folders, the asset roots a batch's tasks are confined
//! to, and the roots a local cluster gives its workers.
//!
//! Owns: the walk (sorted, confined to each root given, skipping Assay's own output folders).
//! Never parses a document (the planner does).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use assay_plan::TaskDocument;

/// Every `.yaml`, `.yml` and `.json` file under `paths` (folders are walked, sorted by path).
///
/// Each path given is a root the walk stays in: a symbolic link is followed only when what it
/// points to is inside that root (a link out of it is refused, naming both), and Assay output
/// folders (those holding [`crate::outdir::MARKER`]) are skipped, so a run never reads its own
/// report as a task.
pub fn collect(paths: &[PathBuf]) -> anyhow::Result<Vec<TaskDocument>> {
    let mut files = Vec::new();
    for p in paths {
        let root = p
            .canonicalize()
            .with_context(|| format!("reading {}", p.display()))?;
        walk(p, &root, &mut files).with_context(|| format!("reading {}", p.display()))?;
    }
    if files.is_empty() {
        bail!(
            "no task files (.yaml, .yml, .json) under {}",
            paths
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    files.sort();
    files
        .into_iter()
        .map(|f| {
            let content =
                std::fs::read_to_string(&f).with_context(|| format!("reading {}", f.display()))?;
            let format = if f.extension().is_some_and(|e| e == "json") {
                "json"
            } else {
                "yaml"
            };
            Ok(TaskDocument {
                origin: f.display().to_string(),
                format: format.into(),
                content,
            })
        })
        .collect()
}

/// The folders a batch's tasks may read asset files from: each task path given (a folder, or a
/// file's folder), and each `--asset-root` — or, when none is given, the working folder (so a
/// project's tasks reach its shared assets folder, and nothing above the project). Canonical.
/// The operator sets them; nothing in a task widens them (`TaskSpec::check_asset_roots`).
pub fn asset_roots(paths: &[PathBuf], extra: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    let mut roots = Vec::new();
    if extra.is_empty() {
        roots.push(
            std::env::current_dir()
                .and_then(|d| d.canonicalize())
                .context("the working folder")?,
        );
    }
    for p in paths {
        let c = p
            .canonicalize()
            .with_context(|| format!("reading {}", p.display()))?;
        let dir = if c.is_dir() {
            c
        } else {
            c.parent().map(Path::to_path_buf).unwrap_or(c)
        };
        roots.push(dir);
    }
    for p in extra {
        roots.push(
            p.canonicalize()
                .with_context(|| format!("--asset-root {}", p.display()))?,
        );
    }
    roots.sort();
    roots.dedup();
    Ok(roots)
}

/// The folders the workers of a local cluster may read files from: the batch's asset roots
/// (`task_roots`, [`asset_roots`]) and the folder of each model file the user's own `--policy`
/// values name as a file that exists here (`torchscript:path=bc.pt`, a `diffusion:model=` that
/// is a file rather than an artifact key). A worker opens a policy's model only below its roots
/// or its artifact store; the user's command line is the operator's, so a local run reaches its
/// own models wherever they lie. Canonical. A name that does not parse is left to the planner
/// to refuse.
pub fn worker_roots(task_roots: &[PathBuf], policies: &[String]) -> Vec<PathBuf> {
    use assay_model::policy::PolicySpec;
    let mut roots = task_roots.to_vec();
    for name in policies {
        let path = match PolicySpec::parse(name) {
            Ok(PolicySpec::TorchScript { path, .. }) => path,
            Ok(PolicySpec::Diffusion { model }) => model,
            _ => continue,
        };
        if let Some(folder) = Path::new(&path)
            .canonicalize()
            .ok()
            .filter(|p| p.is_file())
            .and_then(|p| p.parent().map(Path::to_path_buf))
        {
            roots.push(folder);
        }
    }
    roots.sort();
    roots.dedup();
    roots
}

/// The environment variables the `api_key_env` of `policies` name (`openpi:…,api_key_env=VAR`):
/// a local run's workers may send them, since the user's command line is the operator's. A
/// worker sends no other (`assay worker --policy-key-env`).
pub fn policy_key_envs(policies: &[String]) -> Vec<String> {
    use assay_model::policy::PolicySpec;
    let mut vars: Vec<String> = policies
        .iter()
        .filter_map(|name| match PolicySpec::parse(name) {
            Ok(PolicySpec::OpenPi { api_key_env, .. }) => api_key_env,
            _ => None,
        })
        .collect();
    vars.sort();
    vars.dedup();
    vars
}

/// As strings, for a batch request.
pub fn root_strings(roots: &[PathBuf]) -> Vec<String> {
    roots.iter().map(|r| r.display().to_string()).collect()
}

fn walk(p: &Path, root: &Path, out: &mut Vec<PathBuf>) -> std::io::Result<()> {
    let meta = std::fs::symlink_metadata(p)?;
    if meta.file_type().is_symlink() {
        let target = p.canonicalize()?;
        if !target.starts_with(root) {
            return Err(std::io::Error::new(
                std::io::ErrorKind::PermissionDenied,
                format!(
                    "{} links to {}, outside the task folder {}: refusing to follow it",
                    p.display(),
                    target.display(),
                    root.display()
                ),
            ));
        }
    }
    if p.is_dir() {
        if crate::outdir::is_output_folder(p) {
            return Ok(());
        }
        for entry in std::fs::read_dir(p)? {
            walk(&entry?.path(), root, out)?;
        }
    } else if p.is_file() {
        if assay_spec::spec::Format::from_path(&p.display().to_string()).is_some() {
            out.push(p.to_path_buf());
        }
    } else {
        return Err(std::io::Error::new(
            std::io::ErrorKind::NotFound,
            "no such file or folder",
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const TASK: &str = "id: t\n";

    fn origins(docs: &[TaskDocument]) -> Vec<String> {
        docs.iter().map(|d| d.origin.clone()).collect()
    }

    /// A local run's workers may send the key variables its own openpi policies name, each
    /// once; other policies and names that do not parse name none.
    #[test]
    fn policy_key_envs_are_those_the_run_s_openpi_policies_name() {
        let policies = [
            "openpi:url=ws://127.0.0.1:8000,api_key_env=PI_KEY".to_owned(),
            "openpi:url=ws://127.0.0.1:8001,api_key_env=PI_KEY".to_owned(),
            "openpi:url=ws://127.0.0.1:8002,api_key_env=OTHER_KEY".to_owned(),
            "openpi:url=ws://127.0.0.1:8003".to_owned(),
            "remote:url=http://127.0.0.1:9000".to_owned(),
            "oracle".to_owned(),
            "not a policy".to_owned(),
        ];
        assert_eq!(policy_key_envs(&policies), vec!["OTHER_KEY", "PI_KEY"]);
    }

    /// The folders of model files the user's own policy names give are added to the workers'
    /// roots; artifact keys, servers and names that do not parse add nothing.
    #[test]
    fn worker_roots_add_the_folders_of_named_model_files() {
        let dir = tempfile::tempdir().unwrap();
        let (models, checkpoints, tasks) = (
            dir.path().join("models"),
            dir.path().join("ckpt"),
            dir.path().join("tasks"),
        );
        for d in [&models, &checkpoints, &tasks] {
            std::fs::create_dir_all(d).unwrap();
        }
        std::fs::write(models.join("bc.pt"), "m").unwrap();
        std::fs::write(checkpoints.join("d.ckpt"), "m").unwrap();
        let canonical = |p: &Path| p.canonicalize().unwrap();
        let roots = worker_roots(
            &[canonical(&tasks)],
            &[
                format!(
                    "torchscript:path={},max_steps=480",
                    models.join("bc.pt").display()
                ),
                format!("diffusion:model={}", checkpoints.join("d.ckpt").display()),
                "diffusion:model=policies/abc.ckpt".into(),
                format!(
                    "torchscript:path={}",
                    dir.path().join("missing.pt").display()
                ),
                "remote:url=http://127.0.0.1:9".into(),
                "oracle".into(),
                "torchscript:".into(),
            ],
        );
        let mut want = vec![
            canonical(&tasks),
            canonical(&models),
            canonical(&checkpoints),
        ];
        want.sort();
        assert_eq!(roots, want);
    }

    #[test]
    fn output_folders_are_skipped() {
        let dir = tempfile::tempdir().unwrap();
        let tasks = dir.path().join("tasks");
        std::fs::create_dir_all(tasks.join("out")).unwrap();
        std::fs::write(tasks.join("a.yaml"), TASK).unwrap();
        std::fs::write(tasks.join("out/report.json"), "{}").unwrap();
        std::fs::write(tasks.join("out").join(crate::outdir::MARKER), "{}").unwrap();
        let docs = collect(std::slice::from_ref(&tasks)).unwrap();
        assert_eq!(origins(&docs), [tasks.join("a.yaml").display().to_string()]);
    }

    #[cfg(unix)]
    #[test]
    fn links_out_of_the_task_folder_are_refused_and_links_inside_followed() {
        let dir = tempfile::tempdir().unwrap();
        let outside = dir.path().join("outside");
        let tasks = dir.path().join("tasks");
        std::fs::create_dir_all(&outside).unwrap();
        std::fs::create_dir_all(tasks.join("real")).unwrap();
        std::fs::write(outside.join("secret.yaml"), TASK).unwrap();
        std::fs::write(tasks.join("real/a.yaml"), TASK).unwrap();
        std::os::unix::fs::symlink(tasks.join("real"), tasks.join("alias")).unwrap();
        let docs = collect(std::slice::from_ref(&tasks)).unwrap();
        assert_eq!(docs.len(), 2, "{:?}", origins(&docs));

        std::os::unix::fs::symlink(&outside, tasks.join("escape")).unwrap();
        let e = format!("{:#}", collect(std::slice::from_ref(&tasks)).unwrap_err());
        assert!(e.contains("outside the task folder"), "{e}");
        std::fs::remove_file(tasks.join("escape")).unwrap();
        std::os::unix::fs::symlink(outside.join("secret.yaml"), tasks.join("b.yaml")).unwrap();
        let e = format!("{:#}", collect(std::slice::from_ref(&tasks)).unwrap_err());
        assert!(e.contains("secret.yaml"), "{e}");
        // The operator may name the outside folder itself: it is then the root.
        assert_eq!(collect(std::slice::from_ref(&outside)).unwrap().len(), 1);
    }

    /// Property: on random trees of task files, folders and links that point in or out, the
    /// walk either refuses (a link out) or returns only files inside the root; and a tree with
    /// no link out is always read.
    #[cfg(unix)]
    mod walk_property {
        use super::*;
        use proptest::prelude::*;

        #[derive(Debug, Clone)]
        enum Entry {
            File,
            Dir,
            LinkOut,
            LinkOutFile,
            LinkIn,
            Marker,
        }

        fn entry() -> impl Strategy<Value = (Vec<u8>, Entry)> {
            (
                prop::collection::vec(0u8..3, 1..4),
                prop_oneof![
                    Just(Entry::File),
                    Just(Entry::Dir),
                    Just(Entry::LinkOut),
                    Just(Entry::LinkOutFile),
                    Just(Entry::LinkIn),
                    Just(Entry::Marker),
                ],
            )
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(
                std::env::var("ASSAY_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(256)
            ))]

            #[test]
            fn the_walk_reads_nothing_outside_its_root(entries in prop::collection::vec(entry(), 0..12)) {
                let dir = tempfile::tempdir().unwrap();
                let root = dir.path().join("tasks");
                let outside = dir.path().join("outside");
                std::fs::create_dir_all(&root).unwrap();
                std::fs::create_dir_all(&outside).unwrap();
                std::fs::write(outside.join("secret.yaml"), TASK).unwrap();
                std::fs::write(root.join("seed.yaml"), TASK).unwrap();
                let mut outward = false;
                for (k, (names, kind)) in entries.iter().enumerate() {
                    let mut at = root.clone();
                    for n in &names[..names.len() - 1] {
                        at.push(format!("d{n}"));
                    }
                    if std::fs::create_dir_all(&at).is_err() {
                        continue;
                    }
                    let leaf = at.join(format!("e{k}-{}", names[names.len() - 1]));
                    let made = match kind {
                        Entry::File => std::fs::write(leaf.with_extension("yaml"), TASK),
                        Entry::Dir => std::fs::create_dir_all(&leaf),
                        Entry::LinkOut => std::os::unix::fs::symlink(&outside, &leaf),
                        Entry::LinkOutFile => std::os::unix::fs::symlink(
                            outside.join("secret.yaml"),
                            leaf.with_extension("yaml"),
                        ),
                        Entry::LinkIn => std::os::unix::fs::symlink(root.join("seed.yaml"), leaf.with_extension("yaml")),
                        Entry::Marker => std::fs::write(at.join(crate::outdir::MARKER), "{}"),
                    };
                    if made.is_ok() && matches!(kind, Entry::LinkOut | Entry::LinkOutFile) {
                        outward = true;
                    }
                }
                let root_c = root.canonicalize().unwrap();
                match collect(std::slice::from_ref(&root)) {
                    Ok(docs) => {
                        for d in &docs {
                            let c = Path::new(&d.origin).canonicalize().unwrap();
                            prop_assert!(c.starts_with(&root_c), "{} -> {}", d.origin, c.display());
                        }
                    }
                    Err(e) => {
                        let e = format!("{e:#}");
                        prop_assert!(
                            outward || e.contains("no task files"),
                            "a tree without a link out was refused: {e}"
                        );
                    }
                }
            }
        }
    }
}
