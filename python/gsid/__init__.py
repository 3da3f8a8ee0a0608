"""gsid: feature-guided stochastic image denoising for path-traced renders, in-process.

    import gsid
    out = gsid.denoise(color, albedo, normal)          # float32 (H, W, 3) in, float32 (H, W, 3) out
    buffers = gsid.read_render("shot/frame_0001.exr")  # {"color": ..., "albedo": ..., ...}

The same inputs, pipeline and seed give the bits ``gsid denoise`` writes, on any number of threads.
Errors raise :class:`gsid.Error` (a ``ValueError``) with the command line's one-line message naming
the buffer, key or file. The GIL is released while a run goes on; Ctrl-C cancels it.
"""

from __future__ import annotations

import os
from typing import Callable, Dict, List, Mapping, Optional, Sequence, Union

import numpy as np

from . import _gsid
from ._gsid import CancelToken, Cancelled, Error

__all__ = ["denoise", "read_render", "pipelines", "CancelToken", "Cancelled", "Error"]
__version__: str = _gsid.__version__

ProgressCallback = Callable[[float, str], Optional[bool]]


def denoise(
    color: np.ndarray,
    albedo: Optional[np.ndarray] = None,
    normal: Optional[np.ndarray] = None,
    depth: Optional[np.ndarray] = None,
    *,
    material: Optional[np.ndarray] = None,
    shadow: Optional[np.ndarray] = None,
    variance: Optional[np.ndarray] = None,
    color_a: Optional[np.ndarray] = None,
    color_b: Optional[np.ndarray] = None,
    pipeline: str = "full",
    seed: int = 0,
    threads: Optional[int] = None,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    set: Optional[Sequence[str]] = None,
) -> np.ndarray:
    """Denoises one frame and returns the result as a new float32 (H, W, 3) array.

    color:    noisy linear RGB, float32 (H, W, 3); (H, W, 4) is read as RGB (alpha is not read).
    albedo:   surface colour without lighting, (H, W, 3) or (H, W, 4), in 0..1.
    normal:   shading normals, unit xyz in any space, (H, W, 3) or (H, W, 4).
    depth:    distance to the first hit, (H, W) or (H, W, 1).
    material: material weights (diffuse, reflective, refractive), (H, W, 3).
    shadow:   shadow or visibility, (H, W) or (H, W, 1).
    variance: the renderer's variance of the pixel mean, (H, W, 3): the noise is then not estimated.
    color_a, color_b: the colour of two independent halves of the samples, (H, W, 3) each, given
              together: the noise is measured from their difference.
              Any buffer may be left out (its features are off). ``gsid.denoise(**buffers)`` takes
              what :func:`read_render` returns, the command line's pixels for that set. Every array may have any strides
              (``arr[:, ::-1]``, a channel slice of a larger array): it is read in place, not
              copied in Python. All must be float32 and of one height and width.
    pipeline: a built-in pipeline (``gsid.pipelines()``: full, balanced, fast, ...), a pipeline
              file's path (``.toml``), or a pipeline file's text (anything with a line break).
    seed:     seed of every random choice.
    threads:  worker threads, 1 to 1024; None: all cores.
    progress: called as ``progress(fraction, stage)`` on the calling thread every few
              milliseconds, fraction from 0 to 1 and never decreasing, stage the pipeline stage
              running (``"done"`` at the end). Returning False cancels the run; an exception it
              raises cancels the run and is raised.
    cancel:   a :class:`gsid.CancelToken`; ``token.cancel()`` from any thread stops the run within
              a fraction of a second, raising :class:`gsid.Cancelled`.
    set:      parameter overrides as ``gsid denoise --set`` takes them, e.g. ``["gsid.walks=40"]``.

    Raises :class:`gsid.Error` on bad input (a wrong shape or dtype, mismatched sizes, a buffer of
    nothing but NaN, an unknown pipeline), :class:`gsid.Cancelled` when cancelled, and
    ``KeyboardInterrupt`` on Ctrl-C (the run is cancelled first).
    """
    return _gsid.denoise(
        color,
        albedo,
        normal,
        depth,
        material=material,
        shadow=shadow,
        variance=variance,
        color_a=color_a,
        color_b=color_b,
        pipeline=pipeline,
        seed=seed,
        threads=threads,
        progress=progress,
        cancel=cancel,
        set=None if set is None else list(set),
    )


def read_render(
    path: Union[str, os.PathLike], maps: Optional[Mapping[str, str]] = None
) -> Dict[str, np.ndarray]:
    """Reads a frame's buffers as ``gsid denoise`` maps them.

    path: a render-set folder (color.exr, albedo.exr, normal.exr, depth.exr, ...), or one
          multilayer EXR (Blender's, Mitsuba's, Arnold's passes found by their names).
    maps: which layer of a multilayer file is which buffer, as ``--map`` takes it, e.g.
          ``{"albedo": "ViewLayer.DiffCol"}``.

    Returns ``{"color": (H, W, 3), "albedo": ..., "normal": ..., "depth": (H, W), ...}``, float32,
    only the buffers found; a normal stored in 0..1 comes back remapped to -1..1, as the command
    line reads it; also ``material``, ``shadow``, ``variance`` and ``color_a``/``color_b`` when
    the set has them. ``gsid.denoise(**gsid.read_render(path))`` denoises them as
    ``gsid denoise path`` does.
    """
    return _gsid.read_render(path, None if maps is None else dict(maps))


def pipelines() -> List[str]:
    """The names of the built-in pipelines (``gsid pipelines`` lists them with their stages)."""
    return _gsid.pipelines()

