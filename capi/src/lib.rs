//! The C API of gsid: a pipeline made once (by name, pipeline file or TOML text), then frames
//! denoised from a renderer's strided float buffers into its own output buffer, with a progress
//! callback (called on the caller's thread) and a cancel flag. Errors are status codes plus a
//! one-line message ([`gsid_last_error`], per thread); no Rust panic crosses the boundary.
//!
//! The header `capi/include/gsid.h` is made from this file by cbindgen (`capi/cbindgen.toml`).

use std::cell::RefCell;
use std::ffi::{c_char, c_void, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicI32, Ordering};

use gsid::embed::watch::{run_watched, ProgressRelay};
use gsid::{
    CancelToken, DenoiseOptions, Error, Feature, ImageView, ImageViewMut, Inputs, Pipeline,
    PipelineSpec,
};

/// What a call returned.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GsidStatus {
    /// It worked.
    Ok = 0,
    /// Bad input or argument (a null pointer, a buffer of the wrong shape, an unknown pipeline, a
    /// wrong parameter): what the command line exits 2 for. The message names the culprit.
    Invalid = 1,
    /// The run was cancelled (the cancel flag, or the progress callback returned false); the
    /// output buffer is untouched.
    Cancelled = 2,
    /// A failure that is not the input's (out of memory for threads, an I/O error).
    Failed = 3,
    /// A bug in gsid (a Rust panic, caught at the boundary); the message says where.
    Internal = 4,
}

/// A float image the caller owns. `data` points at pixel (0, 0)'s first channel; a pixel's
/// channels are adjacent. Strides are in floats, not bytes, and may be negative (rows stored
/// bottom-up); 0 means packed: `pixel_stride` = `channels`, `row_stride` = `width * pixel_stride`.
/// An RGBA framebuffer read as RGB: `channels` 3, `pixel_stride` 4.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct GsidImage {
    pub data: *const f32,
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub row_stride: isize,
    pub pixel_stride: isize,
}

/// A float image the caller owns and gsid writes (see [`GsidImage`]); elements between its
/// samples (an alpha channel, row padding) are left alone.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct GsidImageMut {
    pub data: *mut f32,
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub row_stride: isize,
    pub pixel_stride: isize,
}

/// Told how far a run is (0 to 1, never decreasing) and which stage runs (`done` at the end),
/// on the thread that called [`gsid_denoise`], every few milliseconds while the run goes on.
/// Return false to cancel the run.
pub type GsidProgressFn =
    Option<unsafe extern "C" fn(user: *mut c_void, fraction: f32, stage: *const c_char) -> bool>;

/// How a run goes; start from [`gsid_options_default`].
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct GsidOptions {
    /// Seed of every random choice: the same inputs, pipeline and seed give the same bits on any
    /// number of threads.
    pub seed: u64,
    /// Worker threads, 1 to 1024; 0: all cores.
    pub threads: u32,
    /// Called with `user` as the run goes; may be null.
    pub progress: GsidProgressFn,
    pub user: *mut c_void,
    /// Read every few milliseconds while the run goes on: non-zero cancels it (set it from any
    /// thread, e.g. with C11 `atomic_store`). May be null.
    pub cancel: *const i32,
}

/// A buffer the command line reads, by the name it reads it under: `albedo`, `normal`, `depth`,
/// `material`, `shadow` (features), `variance` (the renderer's variance of the pixel mean, 3
/// channels) or `color_a` and `color_b` (the colour of two independent halves of the samples, 3
/// channels each, given together). For [`gsid_denoise_buffers`].
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct GsidBuffer {
    pub name: *const c_char,
    pub image: GsidImage,
}

/// A pipeline ready to run: made by [`gsid_pipeline_new`] or [`gsid_pipeline_from_toml`], freed
/// by [`gsid_pipeline_free`]. One pipeline may run on several threads at once.
pub struct GsidPipeline {
    spec: PipelineSpec,
    built: Pipeline,
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_error(msg: &str) {
    let msg = CString::new(msg.replace('\0', " ")).unwrap_or_default();
    LAST_ERROR.with_borrow_mut(|e| *e = msg);
}

/// Runs an entry point: its error as a status and this thread's message, a panic caught.
fn guard(f: impl FnOnce() -> Result<(), Error>) -> GsidStatus {
    set_error("");
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => GsidStatus::Ok,
        Ok(Err(e)) => {
            set_error(&e.to_string());
            match e {
                Error::Cancelled => GsidStatus::Cancelled,
                e if e.exit_code() == 2 => GsidStatus::Invalid,
                _ => GsidStatus::Failed,
            }
        }
        Err(panic) => {
            let what = panic
                .downcast_ref::<String>()
                .map(String::as_str)
                .or_else(|| panic.downcast_ref::<&str>().copied())
                .unwrap_or("unknown");
            set_error(&format!(
                "internal error in gsid (please report it): {what}"
            ));
            GsidStatus::Internal
        }
    }
}

