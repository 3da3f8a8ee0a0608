//! Output files and folders: reserved before the work, committed whole or not at all.
//!
//! A regular file is written to a temporary file beside it and renamed into place, so a failed or
//! interrupted run never leaves half an image. A device or FIFO (`-o /dev/null`, a pipe) is written
//! in place: renaming over it would replace the device node with a file. `-` is standard output.
//! Temporary files and folders are listed while pending, so a SIGINT or SIGTERM handler can remove
//! them ([`remove_pending_outputs`]).

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use super::compression::Compression;
use super::exr_file::{self, Frame};
use super::stale;
use crate::error::{Error, Result};
use crate::image::Image;

/// The output path that means standard output.
pub const STDOUT: &str = "-";

/// Temporary files and folders of outputs not yet committed.
static PENDING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn pending() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    // A panic elsewhere cannot leave the list half-changed: pushes and removes are single steps.
    PENDING.lock().unwrap_or_else(|e| e.into_inner())
}

/// A path on the pending list while this lives.
struct Registered(PathBuf);

impl Registered {
    fn new(path: &Path) -> Self {
        pending().push(path.to_path_buf());
        Registered(path.to_path_buf())
    }
}

impl Drop for Registered {
    fn drop(&mut self) {
        let mut list = pending();
        if let Some(i) = list.iter().position(|p| *p == self.0) {
            list.swap_remove(i);
        }
    }
}

/// Folders a run created for its outputs and has not finished filling.
static CREATED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn created() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    CREATED.lock().unwrap_or_else(|e| e.into_inner())
}

/// Removes every temporary file and folder of an output not yet committed, then every folder the
/// run created for its outputs that is empty again (for a signal handler, which then exits). Holds
/// the lists' locks, so no new output starts meanwhile.
pub fn remove_pending_outputs() {
    let list = pending();
    for path in list.iter() {
        let _ = if path.is_dir() {
            std::fs::remove_dir_all(path)
        } else {
            std::fs::remove_file(path)
        };
    }
    let folders = created();
    for path in folders.iter().rev() {
        let _ = std::fs::remove_dir(path);
    }
    std::mem::forget(list);
    std::mem::forget(folders);
}

/// An output folder (`sweep --out`) created by this run if it was missing. Until [`NewFolder::keep`]
/// it is removed again, if empty, when dropped (a failed run) or on SIGINT/SIGTERM, so a stopped run
/// leaves no empty folder behind; a folder that was already there is never removed.
pub struct NewFolder {
    made: Option<PathBuf>,
}

impl NewFolder {
    pub fn create(path: &Path) -> Result<Self> {
        if path.exists() {
            if !path.is_dir() {
                return Err(Error::output(path, "is not a folder"));
            }
            return Ok(NewFolder { made: None });
        }
        std::fs::create_dir_all(path).map_err(|e| Error::output(path, e))?;
        created().push(path.to_path_buf());
        Ok(NewFolder {
            made: Some(path.to_path_buf()),
        })
    }

    /// The run filled the folder: it stays.
    pub fn keep(mut self) {
        self.forget();
    }

    fn forget(&mut self) {
        if let Some(path) = self.made.take() {
            let mut list = created();
            if let Some(i) = list.iter().position(|p| *p == path) {
                list.remove(i);
            }
        }
    }
}

impl Drop for NewFolder {
    fn drop(&mut self) {
        if let Some(path) = self.made.clone() {
            let _ = std::fs::remove_dir(&path);
        }
        self.forget();
    }
}

/// Writes an EXR (float32, zip-compressed): RGB for 3 channels, `Y` for one.
///
/// The data goes to a temporary file next to `path`, which is renamed over `path` only once complete.
pub fn write_exr(path: &Path, image: &Image) -> Result<()> {
    let pending = PendingOutput::create(path)?;
    pending.write_exr(image, Compression::Zip)
}

/// The folder an output path lies in (`.` for a bare file name).
fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Folders an output's path needed and this run created: removed again (innermost first, each
/// only if empty) when dropped before [`MadeFolders::keep`], or by the signal handler.
struct MadeFolders(Vec<PathBuf>);

