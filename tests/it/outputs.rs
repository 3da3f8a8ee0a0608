//! Where outputs go: devices and FIFOs written in place (never replaced by a file), `-o -` to
//! stdout, inputs and duplicate paths refused before any work, file modes from the umask, write
//! failures exit 1, and SIGINT/SIGTERM leave no temporary file behind.
//!
//! Device tests make their own nodes with `mknod` in a temporary folder (root only) and never touch
//! /dev/null or /dev/full: while the bug they guard against is there, such a test would replace the
//! machine's device with a regular file.

use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use crate::common::*;

/// The first four bytes of every EXR file.
const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

fn small_set(dir: &Path) -> String {
    let set = dir.join("set");
    write_set(&set, &synthetic_set(16, 12));
    set.to_str().unwrap().to_string()
}

fn is_root() -> bool {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() == 0 }
}

/// A character device node `name` in `dir` with the given major/minor numbers.
fn mknod(dir: &Path, name: &str, major: u32, minor: u32) -> std::path::PathBuf {
    let path = dir.join(name);
    let status = Command::new("mknod")
        .arg(&path)
        .args(["c", &major.to_string(), &minor.to_string()])
        .status()
        .expect("run mknod");
    assert!(status.success(), "mknod {}", path.display());
    path
}

/// A temporary folder with a small render set and a device node `name` (root only, else `None`).
fn set_and_device(
    name: &str,
    major: u32,
    minor: u32,
) -> Option<(tempfile::TempDir, String, std::path::PathBuf)> {
    if !is_root() {
        eprintln!("skipped: mknod needs root");
        return None;
    }
    let tmp = tempfile::tempdir().unwrap();
    let set = small_set(tmp.path());
    let node = mknod(tmp.path(), name, major, minor);
    Some((tmp, set, node))
}

#[test]
fn a_character_device_stays_a_device() {
    let Some((tmp, set, null)) = set_and_device("null", 1, 3) else {
        return;
    };
    let run = gsid(&["denoise", &set, "-o", null.to_str().unwrap(), "-q"]);
    assert!(run.status.success(), "{}", stderr(&run));
    let kind = std::fs::metadata(&null).unwrap().file_type();
    assert!(kind.is_char_device(), "the device node was replaced");
    assert_eq!(
        files_in(tmp.path()),
        vec!["null", "set"],
        "no temp file left"
    );
}

#[test]
fn a_write_failure_on_a_full_device_exits_1() {
    let Some((_tmp, set, full)) = set_and_device("full", 1, 7) else {
        return;
    };
    let run = gsid(&["denoise", &set, "-o", full.to_str().unwrap(), "-q"]);
    assert_eq!(run.status.code(), Some(1), "{}", stderr(&run));
    assert!(stderr(&run).contains("full"), "{}", stderr(&run));
    assert!(!stderr(&run).contains("panicked"));
    assert!(std::fs::metadata(&full)
        .unwrap()
        .file_type()
        .is_char_device());
}

#[test]
fn a_fifo_is_written_in_place() {
    let tmp = tempfile::tempdir().unwrap();
    let set = small_set(tmp.path());
    let fifo = tmp.path().join("pipe");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read(fifo).unwrap())
    };
    let run = gsid(&["denoise", &set, "-o", fifo.to_str().unwrap(), "-q"]);
    assert!(run.status.success(), "{}", stderr(&run));
    // Checked before the reader is joined: a FIFO replaced by a file would leave it blocked.
    assert!(
        std::fs::metadata(&fifo).unwrap().file_type().is_fifo(),
        "the FIFO was replaced"
    );
    let bytes = reader.join().unwrap();
    assert_eq!(bytes[..4], EXR_MAGIC);
}

#[test]
fn dash_writes_the_exr_to_stdout() {
    let tmp = tempfile::tempdir().unwrap();
    let set = small_set(tmp.path());
    let file = tmp.path().join("out.exr");
    let to_file = gsid(&["denoise", &set, "-o", file.to_str().unwrap(), "-q"]);
    assert!(to_file.status.success(), "{}", stderr(&to_file));
    let to_stdout = gsid(&["denoise", &set, "-o", "-", "-q"]);
    assert!(to_stdout.status.success(), "{}", stderr(&to_stdout));
    assert_eq!(to_stdout.stdout, std::fs::read(&file).unwrap());
    assert_eq!(to_stdout.stdout[..4], EXR_MAGIC);
}

#[test]
fn the_reference_is_refused_as_an_output() {
    let tmp = tempfile::tempdir().unwrap();
    let set = copy_fixture(4, tmp.path());
    let reference = tmp.path().join("reference.exr");
    let before = std::fs::read(&reference).unwrap();
    let run = gsid(&[
        "denoise",
        set.to_str().unwrap(),
        "-o",
        reference.to_str().unwrap(),
    ]);
    assert_bad_input(&run, "reference");
    assert_eq!(before, std::fs::read(&reference).unwrap());
}

