/* lightmaps/image.h — writing lightmap atlases: OpenEXR (half float, named channels) for
 * the data, an sRGB PNG for a quick look; an EXR reader for tests and tools.
 *
 * Pixel layout everywhere: row-major, row 0 at the top (the lightmap UV v = 0 side, the
 * EXR INCREASING_Y order), channels interleaved: data[(y*width + x)*channels + c].
 * Files are written to PATH.tmp and renamed into place, so a failed write never leaves a
 * truncated file under the final name.
 * Lifecycle: ub_image_read_exr allocates a ub_image; ub_image_free releases it (NULL-safe).
 * Thread safety: functions share no state; each call may run on any thread.
 */
#ifndef UBAKE_LIGHTMAPS_IMAGE_H
#define UBAKE_LIGHTMAPS_IMAGE_H

#include <stdint.h>

#include "ubake/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/* AHD atlas channels (DESIGN: "lightmaps as OpenEXR"), in this order in the data:
 * ambient.R/G/B  C_a, W/m²;
 * dir.X/Y/Z      unit direction d, world space (Y-up);
 * directional.R/G/B  C_d, W/m².
 * E(n) = C_a + C_d · max(0, d·n). */
#define UB_AHD_EXR_CHANNELS 9
extern const char *const ub_ahd_exr_channel_names[UB_AHD_EXR_CHANNELS];

/* Writes width × height × channels floats as HALF channels named channel_names[c]
 * (non-empty, unique, ≤ 255 bytes each; EXR stores them sorted, readers map by name).
 * ZIP compressed. Values beyond the half range become ±Inf: clamp before if that matters.
 * Errors: UB_ERR_INVALID_ARGUMENT (sizes, names), UB_ERR_IO, UB_ERR_OUT_OF_MEMORY. */
ub_result ub_image_write_exr(const char *path, uint32_t width, uint32_t height,
                             uint32_t channels, const char *const *channel_names,
                             const float *data, const ub_log *log);

/* 8-bit sRGB PNG preview of a linear RGB image (width × height × 3 floats, W/m² or any
 * linear unit). Tone map: scale so the 99th percentile of the luminance of the non-zero
 * pixels maps to 0.9, times exposure (1 = automatic only; ≤ 0 or non-finite taken as 1),
 * clamp to [0,1], sRGB transfer curve. NaN/Inf pixels are written black. */
ub_result ub_image_write_png_preview(const char *path, uint32_t width, uint32_t height,
                                     const float *rgb, float exposure, const ub_log *log);

/* 8-bit false-colour PNG of a scalar image (width × height floats): log scale from vmin
 * (blue) through cyan, green, yellow to vmax (red), clamped at both ends; negative, NaN or
 * Inf pixels (no data) are black. Requires 0 < vmin < vmax. */
ub_result ub_image_write_png_false_colour(const char *path, uint32_t width, uint32_t height,
                                          const float *v, float vmin, float vmax,
                                          const ub_log *log);

typedef struct ub_image {
  uint32_t width, height, channels;
  char **channel_names; /* channels names, in the file's (sorted) order */
  float *data;          /* width × height × channels, interleaved in channel_names order */
} ub_image;

/* Reads a single-part scanline EXR (HALF, FLOAT or UINT channels, no subsampling) into
 * floats. Hostile input: sizes are checked before allocating; errors name the file. */
ub_result ub_image_read_exr(const char *path, const ub_log *log, ub_image **out_image);
void ub_image_free(ub_image *image);
/* Index of the channel called name, -1 if absent. */
int ub_image_channel(const ub_image *image, const char *name);

#ifdef __cplusplus
}
#endif
#endif