impl MadeFolders {
    /// Creates the folders missing on the way to `dir`, each registered as it is made.
    fn create(dir: &Path, path: &Path) -> Result<Self> {
        let missing: Vec<PathBuf> = dir
            .ancestors()
            .filter(|d| !d.as_os_str().is_empty())
            .take_while(|d| std::fs::symlink_metadata(d).is_err())
            .map(Path::to_path_buf)
            .collect();
        let mut made = MadeFolders(Vec::new());
        for d in missing.into_iter().rev() {
            match std::fs::create_dir(&d) {
                Ok(()) => {
                    created().push(d.clone());
                    made.0.push(d);
                }
                // Another process (a farm's other task) made it meanwhile: it is not ours to remove.
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && d.is_dir() => {}
                Err(e) => {
                    return Err(Error::output(
                        path,
                        format!("cannot create folder {}: {e}", d.display()),
                    ))
                }
            }
        }
        Ok(made)
    }

    /// The output is in place: its folders stay.
    fn keep(mut self) {
        self.forget();
    }

    fn forget(&mut self) {
        let mut list = created();
        for d in self.0.drain(..) {
            if let Some(i) = list.iter().position(|p| *p == d) {
                list.remove(i);
            }
        }
    }
}

impl Drop for MadeFolders {
    fn drop(&mut self) {
        for d in self.0.iter().rev() {
            let _ = std::fs::remove_dir(d);
        }
        self.forget();
    }
}

/// Removes what dead runs left in the folder `path` will be in (`stale`), once a run and folder:
/// also when no output is written there (every frame of a requeued chunk skipped).
pub fn remove_stale_beside(path: &Path) {
    let dir = parent_dir(path);
    if path.as_os_str() != STDOUT && dir.is_dir() {
        stale::sweep(&dir);
    }
}

/// A temporary file or folder (`make`) named `.gsid-HOST-PID-*.tmp` in the folder `path` will be
/// in, made (with the folders above it) if missing; what dead runs left there is removed first
/// (`stale`).
fn temp_beside<T>(
    path: &Path,
    make: impl FnOnce(&tempfile::Builder, &Path) -> std::io::Result<T>,
) -> Result<(T, MadeFolders)> {
    let dir = parent_dir(path);
    let made = MadeFolders::create(&dir, path)?;
    if !dir.is_dir() {
        return Err(Error::output(
            path,
            format!("{} is not a folder", dir.display()),
        ));
    }
    stale::sweep(&dir);
    let made_here = make(
        tempfile::Builder::new()
            .prefix(&stale::prefix())
            .suffix(".tmp"),
        &dir,
    )
    .map_err(|e| Error::output(path, e))?;
    Ok((made_here, made))
}

/// Where a reserved output's bytes go.
enum Target {
    /// A temporary file beside the output, renamed over it once complete.
    Temp(tempfile::NamedTempFile, Registered),
    /// A device or FIFO, written in place.
    InPlace(File),
    Stdout,
}

/// An output file reserved before the work starts: it proves the path is writable early, and
/// commits atomically or vanishes if dropped (see the module doc for devices and `-`).
pub struct PendingOutput {
    path: PathBuf,
    target: Target,
    /// Folders made for it, removed if it is never committed.
    folders: Option<MadeFolders>,
}

