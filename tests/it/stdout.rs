//! Standard output as scripts treat it: a reader that closes the pipe early (`gsid pipelines |
//! head -1`) ends the run quietly with exit 0; a stdout that cannot be written (a full device)
//! is one error line and exit 1; never a panic.

use std::os::fd::{FromRawFd, OwnedFd};
use std::path::Path;
use std::process::{Command, Output, Stdio};

use crate::common::*;

/// Runs gsid with `args` and a stdout whose reader is already closed, so the first write fails.
fn into_closed_pipe(args: &[&str]) -> Output {
    gsid_command()
        .args(args)
        .stdout(Stdio::from(closed_pipe()))
        .stderr(Stdio::piped())
        .output()
        .expect("run gsid")
}

/// Every subcommand that writes to stdout, on small inputs in `dir`.
fn commands(dir: &Path) -> Vec<Vec<String>> {
    let set = dir.join("set");
    if !set.exists() {
        copy_fixture(1, dir);
        std::fs::rename(dir.join("spp1"), &set).unwrap();
    }
    let set = set.to_str().unwrap().to_string();
    let reference = dir.join("reference.exr").to_str().unwrap().to_string();
    let sweep_out = dir.join("sweep").to_str().unwrap().to_string();
    let strings = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    vec![
        strings(&["pipelines"]),
        strings(&["eval", &reference, "--reference", &reference]),
        strings(&["eval", &reference, "--reference", &reference, "--json"]),
        strings(&["ablate", &set, "--pipeline", "gsid", "-q"]),
        strings(&[
            "sweep",
            &set,
            "--pipeline",
            "gsid",
            "--vary",
            "gsid.walks=1,2",
            "--repeat",
            "1",
            "--out",
            &sweep_out,
            "-q",
        ]),
        strings(&["denoise", &set, "--pipeline", "gsid", "-o", "-", "-q"]),
    ]
}

fn args(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

/// A listing or a table whose reader went away ends quietly (`gsid pipelines | head -1`); an image
/// written to stdout (`-o -`) that the reader did not take whole is lost, so that is exit 1 with one
/// line (it exited 0).
#[test]
fn a_closed_pipe_ends_every_command_quietly_but_a_lost_image_fails() {
    let tmp = tempfile::tempdir().unwrap();
    for cmd in commands(tmp.path()) {
        let run = into_closed_pipe(&args(&cmd));
        let err = stderr(&run);
        assert!(!err.contains("panicked"), "{cmd:?}: {err}");
        if cmd.iter().any(|a| a == "-") {
            assert_eq!(run.status.code(), Some(1), "{cmd:?}: {err}");
            assert_eq!(err.lines().count(), 1, "{cmd:?}: {err}");
            assert!(err.contains("standard output"), "{cmd:?}: {err}");
        } else {
            assert_eq!(run.status.code(), Some(0), "{cmd:?}: {err}");
            assert!(err.trim().is_empty(), "{cmd:?} printed: {err}");
        }
    }
}

#[test]
fn a_full_stdout_is_one_error_line_and_exit_1() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(full) = full_device(tmp.path()) else {
        return;
    };
    for cmd in commands(tmp.path()) {
        let out = std::fs::OpenOptions::new().write(true).open(&full).unwrap();
        let run = Command::new(env!("CARGO_BIN_EXE_gsid"))
            .args(args(&cmd))
            .stdout(Stdio::from(out))
            .output()
            .unwrap();
        let err = stderr(&run);
        assert_eq!(run.status.code(), Some(1), "{cmd:?}: {err}");
        assert!(!err.contains("panicked"), "{cmd:?}: {err}");
        let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "{cmd:?}: {err}");
    }
}

/// A full device of the test's own (`mknod c 1 7`; never the machine's /dev/full), or `None`
/// where that needs root and we are not.
fn full_device(dir: &Path) -> Option<std::path::PathBuf> {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!("skipped: mknod needs root");
        return None;
    }
    let full = dir.join("full");
    let made = Command::new("mknod")
        .arg(&full)
        .args(["c", "1", "7"])
        .status()
        .unwrap();
    assert!(made.success(), "mknod failed");
    Some(full)
}