fn invalid(what: &str, msg: &str) -> Error {
    Error::config(what, msg)
}

/// A C string argument as UTF-8.
///
/// # Safety
/// `s` is null or a NUL-terminated string.
unsafe fn text<'a>(s: *const c_char, what: &str) -> Result<&'a str, Error> {
    if s.is_null() {
        return Err(invalid(what, "is a null pointer"));
    }
    // SAFETY: not null; the caller vouches for the terminator.
    unsafe { CStr::from_ptr(s) }
        .to_str()
        .map_err(|_| invalid(what, "is not UTF-8"))
}

/// The defaults: seed 0, all cores, no progress, no cancel flag.
#[no_mangle]
pub extern "C" fn gsid_options_default() -> GsidOptions {
    GsidOptions {
        seed: 0,
        threads: 0,
        progress: None,
        user: std::ptr::null_mut(),
        cancel: std::ptr::null(),
    }
}

/// This thread's message of the last call that failed ("" after one that worked): one line
/// naming the buffer, key or file at fault, as the command line prints it. Valid until the
/// next gsid call on this thread.
#[no_mangle]
pub extern "C" fn gsid_last_error() -> *const c_char {
    LAST_ERROR.with_borrow(|e| e.as_ptr())
}

/// The library's version, e.g. "0.1.0".
#[no_mangle]
pub extern "C" fn gsid_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

fn store(spec: PipelineSpec, out: *mut *mut GsidPipeline) -> Result<(), Error> {
    let built = spec.build()?;
    let handle = Box::new(GsidPipeline { spec, built });
    // SAFETY: checked not null by the callers.
    unsafe { *out = Box::into_raw(handle) };
    Ok(())
}

/// Makes a pipeline from a built-in name (`full`, `balanced`, `fast`, ...) or a pipeline file's
/// path (ending in `.toml`), as `gsid denoise --pipeline` takes it, into `*out`.
///
/// # Safety
/// `name` is a NUL-terminated string; `out` points at writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn gsid_pipeline_new(
    name: *const c_char,
    out: *mut *mut GsidPipeline,
) -> GsidStatus {
    guard(|| {
        if out.is_null() {
            return Err(invalid("out", "is a null pointer"));
        }
        // SAFETY: the caller's promise.
        let name = unsafe { text(name, "pipeline name") }?;
        store(PipelineSpec::resolve(name)?, out)
    })
}

/// Makes a pipeline from a pipeline file's text (TOML, docs/FORMATS.md) into `*out`.
///
/// # Safety
/// `toml` is a NUL-terminated string; `out` points at writable storage for a pointer.
#[no_mangle]
pub unsafe extern "C" fn gsid_pipeline_from_toml(
    toml: *const c_char,
    out: *mut *mut GsidPipeline,
) -> GsidStatus {
    guard(|| {
        if out.is_null() {
            return Err(invalid("out", "is a null pointer"));
        }
        // SAFETY: the caller's promise.
        let toml = unsafe { text(toml, "pipeline text") }?;
        store(PipelineSpec::parse(toml, "pipeline text")?, out)
    })
}

/// Overrides one parameter as `gsid denoise --set KEY=VALUE` does (`gsid.walks=40`); on an
/// error the pipeline is as it was.
///
/// # Safety
/// `pipeline` came from this API and is not freed; `assignment` is a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn gsid_pipeline_set(
    pipeline: *mut GsidPipeline,
    assignment: *const c_char,
) -> GsidStatus {
    guard(|| {
        // SAFETY: the caller's promise.
        let Some(p) = (unsafe { pipeline.as_mut() }) else {
            return Err(invalid("pipeline", "is a null pointer"));
        };
        // SAFETY: the caller's promise.
        let assignment = unsafe { text(assignment, "--set") }?;
        let mut spec = p.spec.clone();
        spec.apply_set(assignment)?;
        p.built = spec.build()?;
        p.spec = spec;
        Ok(())
    })
}

