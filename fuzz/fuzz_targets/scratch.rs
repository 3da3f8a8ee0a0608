//! The one file per process a target rewrites for every input: the readers take a path, not bytes.

use std::path::PathBuf;
use std::sync::OnceLock;

/// `NAME` in a folder of this process's own (the first call's name is kept).
pub fn file(name: &str) -> &'static PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("gsid-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    })
}
