//! A GenSim library written as GenSim's pipeline lays one out, for tests that import task code of
//! their own beside or instead of the real corpus (`../shared/corpora/gensim-library`).

use std::path::Path;

/// One task of a library.
pub struct Task<'a> {
    /// Its key in `generated_tasks.json` and its `task-name`; the code goes to
    /// `generated_tasks/<name, '-' as '_'>.py`.
    pub name: &'a str,
    pub description: &'a str,
    /// What it says it uses (`assets-used`), relative to the asset root.
    pub assets: &'a [&'a str],
    pub code: &'a str,
}

/// Writes `tasks` under `root`: `generated_tasks.json` and each task's code.
pub fn write_library(root: &Path, tasks: &[Task<'_>]) {
    std::fs::create_dir_all(root.join("generated_tasks")).unwrap();
    let mut lib = serde_json::Map::new();
    for t in tasks {
        lib.insert(
            t.name.to_owned(),
            serde_json::json!({
                "task-name": t.name,
                "task-description": t.description,
                "assets-used": t.assets,
            }),
        );
        let file = format!("{}.py", t.name.replace('-', "_"));
        std::fs::write(root.join("generated_tasks").join(file), t.code).unwrap();
    }
    std::fs::write(
        root.join("generated_tasks.json"),
        serde_json::to_string_pretty(&lib).unwrap(),
    )
    .unwrap();
}
