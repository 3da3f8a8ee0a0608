//! Temporary files of gsid runs that died without cleaning up (`kill -9`, a crash, a power cut):
//! every temporary output is named `.gsid-HOST-PID-RANDOM.tmp`, and a later run writing into the
//! same folder removes those of its own host whose process no longer exists. A live run's files,
//! another host's (a shared farm folder) and anything not named so are never touched.
//!
//! Versions before that named them `.gsid-RANDOM.tmp` (and `.gsid-old-RANDOM` for a render set
//! moved aside), with no host or process to ask. Those are removed when they are exactly so named
//! (six letters or digits), last modified before this run began, and open in no process of this
//! machine (a live older gsid holds its temporary file open until it renames it).

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};
use std::time::SystemTime;

/// The name prefix of this process's temporary outputs: `.gsid-HOST-PID-`.
pub(super) fn prefix() -> String {
    format!(".gsid-{}-{}-", host(), std::process::id())
}

/// This machine's name, with anything but letters, digits, `.` and `_` replaced, so that names
/// parse back unambiguously; asked once a run.
fn host() -> &'static str {
    static HOST: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    HOST.get_or_init(machine_name)
}

fn machine_name() -> String {
    let mut buf = [0u8; 256];
    // SAFETY: gethostname writes at most `buf.len()` bytes into the buffer it is given.
    let ok = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) } == 0;
    let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    let name = if ok { &buf[..end] } else { &b"unknown"[..] };
    String::from_utf8_lossy(name)
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '.' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// The host and process of a temporary output's name, if it is one of gsid's.
fn owner(name: &str) -> Option<(&str, u32)> {
    let inner = name.strip_prefix(".gsid-")?.strip_suffix(".tmp")?;
    let mut parts = inner.rsplitn(3, '-');
    let _random = parts.next()?;
    let pid = parts.next()?.parse().ok()?;
    Some((parts.next()?, pid))
}

/// Whether `name` is a temporary output of a gsid before names carried a host and a process:
/// `.gsid-XXXXXX.tmp` or `.gsid-old-XXXXXX`, six letters or digits.
fn legacy(name: &str) -> bool {
    let random = name
        .strip_prefix(".gsid-")
        .and_then(|r| r.strip_suffix(".tmp"))
        .or_else(|| name.strip_prefix(".gsid-old-"));
    random.is_some_and(|r| r.len() == 6 && r.bytes().all(|b| b.is_ascii_alphanumeric()))
}

/// When this run first looked for stale files: a legacy file modified later is not stale.
fn run_start() -> SystemTime {
    static START: OnceLock<SystemTime> = OnceLock::new();
    *START.get_or_init(SystemTime::now)
}

/// Whether any process of this machine has `path` open (its `/proc/PID/fd` links). Without
/// `/proc` this cannot be told, and the file is taken as open.
fn open_anywhere(path: &Path) -> bool {
    let Ok(procs) = std::fs::read_dir("/proc") else {
        return true;
    };
    let Ok(path) = path.canonicalize() else {
        return true;
    };
    procs.flatten().any(|p| {
        let Ok(fds) = std::fs::read_dir(p.path().join("fd")) else {
            return false;
        };
        fds.flatten()
            .any(|fd| std::fs::read_link(fd.path()).is_ok_and(|target| target == path))
    })
}

/// Whether the entry named `name` is a legacy temporary output that no run can still be writing.
fn stale_legacy(name: &str, entry: &std::fs::DirEntry) -> bool {
    let modified = entry.metadata().and_then(|m| m.modified());
    legacy(name) && modified.is_ok_and(|t| t < run_start()) && !open_anywhere(&entry.path())
}

/// Whether process `pid` exists on this machine (or cannot be told: then it is taken as alive).
fn alive(pid: u32) -> bool {
    let Ok(pid) = i32::try_from(pid) else {
        return true;
    };
    // SAFETY: signal 0 only asks whether the process exists; nothing is sent.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// Folders already looked at in this run.
static SWEPT: Mutex<Option<HashSet<PathBuf>>> = Mutex::new(None);

/// Removes, once per run and folder, the temporary outputs in `dir` left by dead gsid processes of
/// this host. Returns how many were removed. Errors (a file already gone) are ignored.
pub(super) fn sweep(dir: &Path) -> usize {
    {
        let mut swept = SWEPT.lock().unwrap_or_else(|e| e.into_inner());
        if !swept
            .get_or_insert_with(HashSet::new)
            .insert(dir.to_path_buf())
        {
            return 0;
        }
    }
    run_start();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let (here, me) = (host(), std::process::id());
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(name) = name.to_str() else {
            continue;
        };
        let dead = match owner(name) {
            Some((h, pid)) => h == here && pid != me && !alive(pid),
            None => stale_legacy(name, &entry),
        };
        if !dead {
            continue;
        }
        let path = entry.path();
        let gone = match entry.file_type() {
            Ok(t) if t.is_dir() => std::fs::remove_dir_all(&path),
            _ => std::fs::remove_file(&path),
        };
        removed += gone.is_ok() as usize;
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_back_to_their_host_and_process() {
        let name = format!("{}Ab3xYz.tmp", prefix());
        assert_eq!(owner(&name), Some((host(), std::process::id())));
        assert_eq!(
            owner(".gsid-farm_01.lan-42-q1w2e3.tmp"),
            Some(("farm_01.lan", 42))
        );
        for other in [
            ".gsid-Ab3xYz.tmp",
            "gsid-h-1-x.tmp",
            ".gsid-h-x-y.tmp",
            "out.exr",
        ] {
            assert_eq!(owner(other), None, "{other}");
        }
        assert!(alive(std::process::id()));
    }

    #[test]
    fn legacy_names_are_exactly_six_letters_or_digits() {
        for old in [".gsid-Ab3xYz.tmp", ".gsid-old-Q1w2E3", ".gsid-000000.tmp"] {
            assert!(legacy(old), "{old}");
        }
        for other in [
            ".gsid-Ab3xY.tmp",
            ".gsid-Ab3xYzz.tmp",
            ".gsid-Ab-xYz.tmp",
            ".gsid-render-set",
            ".gsid-old-Q1w2E3.tmp",
            "gsid-Ab3xYz.tmp",
            ".gsid-h-1-abcdef.tmp",
        ] {
            assert!(!legacy(other), "{other}");
        }
    }
}
