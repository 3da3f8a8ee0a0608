"""The Python package: the CLI's pixels, strided arrays, errors naming the buffer, progress,
cancellation from another thread and by Ctrl-C, and the GIL released while a run goes on.

Run from the repository root: ``python -m pytest python/tests`` (GSID_BIN names the gsid binary
to compare with; without it and without ``gsid`` on PATH the comparison is skipped).
"""

import _thread
import os
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import gsid

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "fixtures" / "cornell" / "spp4"


def synthetic(h, w, seed=1):
    """A noisy frame with albedo, normal and depth: float32, C-contiguous."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    base = np.stack([0.5 + 0.4 * np.sin(x * 20), 0.5 + 0.4 * np.cos(y * 13), 0.3 + 0.2 * x], -1)
    color = (base * rng.exponential(1.0, (h, w, 3))).astype(np.float32)
    albedo = np.clip(base, 0, 1).astype(np.float32)
    normal = np.zeros((h, w, 3), np.float32)
    normal[..., 2] = 1
    depth = (2 + x + y).astype(np.float32)
    return color, albedo, normal, depth


def gsid_binary():
    return os.environ.get("GSID_BIN") or shutil.which("gsid")


def test_same_pixels_as_the_cli(tmp_path):
    exe = gsid_binary()
    if not exe:
        pytest.skip("no gsid binary (GSID_BIN or gsid on PATH)")
    names = ["color", "albedo", "normal", "depth"]
    out = tmp_path / "cli.exr"
    args = [exe, "denoise", "-q", "-o", str(out)]
    for n in names:
        args += [f"--{n}", str(FIXTURE / f"{n}.exr")]
    subprocess.run(args, check=True)
    cli = gsid.read_render(out)["color"]

    buffers = gsid.read_render(FIXTURE)
    assert buffers["color"].dtype == np.float32 and buffers["color"].ndim == 3
    assert buffers["depth"].ndim == 2
    mine = gsid.denoise(*(buffers[n] for n in names))
    assert mine.shape == cli.shape and mine.dtype == np.float32
    assert np.array_equal(mine.view(np.uint32), cli.view(np.uint32))


def test_every_buffer_read_render_returns_is_denoised_as_the_cli_does(tmp_path):
    exe = gsid_binary()
    if not exe:
        pytest.skip("no gsid binary (GSID_BIN or gsid on PATH)")
    out = tmp_path / "cli.exr"
    subprocess.run([exe, "denoise", str(FIXTURE), "-q", "-o", str(out)], check=True)
    cli = gsid.read_render(out)["color"]

    buffers = gsid.read_render(FIXTURE)
    extra = {"material", "shadow", "variance", "color_a", "color_b"}
    assert extra <= buffers.keys(), buffers.keys()
    mine = gsid.denoise(**buffers)
    assert np.array_equal(mine.view(np.uint32), cli.view(np.uint32))
    # The extra buffers are read: without them the pixels differ.
    plain = gsid.denoise(**{k: v for k, v in buffers.items() if k not in extra})
    assert not np.array_equal(plain.view(np.uint32), cli.view(np.uint32))


def test_non_contiguous_views_read_in_place_give_the_same_bits():
    color, albedo, normal, depth = synthetic(48, 64)
    flipped = [a[:, ::-1] for a in (color, albedo, normal, depth)]
    assert not flipped[0].flags.c_contiguous
    want = gsid.denoise(*(np.ascontiguousarray(a) for a in flipped), pipeline="fast", seed=3)
    got = gsid.denoise(*flipped, pipeline="fast", seed=3)
    assert np.array_equal(got.view(np.uint32), want.view(np.uint32))
    # A channel view of a wider array (RGBA read as RGB) and a transposed one.
    rgba = np.concatenate([color, np.ones_like(color[..., :1])], -1)
    assert np.array_equal(
        gsid.denoise(rgba[..., :3], pipeline="fast"), gsid.denoise(color, pipeline="fast")
    )
    assert np.array_equal(
        gsid.denoise(rgba, pipeline="fast"), gsid.denoise(color, pipeline="fast")
    )
    t = np.ascontiguousarray(color.transpose(1, 0, 2)).transpose(1, 0, 2)
    assert np.array_equal(gsid.denoise(t, pipeline="fast"), gsid.denoise(color, pipeline="fast"))


@pytest.mark.parametrize(
    "make, culprit",
    [
        (lambda c, a, n, d: ((c[..., 0],), {}), "buffer `color`: has shape (48, 64)"),
        (lambda c, a, n, d: ((c.astype(np.float64),), {}), "buffer `color`: is a float64 array"),
        (lambda c, a, n, d: ((c, a[:, :50]), {}), "buffer `albedo`: is 50x48 but colour is 64x48"),
        (lambda c, a, n, d: ((c, None, n[:40]), {}), "buffer `normal`: is 64x40"),
        (lambda c, a, n, d: ((c, None, None, n), {}), "buffer `depth`: has shape (48, 64, 3)"),
        (lambda c, a, n, d: ((np.full_like(c, np.nan),), {}), "buffer `color`: every sample is NaN"),
        (lambda c, a, n, d: ((c, np.full_like(a, np.nan)), {}), "buffer `albedo`: every sample is NaN"),
        (lambda c, a, n, d: ((c,), {"pipeline": "no-such"}), "unknown pipeline `no-such`"),
        (lambda c, a, n, d: ((c,), {"set": ["gsid.walsk=3"]}), "walsk"),
        (lambda c, a, n, d: ((c,), {"threads": 0}), "threads"),
        (lambda c, a, n, d: (([[0.0]],), {}), "buffer `color`: is a list"),
        (lambda c, a, n, d: ((c,), {"shadow": a}), "buffer `shadow`: has shape (48, 64, 3)"),
        (lambda c, a, n, d: ((c,), {"material": a[:40]}), "buffer `material`: is 64x40"),
        (lambda c, a, n, d: ((c,), {"variance": d}), "buffer `variance`: has shape (48, 64)"),
        (lambda c, a, n, d: ((c,), {"color_a": c}), "buffer `color_b`: is required with color_a"),
    ],
)
def test_bad_input_raises_gsid_error_naming_the_culprit(make, culprit):
    args, kwargs = make(*synthetic(48, 64))
    with pytest.raises(gsid.Error) as raised:
        gsid.denoise(*args, **kwargs)
    assert isinstance(raised.value, ValueError)
    assert culprit in str(raised.value)


def test_progress_fractions_never_decrease_and_end_at_one():
    seen = []
    gsid.denoise(*synthetic(256, 256), progress=lambda f, stage: seen.append((f, stage)))
    assert len(seen) >= 3, seen
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions), seen
    assert all(0.0 <= f <= 1.0 for f in fractions)
    assert seen[-1] == (1.0, "done")
    stages = {s for _, s in seen}
    assert len(stages) >= 3, seen


def test_progress_returning_false_or_raising_cancels():
    frame = synthetic(256, 256)
    with pytest.raises(gsid.Cancelled):
        gsid.denoise(*frame, progress=lambda f, s: False)

    def boom(f, s):
        raise RuntimeError("from the callback")

    with pytest.raises(RuntimeError, match="from the callback"):
        gsid.denoise(*frame, progress=boom)


def test_a_cancel_from_another_thread_ends_a_1024_run_within_half_a_second():
    frame = synthetic(1024, 1024)
    token = gsid.CancelToken()
    started = threading.Event()
    outcome = {}

    def run():
        try:
            gsid.denoise(*frame, cancel=token, progress=lambda f, s: started.set())
            outcome["error"] = None
        except BaseException as e:  # noqa: BLE001 - the test inspects it
            outcome["error"] = e

    worker = threading.Thread(target=run)
    worker.start()
    assert started.wait(30)
    time.sleep(0.3)  # well inside the run (several seconds at 1024²)
    t0 = time.perf_counter()
    token.cancel()
    worker.join(10)
    elapsed = time.perf_counter() - t0
    print(f"cancel of a 1024x1024 full run returned after {elapsed * 1000:.0f} ms")
    assert not worker.is_alive()
    assert isinstance(outcome["error"], gsid.Cancelled), outcome
    assert elapsed < 0.5, f"{elapsed:.3f} s"
    assert token.cancelled


def test_ctrl_c_cancels_the_run_and_raises_keyboard_interrupt():
    frame = synthetic(1024, 1024)
    # Python's own SIGINT handler, even when started with SIGINT ignored (a background job).
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.5, _thread.interrupt_main)
    timer.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            gsid.denoise(*frame)
    finally:
        elapsed = time.perf_counter() - t0
        timer.join()
        signal.signal(signal.SIGINT, previous)
    print(f"Ctrl-C 0.5 s into a 1024x1024 run: returned after {elapsed:.2f} s")
    assert elapsed < 5.0


def test_the_gil_is_released_while_a_run_goes_on():
    frame = synthetic(512, 512)
    count = [0]
    stop = threading.Event()

    def counter():
        while not stop.is_set():
            count[0] += 1

    t = threading.Thread(target=counter)
    t.start()
    time.sleep(0.05)
    before = count[0]
    t0 = time.perf_counter()
    gsid.denoise(*frame)
    seconds = time.perf_counter() - t0
    during = count[0] - before
    stop.set()
    t.join()
    # Holding the GIL for the whole run, the counter would gain a handful of increments at most.
    assert during > 10000, (during, seconds)


def test_read_render_maps_buffers_as_the_cli_and_names_bad_files(tmp_path):
    b = gsid.read_render(FIXTURE)
    assert {"color", "albedo", "normal", "depth"} <= set(b)
    h, w, _ = b["color"].shape
    assert b["albedo"].shape == (h, w, 3) and b["depth"].shape == (h, w)
    with pytest.raises(gsid.Error, match="nothing-here"):
        gsid.read_render(tmp_path / "nothing-here")
    with pytest.raises(gsid.Error, match="--map"):
        gsid.read_render(FIXTURE / "color.exr", maps={"colour": "X"})
    assert "full" in gsid.pipelines()
