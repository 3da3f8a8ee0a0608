//! The project's written files, for the house-rule tests (`tests/layout.rs`, `tests/docs.rs`).

use std::fs;
use std::path::{Path, PathBuf};

/// Every file under `dir` with one of the extensions `exts`, sorted; build output (`target`),
/// fixtures, test data, virtual environments and hidden folders left out.
pub fn written_files(dir: &Path, exts: &[&str], out: &mut Vec<PathBuf>) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<_> = entries.map(|e| e.unwrap().path()).collect();
    entries.sort();
    for path in entries {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if path.is_dir() {
            let skipped = ["target", "fixtures", "data", "venv"].contains(&name.as_str());
            if !skipped && !name.starts_with('.') {
                written_files(&path, exts, out);
            }
        } else if path
            .extension()
            .is_some_and(|e| exts.contains(&e.to_string_lossy().as_ref()))
        {
            out.push(path);
        }
    }
}