#[test]
fn two_outputs_to_one_path_are_refused_before_any_work() {
    let tmp = tempfile::tempdir().unwrap();
    let set = small_set(tmp.path());
    let out = tmp.path().join("out.exr");
    let out = out.to_str().unwrap();
    let run = gsid(&[
        "denoise",
        &set,
        "-o",
        out,
        "--save-buffer",
        &format!("outlier_mask={out}"),
    ]);
    assert_bad_input(&run, "two outputs");
    let other = tmp.path().join("mask.exr");
    let other = other.to_str().unwrap();
    let saves = [format!("outlier_mask={other}"), format!("color={other}")];
    let mut args = vec!["denoise", &set, "-o", out];
    for save in &saves {
        args.extend(["--save-buffer", save]);
    }
    let run = gsid(&args);
    assert_bad_input(&run, "two outputs");
    assert_eq!(files_in(tmp.path()), vec!["set"]);
}

#[test]
fn outputs_get_the_umask_s_mode_and_keep_an_existing_file_s() {
    let tmp = tempfile::tempdir().unwrap();
    let set = small_set(tmp.path());
    let out = tmp.path().join("out.exr");
    let run = |umask: &str| {
        let script = format!("umask {umask} && exec \"$0\" denoise \"$1\" -o \"$2\" -q",);
        Command::new("sh")
            .args(["-c", &script, env!("CARGO_BIN_EXE_gsid"), &set])
            .arg(&out)
            .status()
            .unwrap()
    };
    let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert!(run("022").success());
    assert_eq!(mode(&out), 0o644);
    std::fs::set_permissions(&out, std::fs::Permissions::from_mode(0o640)).unwrap();
    assert!(run("022").success());
    assert_eq!(mode(&out), 0o640, "an existing output's mode is kept");
    std::fs::remove_file(&out).unwrap();
    assert!(run("077").success());
    assert_eq!(mode(&out), 0o600);
}

/// Starts `gsid denoise` on a 2048² set writing into a fresh folder, sends `signal` after a
/// second, and returns the temporary root, that folder and what the run gave.
fn signalled(signal: i32) -> (tempfile::TempDir, PathBuf, std::process::Output) {
    let tmp = tempfile::tempdir().unwrap();
    let set = tmp.path().join("set");
    write_set(&set, &synthetic_set(2048, 2048));
    let out_dir = tmp.path().join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let child = gsid_command()
        .args([
            "denoise",
            set.to_str().unwrap(),
            "--pipeline",
            "quality",
            "-q",
            "-o",
        ])
        .arg(out_dir.join("big.exr"))
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Signalled once the output is reserved (its temporary file exists), however loaded the machine.
    for _ in 0..1200 {
        let reserved = files_in(&out_dir).iter().any(|f| f.starts_with(".gsid-"));
        if reserved {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    // SAFETY: kill sends a signal to the child we started; it has no memory-safety preconditions.
    assert_eq!(unsafe { libc::kill(child.id() as i32, signal) }, 0);
    let done = child.wait_with_output().unwrap();
    (tmp, out_dir, done)
}

/// [`signalled`] with a signal gsid handles: the exit code, the output folder left empty, and the
/// one line of a run that ended through the library's cancel (not the signal handler's fallback,
/// which exits without a word).
fn interrupted(signal: i32, code: i32) {
    let (_tmp, out_dir, done) = signalled(signal);
    let stderr = String::from_utf8_lossy(&done.stderr);
    assert_eq!(done.status.code(), Some(code), "stderr: {stderr}");
    assert_eq!(stderr.trim_end(), "gsid: cancelled", "stderr: {stderr}");
    assert!(
        files_in(&out_dir).is_empty(),
        "left: {:?}",
        files_in(&out_dir)
    );
}

#[test]
fn sigint_leaves_no_file_and_exits_130() {
    interrupted(libc::SIGINT, 130);
}

#[test]
fn sigterm_leaves_no_file_and_exits_143() {
    interrupted(libc::SIGTERM, 143);
}

#[test]
fn render_builds_its_set_aside_and_replaces_an_old_one_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("scene.toml");
    let text = std::fs::read_to_string("fixtures/scenes/cornell.toml")
        .unwrap()
        .replace("width = 128", "width = 16")
        .replace("height = 128", "height = 12");
    std::fs::write(&scene, text).unwrap();
    let dest = tmp.path().join("set");
    let render = |spp: &str| {
        gsid(&[
            "render",
            scene.to_str().unwrap(),
            "--spp",
            spp,
            "--reference-spp",
            "4",
            "-q",
            "-o",
            dest.to_str().unwrap(),
        ])
    };
    let first = render("1,2");
    assert!(first.status.success(), "{}", stderr(&first));
    assert_eq!(
        files_in(&dest),
        vec![
            ".gsid-render-set",
            "reference.exr",
            "sample_variance.exr",
            "scene.toml",
            "spp1",
            "spp2"
        ]
    );
    let mode = std::fs::metadata(&dest).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode & 0o700, 0o700);
    let second = render("4");
    assert!(second.status.success(), "{}", stderr(&second));
    assert_eq!(
        files_in(&dest),
        vec![
            ".gsid-render-set",
            "reference.exr",
            "sample_variance.exr",
            "scene.toml",
            "spp4"
        ]
    );
    assert_eq!(
        files_in(tmp.path()),
        vec!["scene.toml", "set"],
        "no temp folder left"
    );
}