/// Frees a pipeline (null is allowed).
///
/// # Safety
/// `pipeline` is null or came from this API, and is not used again.
#[no_mangle]
pub unsafe extern "C" fn gsid_pipeline_free(pipeline: *mut GsidPipeline) {
    if !pipeline.is_null() {
        // SAFETY: made by Box::into_raw in `store`, freed once.
        let _ = catch_unwind(AssertUnwindSafe(|| {
            drop(unsafe { Box::from_raw(pipeline) })
        }));
    }
}

/// Strides with 0 read as packed.
fn strides(channels: usize, width: usize, row: isize, pixel: isize) -> [isize; 3] {
    let pixel = if pixel == 0 { channels as isize } else { pixel };
    let row = if row == 0 {
        width as isize * pixel
    } else {
        row
    };
    [row, pixel, 1]
}

/// A buffer argument as a view; null is `None`.
///
/// # Safety
/// `img` is null or points at a [`GsidImage`] whose samples are readable for the call.
unsafe fn view<'a>(img: *const GsidImage, name: &str) -> Result<Option<ImageView<'a>>, Error> {
    // SAFETY: the caller's promise.
    let Some(img) = (unsafe { img.as_ref() }) else {
        return Ok(None);
    };
    let shape = (img.width, img.height, img.channels);
    let strides = strides(img.channels, img.width, img.row_stride, img.pixel_stride);
    // SAFETY: the caller vouches for the samples the strides reach.
    unsafe { ImageView::from_raw(img.data, shape, strides) }
        .map(Some)
        .map_err(|msg| Error::buffer(name, msg))
}

/// Denoises a frame: `color` (3 channels) and the optional `albedo` (3), `normal` (3, unit xyz)
/// and `depth` (1) (null when the renderer has none), all of one size, into `output` (3
/// channels of that size). `output` is written only when the run succeeds. `options` may be
/// null (the defaults). The same inputs, pipeline and seed give the command line's bits.
///
/// # Safety
/// `pipeline` came from this API; each image pointer is null (not `color`, not `output`) or
/// points at a description of memory readable (writable for `output`) for the call, which no
/// one writes meanwhile; `options`, when not null, points at a [`GsidOptions`] whose `cancel`
/// is null or stays readable for the call.
#[no_mangle]
pub unsafe extern "C" fn gsid_denoise(
    pipeline: *const GsidPipeline,
    color: *const GsidImage,
    albedo: *const GsidImage,
    normal: *const GsidImage,
    depth: *const GsidImage,
    output: *const GsidImageMut,
    options: *const GsidOptions,
) -> GsidStatus {
    guard(|| {
        // SAFETY: the caller's promise, for every pointer below.
        let (pipeline, options, mut inputs) = unsafe { start(pipeline, color, options) }?;
        for (feature, img) in [
            (Feature::Albedo, albedo),
            (Feature::Normal, normal),
            (Feature::Depth, depth),
        ] {
            if let Some(v) = unsafe { view(img, feature.name()) }? {
                inputs = inputs.with(feature, v);
            }
        }
        unsafe { run_into(&pipeline.built, &inputs, output, &options) }
    })
}

/// [`gsid_denoise`] with any of the buffers the command line reads: `color` (3 channels) and
/// `count` named buffers ([`GsidBuffer`]; `buffers` may be null when `count` is 0), all of one
/// size, into `output` (3 channels of that size), written only when the run succeeds. An unknown
/// name, a buffer of the wrong shape or one half without the other is `GSID_STATUS_INVALID`
/// with a message naming it. The same buffers, pipeline and seed give the command line's bits.
///
/// # Safety
/// As [`gsid_denoise`]; `buffers` points at `count` readable [`GsidBuffer`]s whose names are
/// NUL-terminated strings.
#[no_mangle]
pub unsafe extern "C" fn gsid_denoise_buffers(
    pipeline: *const GsidPipeline,
    color: *const GsidImage,
    buffers: *const GsidBuffer,
    count: usize,
    output: *const GsidImageMut,
    options: *const GsidOptions,
) -> GsidStatus {
    guard(|| {
        // SAFETY: the caller's promise, for every pointer below.
        let (pipeline, options, mut inputs) = unsafe { start(pipeline, color, options) }?;
        let buffers: &[GsidBuffer] = match (buffers.is_null(), count) {
            (_, 0) => &[],
            (true, _) => return Err(invalid("buffers", "is a null pointer")),
            (false, n) => unsafe { std::slice::from_raw_parts(buffers, n) },
        };
        for buffer in buffers {
            let name = unsafe { text(buffer.name, "buffer name") }?;
            let v = unsafe { view(&buffer.image, name) }?.expect("a reference is not null");
            inputs = inputs.with_named(name, v)?;
        }
        unsafe { run_into(&pipeline.built, &inputs, output, &options) }
    })
}

