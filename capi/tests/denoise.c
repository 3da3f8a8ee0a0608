/* The C API from C: denoises a frame handed over as raw float files (the colour through an RGBA
 * framebuffer stored bottom-up, a negative row stride; albedo, normal and the renderer's variance
 * as named buffers), and writes the result as packed RGB floats; then checks that bad arguments
 * come back as error codes with a message, and that a cancelled run leaves the output alone.
 * tests/it/embedding.rs builds and runs it and compares the pixels with the CLI's.
 *
 *   denoise W H color.f32 albedo.f32 normal.f32 variance.f32 out.f32
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gsid.h"

static int failures = 0;

#define CHECK(cond, ...)                                                                           \
    do {                                                                                           \
        if (!(cond)) {                                                                             \
            fprintf(stderr, "FAIL %s:%d: ", __FILE__, __LINE__);                                   \
            fprintf(stderr, __VA_ARGS__);                                                          \
            fprintf(stderr, "\n");                                                                 \
            failures++;                                                                            \
        }                                                                                          \
    } while (0)

static float *read_floats(const char *path, size_t n) {
    float *data = malloc(n * sizeof(float));
    FILE *f = fopen(path, "rb");
    if (!data || !f || fread(data, sizeof(float), n, f) != n) {
        fprintf(stderr, "cannot read %zu floats from %s\n", n, path);
        exit(2);
    }
    fclose(f);
    return data;
}

struct Seen {
    int calls;
    float last;
    int backwards;
};

static bool on_progress(void *user, float fraction, const char *stage) {
    struct Seen *seen = user;
    if (fraction < seen->last || fraction < 0.0f || fraction > 1.0f || stage == NULL)
        seen->backwards++;
    seen->last = fraction;
    seen->calls++;
    return true;
}

int main(int argc, char **argv) {
    if (argc != 8) {
        fprintf(stderr, "usage: denoise W H color.f32 albedo.f32 normal.f32 variance.f32 out.f32\n");
        return 2;
    }
    size_t w = strtoul(argv[1], NULL, 10), h = strtoul(argv[2], NULL, 10);
    float *color = read_floats(argv[3], w * h * 3);
    float *albedo = read_floats(argv[4], w * h * 3);
    float *normal = read_floats(argv[5], w * h * 3);
    float *variance = read_floats(argv[6], w * h * 3);

    /* The colour as a renderer's RGBA framebuffer, rows stored bottom-up. */
    float *rgba = malloc(w * h * 4 * sizeof(float));
    for (size_t y = 0; y < h; y++)
        for (size_t x = 0; x < w; x++) {
            float *px = rgba + ((h - 1 - y) * w + x) * 4;
            memcpy(px, color + (y * w + x) * 3, 3 * sizeof(float));
            px[3] = 1.0f;
        }
    GsidImage color_img = {rgba + (h - 1) * w * 4, w, h, 3, -(ptrdiff_t)(w * 4), 4};
    GsidImage albedo_img = {albedo, w, h, 3, 0, 0};
    GsidImage normal_img = {normal, w, h, 3, 0, 0};
    GsidBuffer named[] = {
        {"albedo", albedo_img},
        {"normal", normal_img},
        {"variance", {variance, w, h, 3, 0, 0}},
    };

    /* The output into another RGBA framebuffer, whose alpha must survive. */
    float *out_rgba = malloc(w * h * 4 * sizeof(float));
    for (size_t i = 0; i < w * h * 4; i++) out_rgba[i] = -1.0f;
    GsidImageMut out_img = {out_rgba, w, h, 3, 0, 4};

    GsidPipeline *pipeline = NULL;
    GsidStatus status = gsid_pipeline_new("full", &pipeline);
    CHECK(status == GSID_STATUS_OK, "gsid_pipeline_new: %s", gsid_last_error());

    /* A cancel flag set before the run: cancelled, output untouched. */
    int32_t cancel = 1;
    GsidOptions options = gsid_options_default();
    options.cancel = &cancel;
    status = gsid_denoise(pipeline, &color_img, &albedo_img, &normal_img, NULL, &out_img, &options);
    CHECK(status == GSID_STATUS_CANCELLED, "cancelled run: status %d", (int)status);
    CHECK(strcmp(gsid_last_error(), "cancelled") == 0, "cancelled run: '%s'", gsid_last_error());
    CHECK(out_rgba[0] == -1.0f && out_rgba[4 * w * h - 1] == -1.0f, "cancelled run wrote output");

    /* The run itself, with the variance as an extra buffer. */
    struct Seen told = {0, 0.0f, 0};
    options = gsid_options_default();
    options.progress = on_progress;
    options.user = &told;
    status = gsid_denoise_buffers(pipeline, &color_img, named, 3, &out_img, &options);
    CHECK(status == GSID_STATUS_OK, "gsid_denoise_buffers: %s", gsid_last_error());
    CHECK(strcmp(gsid_last_error(), "") == 0, "message after success: '%s'", gsid_last_error());
    CHECK(told.calls >= 1 && told.backwards == 0 && told.last == 1.0f,
          "progress: %d calls, %d out of order, last %g", told.calls, told.backwards, told.last);
    for (size_t i = 0; i < w * h; i++) CHECK(out_rgba[4 * i + 3] == -1.0f, "alpha %zu written", i);

    float *out = malloc(w * h * 3 * sizeof(float));
    for (size_t i = 0; i < w * h; i++) memcpy(out + 3 * i, out_rgba + 4 * i, 3 * sizeof(float));
    FILE *f = fopen(argv[7], "wb");
    if (!f || fwrite(out, sizeof(float), w * h * 3, f) != w * h * 3) {
        fprintf(stderr, "cannot write %s\n", argv[7]);
        return 2;
    }
    fclose(f);

    /* Albedo and normal named give gsid_denoise's bits; the variance changes them. */
    float *plain = malloc(w * h * 3 * sizeof(float));
    float *named_plain = malloc(w * h * 3 * sizeof(float));
    GsidImageMut plain_img = {plain, w, h, 3, 0, 0};
    GsidImageMut named_plain_img = {named_plain, w, h, 3, 0, 0};
    status = gsid_denoise(pipeline, &color_img, &albedo_img, &normal_img, NULL, &plain_img, NULL);
    CHECK(status == GSID_STATUS_OK, "gsid_denoise: %s", gsid_last_error());
    status = gsid_denoise_buffers(pipeline, &color_img, named, 2, &named_plain_img, NULL);
    CHECK(status == GSID_STATUS_OK, "gsid_denoise_buffers: %s", gsid_last_error());
    CHECK(memcmp(plain, named_plain, w * h * 3 * sizeof(float)) == 0, "named buffers differ");
    CHECK(memcmp(plain, out, w * h * 3 * sizeof(float)) != 0, "the variance was not read");

    /* Bad arguments: a code and a message naming the culprit, never a crash. */
    GsidPipeline *none = NULL;
    status = gsid_pipeline_new("no-such-pipeline", &none);
    CHECK(status == GSID_STATUS_INVALID && none == NULL, "unknown pipeline: status %d", (int)status);
    CHECK(strstr(gsid_last_error(), "no-such-pipeline") != NULL, "message: '%s'", gsid_last_error());

    status = gsid_pipeline_from_toml("name = \"x\"\n[[stage]]\nkind = \"gsid\"\nwalsk = 3\n", &none);
    CHECK(status == GSID_STATUS_INVALID, "misspelt key: status %d", (int)status);
    CHECK(strstr(gsid_last_error(), "walsk") != NULL, "message: '%s'", gsid_last_error());

    status = gsid_pipeline_set(pipeline, "gsid.walks=many");
    CHECK(status == GSID_STATUS_INVALID, "bad --set: status %d", (int)status);

    GsidImage narrow = {albedo, w - 1, h, 3, 0, 0};
    status = gsid_denoise(pipeline, &color_img, &narrow, NULL, NULL, &out_img, NULL);
    CHECK(status == GSID_STATUS_INVALID, "albedo of another size: status %d", (int)status);
    CHECK(strncmp(gsid_last_error(), "buffer `albedo`: ", 17) == 0, "message: '%s'",
          gsid_last_error());

    GsidImage depth_rgb = {albedo, w, h, 3, 0, 0};
    status = gsid_denoise(pipeline, &color_img, NULL, NULL, &depth_rgb, &out_img, NULL);
    CHECK(status == GSID_STATUS_INVALID, "3-channel depth: status %d", (int)status);
    CHECK(strstr(gsid_last_error(), "depth") != NULL, "message: '%s'", gsid_last_error());

    GsidImage null_color = {NULL, w, h, 3, 0, 0};
    status = gsid_denoise(pipeline, &null_color, NULL, NULL, NULL, &out_img, NULL);
    CHECK(status == GSID_STATUS_INVALID, "null colour data: status %d", (int)status);
    CHECK(strstr(gsid_last_error(), "color") != NULL, "message: '%s'", gsid_last_error());

    status = gsid_denoise(pipeline, &color_img, NULL, NULL, NULL, NULL, NULL);
    CHECK(status == GSID_STATUS_INVALID, "null output: status %d", (int)status);
    status = gsid_denoise(NULL, &color_img, NULL, NULL, NULL, &out_img, NULL);
    CHECK(status == GSID_STATUS_INVALID, "null pipeline: status %d", (int)status);

    GsidBuffer shadow_rgb = {"shadow", albedo_img};
    status = gsid_denoise_buffers(pipeline, &color_img, &shadow_rgb, 1, &out_img, NULL);
    CHECK(status == GSID_STATUS_INVALID, "3-channel shadow: status %d", (int)status);
    CHECK(strstr(gsid_last_error(), "shadow") != NULL, "message: '%s'", gsid_last_error());

    GsidBuffer unknown = {"albdo", albedo_img};
    status = gsid_denoise_buffers(pipeline, &color_img, &unknown, 1, &out_img, NULL);
    CHECK(status == GSID_STATUS_INVALID, "unknown buffer: status %d", (int)status);
    CHECK(strstr(gsid_last_error(), "albdo") != NULL, "message: '%s'", gsid_last_error());

    GsidBuffer half = {"color_a", {color, w, h, 3, 0, 0}};
    status = gsid_denoise_buffers(pipeline, &color_img, &half, 1, &out_img, NULL);
    CHECK(status == GSID_STATUS_INVALID, "one half: status %d", (int)status);
    CHECK(strstr(gsid_last_error(), "color_b") != NULL, "message: '%s'", gsid_last_error());

    GsidOptions many = gsid_options_default();
    many.threads = 5000;
    status = gsid_denoise(pipeline, &color_img, NULL, NULL, NULL, &out_img, &many);
    CHECK(status == GSID_STATUS_INVALID, "5000 threads: status %d", (int)status);
    CHECK(strstr(gsid_last_error(), "threads") != NULL, "message: '%s'", gsid_last_error());

    gsid_pipeline_free(pipeline);
    gsid_pipeline_free(NULL);
    free(color), free(albedo), free(normal), free(variance), free(rgba), free(out_rgba), free(out);
    free(plain), free(named_plain);
    if (failures) {
        fprintf(stderr, "%d checks failed\n", failures);
        return 1;
    }
    printf("gsid %s: C API checks passed\n", gsid_version());
    return 0;
}
