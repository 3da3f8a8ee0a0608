//! `gsid._gsid`: the native side of the Python package. NumPy arrays are read in place (any
//! strides, no copy in Python), the run goes on a thread of its own with the GIL released, and
//! the calling thread wakes every few milliseconds to pass progress on and to look for Ctrl-C
//! (Python only delivers signals to the main thread, so it must be the caller's thread that looks).
//! The documented functions are in `gsid/__init__.py`.

use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use gsid::embed::watch::{run_watched, ProgressRelay};
use gsid::{CancelToken, DenoiseOptions, Feature, ImageView, ImageViewMut, Inputs, PipelineSpec};
use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

pyo3::create_exception!(
    gsid,
    Error,
    PyValueError,
    "Bad input or a failed run: the command line's one-line message, naming the buffer, key or file."
);
pyo3::create_exception!(
    gsid,
    Cancelled,
    Error,
    "The run was cancelled (a CancelToken, or the progress callback returned False)."
);

fn error(e: gsid::Error) -> PyErr {
    match e {
        gsid::Error::Cancelled => Cancelled::new_err("cancelled"),
        e => Error::new_err(e.to_string()),
    }
}

fn buffer_error(name: &str, msg: impl std::fmt::Display) -> PyErr {
    error(gsid::Error::buffer(name, msg))
}

/// Stops a run from any thread: pass it as `cancel=` and call `cancel()`.
#[pyclass(frozen, name = "CancelToken", module = "gsid")]
struct PyCancelToken(CancelToken);

#[pymethods]
impl PyCancelToken {
    #[new]
    fn new() -> Self {
        PyCancelToken(CancelToken::new())
    }

    /// Asks every run holding this token to stop; it raises `gsid.Cancelled`.
    fn cancel(&self) {
        self.0.cancel()
    }

    /// Whether `cancel()` was called.
    #[getter]
    fn cancelled(&self) -> bool {
        self.0.is_cancelled()
    }
}

/// A borrowed float32 array: its shape as (width, height, channels) and strides in elements.
struct Borrowed<'py> {
    _keep: numpy::PyReadonlyArrayDyn<'py, f32>,
    ptr: *const f32,
    shape: (usize, usize, usize),
    strides: [isize; 3],
}

/// Borrows `obj` as buffer `name`: H×W×3 (or ×4, whose fourth channel is not read) when
/// `channels` is 3, H×W or H×W×1 when it is 1.
fn borrow<'py>(name: &str, obj: &Bound<'py, PyAny>, channels: usize) -> PyResult<Borrowed<'py>> {
    let Ok(array) = obj.cast::<PyArrayDyn<f32>>() else {
        let msg = match obj.getattr("dtype") {
            Ok(dtype) => format!(
                "is a {dtype} array; gsid takes float32 (convert it with .astype(numpy.float32))"
            ),
            Err(_) => format!("is a {}, not a NumPy float32 array", obj.get_type().name()?),
        };
        return Err(buffer_error(name, msg));
    };
    let shape = array.shape().to_vec();
    let bytes = array.strides().to_vec();
    let expected = if channels == 3 {
        "(height, width, 3)"
    } else {
        "(height, width) or (height, width, 1)"
    };
    let fits = match (channels, shape.as_slice()) {
        (3, [_, _, c]) => *c == 3 || *c == 4,
        (1, [_, _]) => true,
        (1, [_, _, 1]) => true,
        _ => false,
    };
    if !fits {
        let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
        return Err(buffer_error(
            name,
            format!("has shape ({}), expected {expected}", dims.join(", ")),
        ));
    }
    let item = std::mem::size_of::<f32>() as isize;
    if bytes.iter().any(|b| b % item != 0) {
        return Err(buffer_error(
            name,
            "has strides that are not whole float32s; pass numpy.ascontiguousarray(arr)",
        ));
    }
    let stride = |k: usize| bytes.get(k).map_or(1, |b| b / item);
    let keep = array
        .try_readonly()
        .map_err(|e| buffer_error(name, format!("cannot be read: {e}")))?;
    Ok(Borrowed {
        ptr: array.data() as *const f32,
        shape: (shape[1], shape[0], channels),
        strides: [
            stride(0),
            stride(1),
            if shape.len() == 3 { stride(2) } else { 1 },
        ],
        _keep: keep,
    })
}

