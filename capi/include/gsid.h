/* gsid C API: denoise a path-traced frame in-process (see docs/EMBEDDING.md).
 * Made by cbindgen from capi/src/lib.rs; do not edit. */

#ifndef GSID_H
#define GSID_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

// What a call returned.
typedef enum GsidStatus {
  // It worked.
  GSID_STATUS_OK = 0,
  // Bad input or argument (a null pointer, a buffer of the wrong shape, an unknown pipeline, a
  // wrong parameter): what the command line exits 2 for. The message names the culprit.
  GSID_STATUS_INVALID = 1,
  // The run was cancelled (the cancel flag, or the progress callback returned false); the
  // output buffer is untouched.
  GSID_STATUS_CANCELLED = 2,
  // A failure that is not the input's (out of memory for threads, an I/O error).
  GSID_STATUS_FAILED = 3,
  // A bug in gsid (a Rust panic, caught at the boundary); the message says where.
  GSID_STATUS_INTERNAL = 4,
} GsidStatus;

// A pipeline ready to run: made by [`gsid_pipeline_new`] or [`gsid_pipeline_from_toml`], freed
// by [`gsid_pipeline_free`]. One pipeline may run on several threads at once.
typedef struct GsidPipeline GsidPipeline;

// Told how far a run is (0 to 1, never decreasing) and which stage runs (`done` at the end),
// on the thread that called [`gsid_denoise`], every few milliseconds while the run goes on.
// Return false to cancel the run.
typedef bool (*GsidProgressFn)(void *user, float fraction, const char *stage);

// How a run goes; start from [`gsid_options_default`].
typedef struct GsidOptions {
  // Seed of every random choice: the same inputs, pipeline and seed give the same bits on any
  // number of threads.
  uint64_t seed;
  // Worker threads, 1 to 1024; 0: all cores.
  uint32_t threads;
  // Called with `user` as the run goes; may be null.
  GsidProgressFn progress;
  void *user;
  // Read every few milliseconds while the run goes on: non-zero cancels it (set it from any
  // thread, e.g. with C11 `atomic_store`). May be null.
  const int32_t *cancel;
} GsidOptions;

// A float image the caller owns. `data` points at pixel (0, 0)'s first channel; a pixel's
// channels are adjacent. Strides are in floats, not bytes, and may be negative (rows stored
// bottom-up); 0 means packed: `pixel_stride` = `channels`, `row_stride` = `width * pixel_stride`.
// An RGBA framebuffer read as RGB: `channels` 3, `pixel_stride` 4.
typedef struct GsidImage {
  const float *data;
  size_t width;
  size_t height;
  size_t channels;
  ptrdiff_t row_stride;
  ptrdiff_t pixel_stride;
} GsidImage;

// A float image the caller owns and gsid writes (see [`GsidImage`]); elements between its
// samples (an alpha channel, row padding) are left alone.
typedef struct GsidImageMut {
  float *data;
  size_t width;
  size_t height;
  size_t channels;
  ptrdiff_t row_stride;
  ptrdiff_t pixel_stride;
} GsidImageMut;

// A buffer the command line reads, by the name it reads it under: `albedo`, `normal`, `depth`,
// `material`, `shadow` (features), `variance` (the renderer's variance of the pixel mean, 3
// channels) or `color_a` and `color_b` (the colour of two independent halves of the samples, 3
// channels each, given together). For [`gsid_denoise_buffers`].
typedef struct GsidBuffer {
  const char *name;
  struct GsidImage image;
} GsidBuffer;

#ifdef __cplusplus
extern "C" {
#endif // __cplusplus

// The defaults: seed 0, all cores, no progress, no cancel flag.
struct GsidOptions gsid_options_default(void);

// This thread's message of the last call that failed ("" after one that worked): one line
// naming the buffer, key or file at fault, as the command line prints it. Valid until the
// next gsid call on this thread.
const char *gsid_last_error(void);

// The library's version, e.g. "0.1.0".
const char *gsid_version(void);

// Makes a pipeline from a built-in name (`full`, `balanced`, `fast`, ...) or a pipeline file's
// path (ending in `.toml`), as `gsid denoise --pipeline` takes it, into `*out`.
//
// # Safety
// `name` is a NUL-terminated string; `out` points at writable storage for a pointer.
enum GsidStatus gsid_pipeline_new(const char *name, struct GsidPipeline **out);

// Makes a pipeline from a pipeline file's text (TOML, docs/FORMATS.md) into `*out`.
//
// # Safety
// `toml` is a NUL-terminated string; `out` points at writable storage for a pointer.
enum GsidStatus gsid_pipeline_from_toml(const char *toml, struct GsidPipeline **out);

// Overrides one parameter as `gsid denoise --set KEY=VALUE` does (`gsid.walks=40`); on an
// error the pipeline is as it was.
//
// # Safety
// `pipeline` came from this API and is not freed; `assignment` is a NUL-terminated string.
enum GsidStatus gsid_pipeline_set(struct GsidPipeline *pipeline, const char *assignment);

// Frees a pipeline (null is allowed).
//
// # Safety
// `pipeline` is null or came from this API, and is not used again.
void gsid_pipeline_free(struct GsidPipeline *pipeline);

// Denoises a frame: `color` (3 channels) and the optional `albedo` (3), `normal` (3, unit xyz)
// and `depth` (1) (null when the renderer has none), all of one size, into `output` (3
// channels of that size). `output` is written only when the run succeeds. `options` may be
// null (the defaults). The same inputs, pipeline and seed give the command line's bits.
//
// # Safety
// `pipeline` came from this API; each image pointer is null (not `color`, not `output`) or
// points at a description of memory readable (writable for `output`) for the call, which no
// one writes meanwhile; `options`, when not null, points at a [`GsidOptions`] whose `cancel`
// is null or stays readable for the call.
enum GsidStatus gsid_denoise(const struct GsidPipeline *pipeline,
                             const struct GsidImage *color,
                             const struct GsidImage *albedo,
                             const struct GsidImage *normal,
                             const struct GsidImage *depth,
                             const struct GsidImageMut *output,
                             const struct GsidOptions *options);

// [`gsid_denoise`] with any of the buffers the command line reads: `color` (3 channels) and
// `count` named buffers ([`GsidBuffer`]; `buffers` may be null when `count` is 0), all of one
// size, into `output` (3 channels of that size), written only when the run succeeds. An unknown
// name, a buffer of the wrong shape or one half without the other is `GSID_STATUS_INVALID`
// with a message naming it. The same buffers, pipeline and seed give the command line's bits.
//
// # Safety
// As [`gsid_denoise`]; `buffers` points at `count` readable [`GsidBuffer`]s whose names are
// NUL-terminated strings.
enum GsidStatus gsid_denoise_buffers(const struct GsidPipeline *pipeline,
                                     const struct GsidImage *color,
                                     const struct GsidBuffer *buffers,
                                     size_t count,
                                     const struct GsidImageMut *output,
                                     const struct GsidOptions *options);

#ifdef __cplusplus
}  // extern "C"
#endif  // __cplusplus

#endif  /* GSID_H */