/// The write end of a pipe whose reader is already gone.
fn closed_pipe() -> OwnedFd {
    let mut fds = [0; 2];
    // Close-on-exec, so no child another test spawns meanwhile inherits the read end and keeps
    // the pipe open.
    // SAFETY: pipe2 writes two new descriptors into the array it is given.
    assert_eq!(unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) }, 0);
    // SAFETY: both descriptors were just created by pipe and are owned here alone.
    let (read, write) = unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
    drop(read);
    write
}

/// Runs gsid with `args`, its stderr full (`Some(device)`) or a closed pipe (`None`).
fn with_stderr(args: &[&str], full: Option<&Path>) -> Output {
    let err = match full {
        Some(device) => Stdio::from(
            std::fs::OpenOptions::new()
                .write(true)
                .open(device)
                .unwrap(),
        ),
        None => Stdio::from(closed_pipe()),
    };
    gsid_command()
        .args(args)
        .stdout(Stdio::null())
        .stderr(err)
        .output()
        .unwrap()
}

/// Notes, progress and errors are written to stderr; when it is full or its reader went away the
/// run goes on (it panicked: exit 101, and a sequence stopped after its first frame).
#[test]
fn a_full_or_closed_stderr_never_stops_a_run() {
    let tmp = tempfile::tempdir().unwrap();
    let full = full_device(tmp.path());
    let shot = tmp.path().join("shot");
    std::fs::create_dir(&shot).unwrap();
    for n in 1..=3 {
        let color = format!("{FIXTURE}/spp4/color.exr");
        std::fs::copy(color, shot.join(format!("b.{n:04}.exr"))).unwrap();
    }
    let set = format!("{FIXTURE}/spp4");
    for (k, device) in [None, full.as_deref()].into_iter().enumerate() {
        if k == 1 && device.is_none() {
            continue;
        }
        let out = tmp.path().join(format!("out{k}.exr"));
        let o = out.to_str().unwrap();
        let run = with_stderr(&["denoise", &set, "-o", o, "-p", "fast"], device);
        assert_eq!(run.status.code(), Some(0), "stderr {k}");
        assert!(out.is_file());
        let missing = tmp.path().join("missing");
        let run = with_stderr(&["denoise", missing.to_str().unwrap(), "-o", o], device);
        assert_eq!(run.status.code(), Some(2), "stderr {k}, error path");
        let pattern = shot.join("b.####.exr");
        let outs = tmp.path().join(format!("seq{k}"));
        let out_pattern = outs.join("d.####.exr");
        std::fs::create_dir(&outs).unwrap();
        let run = with_stderr(
            &[
                "denoise",
                pattern.to_str().unwrap(),
                "-o",
                out_pattern.to_str().unwrap(),
                "-p",
                "fast",
            ],
            device,
        );
        assert_eq!(run.status.code(), Some(0), "stderr {k}, sequence");
        assert_eq!(
            files_in(&outs).len(),
            3,
            "stderr {k}: {:?}",
            files_in(&outs)
        );
    }
}

/// `--help` and `--version` that cannot be written are a failure (they exited 0); a reader that
/// went away is not.
#[test]
fn help_and_version_into_a_full_stdout_exit_1() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(full) = full_device(tmp.path()) else {
        return;
    };
    for args in [&["--help"][..], &["--version"], &["denoise", "--help"]] {
        let out = std::fs::OpenOptions::new().write(true).open(&full).unwrap();
        let run = gsid_command()
            .args(args)
            .stdout(Stdio::from(out))
            .output()
            .unwrap();
        assert_eq!(run.status.code(), Some(1), "{args:?}: {}", stderr(&run));
        assert!(!stderr(&run).contains("panicked"), "{args:?}");
        let run = into_closed_pipe(args);
        assert_eq!(run.status.code(), Some(0), "{args:?}: {}", stderr(&run));
    }
}