impl Borrowed<'_> {
    fn view(&self, name: &str) -> PyResult<ImageView<'_>> {
        // SAFETY: NumPy vouches that every element the shape and strides reach lies in the
        // array's memory, which the readonly borrow keeps alive and unborrowed mutably by Rust.
        unsafe { ImageView::from_raw(self.ptr, self.shape, self.strides) }
            .map_err(|msg| buffer_error(name, msg))
    }
}

/// The pipeline a `pipeline=` argument names: TOML text when it holds a line break, else a
/// built-in name or a pipeline file's path; then each `set` override.
fn pipeline_of(pipeline: &str, set: &[String]) -> PyResult<gsid::Pipeline> {
    let mut spec = if pipeline.contains('\n') {
        PipelineSpec::parse(pipeline, "pipeline text")
    } else {
        PipelineSpec::resolve(pipeline)
    }
    .map_err(error)?;
    for assignment in set {
        spec.apply_set(assignment).map_err(error)?;
    }
    spec.build().map_err(error)
}

#[pyfunction]
#[pyo3(signature = (color, albedo=None, normal=None, depth=None, *, material=None, shadow=None, variance=None, color_a=None, color_b=None, pipeline="full", seed=0, threads=None, progress=None, cancel=None, set=None))]
#[allow(clippy::too_many_arguments)]
fn denoise<'py>(
    py: Python<'py>,
    color: &Bound<'py, PyAny>,
    albedo: Option<&Bound<'py, PyAny>>,
    normal: Option<&Bound<'py, PyAny>>,
    depth: Option<&Bound<'py, PyAny>>,
    material: Option<&Bound<'py, PyAny>>,
    shadow: Option<&Bound<'py, PyAny>>,
    variance: Option<&Bound<'py, PyAny>>,
    color_a: Option<&Bound<'py, PyAny>>,
    color_b: Option<&Bound<'py, PyAny>>,
    pipeline: &str,
    seed: u64,
    threads: Option<usize>,
    progress: Option<Py<PyAny>>,
    cancel: Option<Py<PyCancelToken>>,
    set: Option<Vec<String>>,
) -> PyResult<Bound<'py, PyAny>> {
    let pipeline = pipeline_of(pipeline, set.as_deref().unwrap_or_default())?;
    let color = borrow("color", color, 3)?;
    // Every buffer the command line reads, by the name it reads it under.
    let mut features = Vec::new();
    for (name, obj) in [
        ("albedo", albedo),
        ("normal", normal),
        ("depth", depth),
        ("material", material),
        ("shadow", shadow),
        ("variance", variance),
        ("color_a", color_a),
        ("color_b", color_b),
    ] {
        if let Some(obj) = obj.filter(|o| !o.is_none()) {
            let channels = Feature::from_name(name).map_or(3, Feature::channels);
            features.push((name, borrow(name, obj, channels)?));
        }
    }
    let mut inputs = Inputs::new(color.view("color")?);
    for (name, b) in &features {
        inputs = inputs.with_named(name, b.view(name)?).map_err(error)?;
    }
    let (w, h) = inputs.dims();
    let mut out = vec![0.0f32; w * h * 3];
    let token = cancel.map_or_else(CancelToken::new, |c| c.get().0.clone());
    let relay = ProgressRelay::new();
    let options = DenoiseOptions {
        seed,
        threads,
        progress: progress.is_some().then(|| relay.callback()),
        cancel: Some(token.clone()),
        ..DenoiseOptions::default()
    };
    // An exception from Ctrl-C or from the progress callback: it ends the run and is raised.
    let mut raised: Option<PyErr> = None;
    let result = py.detach(|| {
        let mut view = ImageViewMut::packed(&mut out, w, h, 3);
        run_watched(
            || {
                catch_unwind(AssertUnwindSafe(|| {
                    pipeline.denoise_into(&inputs, &mut view, &options)
                }))
            },
            || {
                Python::attach(|py| {
                    if raised.is_some() {
                        return;
                    }
                    if let Err(e) = py.check_signals() {
                        raised = Some(e);
                        token.cancel();
                        return;
                    }
                    let (Some(callback), Some((fraction, stage))) = (&progress, relay.take())
                    else {
                        return;
                    };
                    match callback.call1(py, (fraction, stage)) {
                        Ok(r) if r.bind(py).is(&*pyo3::types::PyBool::new(py, false)) => {
                            token.cancel()
                        }
                        Ok(_) => {}
                        Err(e) => {
                            raised = Some(e);
                            token.cancel();
                        }
                    }
                })
            },
        )
    });
    if let Some(e) = raised {
        return Err(e);
    }
    match result {
        Ok(Ok(_)) => {}
        Ok(Err(e)) => return Err(error(e)),
        Err(_) => {
            return Err(PyRuntimeError::new_err(
                "internal error in gsid (please report it)",
            ))
        }
    }
    drop(features);
    Ok(PyArray1::from_vec(py, out).reshape([h, w, 3])?.into_any())
}