/// The name a temporary output of process `pid` on this machine has (as `io::stale` makes it).
fn temp_name(pid: u32, rest: &str) -> String {
    let host: String = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .unwrap()
        .trim()
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '.' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!(".gsid-{host}-{pid}-{rest}.tmp")
}

/// A run killed with SIGKILL cannot clean up: its temporary file stays. The next run writing into
/// that folder removes it (it stayed for good), and nothing else: not a live process's temporary
/// file, not another machine's, not a file gsid did not name.
#[test]
fn sigkill_leaves_a_temp_file_that_the_next_run_removes() {
    let (tmp, out_dir, done) = signalled(libc::SIGKILL);
    assert_eq!(done.status.code(), None, "killed");
    let left = files_in(&out_dir);
    assert_eq!(left.len(), 1, "{left:?}");
    assert!(
        left[0].starts_with(".gsid-") && left[0].ends_with(".tmp"),
        "{left:?}"
    );
    // Files that must stay: this (live) process's, another host's, ones gsid did not name, and
    // an older gsid's that is open (a live run's) or was modified after the run began.
    let keep = [
        temp_name(std::process::id(), "live00"),
        ".gsid-another_host-1-abc123.tmp".to_string(),
        ".gsid-abc12.tmp".to_string(),
        "notes.tmp".to_string(),
        ".gsid-Open00.tmp".to_string(),
        ".gsid-Later0.tmp".to_string(),
    ];
    for name in &keep {
        std::fs::write(out_dir.join(name), "x").unwrap();
    }
    let _held = std::fs::File::open(out_dir.join(".gsid-Open00.tmp")).unwrap();
    let later = std::time::SystemTime::now() + Duration::from_secs(3600);
    let file = std::fs::File::options()
        .write(true)
        .open(out_dir.join(".gsid-Later0.tmp"));
    file.unwrap().set_modified(later).unwrap();
    // An older gsid's, closed and older than the run: its file and its set moved aside go.
    std::fs::write(out_dir.join(".gsid-abc123.tmp"), "").unwrap();
    std::fs::create_dir(out_dir.join(".gsid-old-Q1w2E3")).unwrap();
    std::fs::write(out_dir.join(".gsid-old-Q1w2E3/color.exr"), "x").unwrap();
    let small = tmp.path().join("small");
    write_set(&small, &synthetic_set(8, 6));
    let run = gsid(&[
        "denoise",
        small.to_str().unwrap(),
        "-p",
        "fast",
        "-q",
        "-o",
        out_dir.join("small.exr").to_str().unwrap(),
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let mut want: Vec<String> = keep.to_vec();
    want.push("small.exr".to_string());
    want.sort();
    assert_eq!(files_in(&out_dir), want);
}

/// A process id that no longer exists: a child that has exited and been reaped.
fn dead_pid() -> u32 {
    let mut child = Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    pid
}

/// What a killed run leaves is removed by a later sequence and by a later folder-of-sets run too,
/// even when every frame is skipped (a requeued farm chunk whose frames all exist).
#[test]
fn sequences_and_folders_of_sets_remove_what_killed_runs_left() {
    let tmp = tempfile::tempdir().unwrap();
    let shot = tmp.path().join("shot");
    std::fs::create_dir_all(&shot).unwrap();
    for n in 1..=2 {
        let set = synthetic_set(8, 6);
        gsid::io::write_exr(
            &shot.join(format!("b.{n:04}.exr")),
            set.get("color").unwrap(),
        )
        .unwrap();
    }
    let out = tmp.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let sequence = |extra: &[&str]| {
        let input = shot.join("b.####.exr");
        let output = out.join("d.####.exr");
        let mut args = vec![
            "denoise",
            input.to_str().unwrap(),
            "-o",
            output.to_str().unwrap(),
        ];
        args.extend_from_slice(&["-p", "fast", "-q"]);
        args.extend_from_slice(extra);
        let run = gsid(&args);
        assert!(run.status.success(), "{}", stderr(&run));
    };
    sequence(&[]);
    let leftovers = [
        temp_name(dead_pid(), "abc123"),
        ".gsid-Zz9Yy8.tmp".to_string(),
    ];
    for name in &leftovers {
        std::fs::write(out.join(name), "").unwrap();
    }
    sequence(&["--skip-existing"]);
    assert_eq!(files_in(&out), ["d.0001.exr", "d.0002.exr"]);

    let sets = tmp.path().join("sets");
    write_set(&sets.join("a"), &synthetic_set(8, 6));
    let denoised = tmp.path().join("denoised");
    std::fs::create_dir_all(&denoised).unwrap();
    for name in &leftovers {
        std::fs::write(denoised.join(name), "").unwrap();
    }
    let run = gsid(&[
        "denoise",
        sets.to_str().unwrap(),
        "-o",
        denoised.to_str().unwrap(),
        "-p",
        "fast",
        "-q",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    assert_eq!(files_in(&denoised), ["a.exr"]);
}