/// What every denoise call starts from: its pipeline, its options (the defaults when null) and
/// inputs holding the colour.
///
/// # Safety
/// As [`gsid_denoise`] for `pipeline`, `color` and `options`.
unsafe fn start<'a>(
    pipeline: *const GsidPipeline,
    color: *const GsidImage,
    options: *const GsidOptions,
) -> Result<(&'a GsidPipeline, GsidOptions, Inputs<'a>), Error> {
    // SAFETY: the caller's promise.
    let Some(pipeline) = (unsafe { pipeline.as_ref() }) else {
        return Err(invalid("pipeline", "is a null pointer"));
    };
    let options = unsafe { options.as_ref() }
        .copied()
        .unwrap_or_else(|| gsid_options_default());
    let color = unsafe { view(color, "color") }?
        .ok_or_else(|| Error::buffer("color", "is a null pointer"))?;
    Ok((pipeline, options, Inputs::new(color)))
}

/// [`run`] into the caller's `output`.
///
/// # Safety
/// `output` is null or describes memory writable for the call, which no one reads meanwhile.
unsafe fn run_into(
    pipeline: &Pipeline,
    inputs: &Inputs,
    output: *const GsidImageMut,
    options: &GsidOptions,
) -> Result<(), Error> {
    // SAFETY: the caller's promise.
    let Some(out) = (unsafe { output.as_ref() }) else {
        return Err(Error::buffer("output", "is a null pointer"));
    };
    let shape = (out.width, out.height, out.channels);
    let strides = strides(out.channels, out.width, out.row_stride, out.pixel_stride);
    // SAFETY: the caller vouches for the samples the strides reach.
    let mut out = unsafe { ImageViewMut::from_raw(out.data, shape, strides) }
        .map_err(|msg| Error::buffer("output", msg))?;
    run(pipeline, inputs, &mut out, options)
}

/// The run on a thread of its own, the caller's thread passing progress on and reading the
/// cancel flag.
fn run(
    pipeline: &Pipeline,
    inputs: &Inputs,
    out: &mut ImageViewMut,
    options: &GsidOptions,
) -> Result<(), Error> {
    let cancel = CancelToken::new();
    let relay = ProgressRelay::new();
    let run_options = DenoiseOptions {
        seed: options.seed,
        threads: (options.threads > 0).then_some(options.threads as usize),
        progress: options.progress.is_some().then(|| relay.callback()),
        cancel: Some(cancel.clone()),
        ..DenoiseOptions::default()
    };
    let flag = options.cancel.cast::<AtomicI32>();
    // SAFETY: the caller keeps the flag readable for the call; an i32's alignment is an
    // AtomicI32's.
    let flagged = || unsafe { flag.as_ref() }.is_some_and(|f| f.load(Ordering::Relaxed) != 0);
    if flagged() {
        return Err(Error::Cancelled);
    }
    let result = run_watched(
        || {
            catch_unwind(AssertUnwindSafe(|| {
                pipeline.denoise_into(inputs, out, &run_options)
            }))
        },
        || {
            if flagged() {
                cancel.cancel();
            }
            if let (Some(progress), Some((fraction, stage))) = (options.progress, relay.take()) {
                let stage = CString::new(stage).unwrap_or_default();
                // SAFETY: a function the caller gave, with the pointer it gave.
                if !unsafe { progress(options.user, fraction, stage.as_ptr()) } {
                    cancel.cancel();
                }
            }
        },
    );
    match result {
        Ok(r) => r.map(|_| ()),
        Err(panic) => std::panic::resume_unwind(panic),
    }
}