/// The buffers of a render-set folder or a multilayer EXR, as `gsid denoise` maps them.
#[pyfunction]
#[pyo3(signature = (path, maps=None))]
fn read_render<'py>(
    py: Python<'py>,
    path: std::path::PathBuf,
    maps: Option<HashMap<String, String>>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut pairs: Vec<(String, String)> = maps.unwrap_or_default().into_iter().collect();
    pairs.sort();
    for (buffer, _) in &pairs {
        if !gsid::io::passes::PASSES.iter().any(|(n, _)| n == buffer) {
            return Err(error(gsid::Error::config(
                "--map",
                format!("`{buffer}` is not a known buffer"),
            )));
        }
    }
    let loaded = py
        .detach(|| gsid::io::load_input(Path::new(&path), &pairs))
        .map_err(error)?;
    let dict = PyDict::new(py);
    let mut set = loaded.set;
    let mut buffers = vec![("color", set.color)];
    for feature in Feature::ALL {
        buffers.extend(set.features.take(feature).map(|img| (feature.name(), img)));
    }
    let [a, b] = gsid::render_set::NoiseInputs::HALVES;
    buffers.extend(
        set.noise
            .variance
            .map(|v| (gsid::render_set::NoiseInputs::VARIANCE, v)),
    );
    if let Some([ha, hb]) = set.noise.halves {
        buffers.extend([(a, ha), (b, hb)]);
    }
    for (name, img) in buffers {
        let (w, h, c) = (img.width(), img.height(), img.channels());
        let flat = PyArray1::from_vec(py, img.into_vec());
        let array = if c == 1 {
            flat.reshape([h, w])?.into_any()
        } else {
            flat.reshape([h, w, c])?.into_any()
        };
        dict.set_item(name, array)?;
    }
    Ok(dict)
}

/// The names of the built-in pipelines.
#[pyfunction]
fn pipelines() -> Vec<&'static str> {
    gsid::pipeline::BUILTIN.iter().map(|(n, _)| *n).collect()
}

#[pymodule]
fn _gsid(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<Error>())?;
    m.add("Cancelled", py.get_type::<Cancelled>())?;
    m.add_class::<PyCancelToken>()?;
    m.add_function(wrap_pyfunction!(denoise, m)?)?;
    m.add_function(wrap_pyfunction!(read_render, m)?)?;
    m.add_function(wrap_pyfunction!(pipelines, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