impl PendingOutput {
    pub fn create(path: &Path) -> Result<Self> {
        if path.as_os_str() == STDOUT {
            return Ok(PendingOutput {
                path: path.to_path_buf(),
                target: Target::Stdout,
                folders: None,
            });
        }
        match std::fs::metadata(path) {
            Ok(m) if m.is_dir() => return Err(Error::output(path, "is a directory")),
            Ok(m) if !m.is_file() => {
                let file = OpenOptions::new()
                    .write(true)
                    .open(path)
                    .map_err(|e| Error::output(path, e))?;
                return Ok(PendingOutput {
                    path: path.to_path_buf(),
                    target: Target::InPlace(file),
                    folders: None,
                });
            }
            _ => {}
        }
        let (tmp, folders) = temp_beside(path, |b, dir| b.tempfile_in(dir))?;
        let listed = Registered::new(tmp.path());
        Ok(PendingOutput {
            path: path.to_path_buf(),
            target: Target::Temp(tmp, listed),
            folders: Some(folders),
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes `image` as a plain float EXR and commits it.
    pub fn write_exr(self, image: &Image, compression: Compression) -> Result<()> {
        self.write_exr_framed(image, &Frame::default(), compression, false)
    }

    /// Writes `image` as EXR with what `frame` keeps of the input (windows, attributes, alpha,
    /// layers read), its own channels f16 if `half`, and commits it.
    pub fn write_exr_framed(
        self,
        image: &Image,
        frame: &Frame,
        compression: Compression,
        half: bool,
    ) -> Result<()> {
        let c = image.channels();
        if ![1, 3, 4].contains(&c) {
            return Err(Error::output(
                &self.path,
                format!("cannot write a {c}-channel image as EXR"),
            ));
        }
        let encoding = exr_file::Encoding {
            compression: compression.exr(),
            half,
        };
        let path = self.path.clone();
        let write_err = |e: &dyn std::fmt::Display| Error::write(&path, e);
        if let Target::Temp(tmp, _) = &self.target {
            let file = tmp.as_file().try_clone().map_err(|e| write_err(&e))?;
            // Large writes: a 1 MP image is 12 MB, which 8 KiB buffers would send in 1500 calls.
            let mut writer = BufWriter::with_capacity(1 << 20, file);
            exr_file::write(&mut writer, image, frame, encoding).map_err(|e| write_err(&e))?;
            writer.flush().map_err(|e| write_err(&e))?;
            drop(writer);
            return self.commit();
        }
        // Devices, pipes and stdout cannot seek back to the offset table: build the file in memory.
        let mut bytes = std::io::Cursor::new(Vec::new());
        exr_file::write(&mut bytes, image, frame, encoding).map_err(|e| write_err(&e))?;
        self.write_bytes(bytes.get_ref())
    }

    /// Writes arbitrary bytes (CSV, JSON, PNG) and commits them.
    pub fn write_bytes(mut self, bytes: &[u8]) -> Result<()> {
        let written = match &mut self.target {
            Target::Temp(tmp, _) => tmp.as_file().write_all(bytes),
            Target::InPlace(file) => file.write_all(bytes),
            Target::Stdout => {
                let mut out = std::io::stdout().lock();
                out.write_all(bytes).and_then(|()| out.flush())
            }
        };
        written.map_err(|e| match (&self.target, e.kind()) {
            // An image the reader did not take whole is lost: a failure, not a quiet end (a
            // listing piped into `head` is another matter: see the CLI's `stdout`).
            (Target::Stdout, std::io::ErrorKind::BrokenPipe) => Error::write(
                "standard output",
                "closed by its reader before the whole image was written",
            ),
            _ => Error::write(&self.path, e),
        })?;
        self.commit()
    }

    /// Renames a temporary file into place; devices and stdout are already written.
    fn commit(self) -> Result<()> {
        match self.target {
            Target::Temp(tmp, _listed) => commit(tmp, &self.path)?,
            Target::InPlace(_) | Target::Stdout => {}
        }
        if let Some(folders) = self.folders {
            folders.keep();
        }
        Ok(())
    }
}

/// Gives the temporary file the mode a new file would have (or the replaced file's), then
/// renames it over `path`.
fn commit(tmp: tempfile::NamedTempFile, path: &Path) -> Result<()> {
    set_mode_for(tmp.path(), path).map_err(|e| Error::write(path, e))?;
    tmp.persist(path)
        .map(drop)
        .map_err(|e| Error::write(path, e.error))
}

/// The temporary file is created 0600; the output gets the mode of the file it replaces, or
/// 0666 less the process umask, as any program's new file would.
#[cfg(unix)]
fn set_mode_for(tmp: &Path, path: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    let mode = match std::fs::metadata(path) {
        Ok(m) if m.is_file() => m.permissions().mode() & 0o7777,
        _ => 0o666 & !umask(),
    };
    std::fs::set_permissions(tmp, std::fs::Permissions::from_mode(mode))
}

#[cfg(not(unix))]
fn set_mode_for(_tmp: &Path, _path: &Path) -> std::io::Result<()> {
    Ok(())
}

/// The process umask. Reading it means setting it, so it is read once and put straight back
/// (while another thread creates a file in that instant, that file gets 0077 more, never less).
#[cfg(unix)]
fn umask() -> u32 {
    static UMASK: std::sync::OnceLock<u32> = std::sync::OnceLock::new();
    *UMASK.get_or_init(|| {
        // SAFETY: umask only swaps the process's file-creation mask; it cannot fail.
        unsafe {
            let old = libc::umask(0o077);
            libc::umask(old);
            old as u32
        }
    })
}

/// An output folder built under a temporary name beside it and renamed into place once complete
/// (`gsid render`), so an interrupted or failed run never leaves a half-written render set.
pub struct PendingFolder {
    path: PathBuf,
    tmp: Option<tempfile::TempDir>,
    _listed: Registered,
    /// Folders made for it, removed if it is never committed.
    folders: Option<MadeFolders>,
}

impl PendingFolder {
    /// Reserves `path` for a folder that will hold the file `marker`, which marks what this kind
    /// of output wrote. A folder already at `path` is replaced only when it is empty or holds
    /// `marker` (an earlier output of the same kind): any other folder is the user's, and never
    /// deleted. The working folder, or one holding it, cannot be renamed away.
    pub fn create(path: &Path, marker: &str) -> Result<Self> {
        if path.exists() && !path.is_dir() {
            return Err(Error::output(path, "exists and is not a folder"));
        }
        if path.is_dir() {
            let cwd = std::env::current_dir()
                .ok()
                .and_then(|d| d.canonicalize().ok());
            let full = path.canonicalize().map_err(|e| Error::output(path, e))?;
            if cwd.is_some_and(|cwd| cwd.starts_with(&full)) {
                return Err(Error::output(
                    path,
                    "is the working folder or holds it; it cannot be replaced (write elsewhere)",
                ));
            }
            let mut entries = std::fs::read_dir(path).map_err(|e| Error::output(path, e))?;
            if entries.next().is_some() && !path.join(marker).is_file() {
                return Err(Error::output(
                    path,
                    format!(
                        "exists and is not a folder gsid wrote (no {marker} in it); refusing to replace it: remove it or choose another path"
                    ),
                ));
            }
        }
        let (tmp, folders) = temp_beside(path, |b, dir| b.tempdir_in(dir))?;
        let listed = Registered::new(tmp.path());
        std::fs::write(
            tmp.path().join(marker),
            "This folder was written by gsid; gsid may replace it.\n",
        )
        .map_err(|e| Error::write(path, e))?;
        Ok(PendingFolder {
            path: path.to_path_buf(),
            tmp: Some(tmp),
            _listed: listed,
            folders: Some(folders),
        })
    }

    /// Where the folder's contents are written until [`PendingFolder::commit`].
    pub fn staging(&self) -> &Path {
        self.tmp.as_ref().expect("present until commit").path()
    }

    /// Renames the finished folder into place. A folder already there is moved aside first and
    /// removed after, so the path holds the old set or the new one, never a mix.
    pub fn commit(mut self) -> Result<()> {
        let tmp = self.tmp.take().expect("present until commit");
        set_folder_mode(tmp.path()).map_err(|e| Error::write(&self.path, e))?;
        let staged = tmp.keep();
        let old = if self.path.exists() {
            let aside = tempfile::Builder::new()
                .prefix(&format!("{}old", stale::prefix()))
                .suffix(".tmp")
                .tempdir_in(parent_dir(&self.path))
                .map_err(|e| Error::write(&self.path, e))?
                .keep();
            std::fs::rename(&self.path, &aside).map_err(|e| Error::write(&self.path, e))?;
            Some(aside)
        } else {
            None
        };
        let renamed = std::fs::rename(&staged, &self.path);
        if let Err(e) = renamed {
            if let Some(aside) = &old {
                let _ = std::fs::rename(aside, &self.path);
            }
            let _ = std::fs::remove_dir_all(&staged);
            return Err(Error::write(&self.path, e));
        }
        if let Some(aside) = old {
            let _ = std::fs::remove_dir_all(aside);
        }
        if let Some(folders) = self.folders.take() {
            folders.keep();
        }
        Ok(())
    }
}

/// A temporary folder is created 0700; the render set gets 0777 less the umask, as `mkdir` would.
#[cfg(unix)]
fn set_folder_mode(dir: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o777 & !umask()))
}

#[cfg(not(unix))]
fn set_folder_mode(_dir: &Path) -> std::io::Result<()> {
    Ok(())
}
