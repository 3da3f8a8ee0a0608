//! Temporary files of gsid runs that died without cleaning up (`kill -9`, a crash, a power cut):
//! every temporary output is named `.gsid-HOST-PID-RANDOM.tmp`, and a later run writing into the
//! same folder removes those of its own host whose process no longer exists. A live run's files,
//! another host's (a shared farm folder) and anything not named so are never touched.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

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
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let (here, me) = (host(), std::process::id());
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some((h, pid)) = name.to_str().and_then(owner) else {
            continue;
        };
        if h != here || pid == me || alive(pid) {
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
}
