/* lightmaps/image.c — OpenEXR (OpenEXRCore C API) and PNG (stb_image_write) output of
 * lightmap atlases, and an EXR reader for tests. See image.h. */
#include "lightmaps/image.h"

#include <math.h>
#include <openexr.h>
#include <stb_image_write.h> /* implementation lives in libstb: no STB_*_IMPLEMENTATION */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "runtime/half.h"

const char *const ub_ahd_exr_channel_names[UB_AHD_EXR_CHANNELS] = {
    "ambient.R", "ambient.G", "ambient.B", "dir.X", "dir.Y", "dir.Z",
    "directional.R", "directional.G", "directional.B"};

/* Largest side we write or accept (EXR allows more; a lightmap atlas never needs it). */
#define UB_IMAGE_MAX_SIDE 65536u
#define UB_IMAGE_MAX_CHANNELS 1024u

/* Routes OpenEXR's messages to our log instead of its default stderr printer. */
static void exr_log_handler(exr_const_context_t ctxt, exr_result_t code, const char *msg)
{
  void *ud = NULL;
  if (ctxt && exr_get_user_data(ctxt, &ud) == EXR_ERR_SUCCESS && ud)
    ub_log_printf((const ub_log *)ud, UB_LOG_ERROR, "openexr: %s (%s)", msg ? msg : "",
                  exr_get_error_code_as_string(code));
}

static char *tmp_path_for(const char *path)
{
  size_t n = strlen(path);
  char *t = malloc(n + 5);
  if (t) {
    memcpy(t, path, n);
    memcpy(t + n, ".tmp", 5);
  }
  return t;
}

ub_result ub_image_write_exr(const char *path, uint32_t width, uint32_t height,
                             uint32_t channels, const char *const *channel_names,
                             const float *data, const ub_log *log)
{
  if (!path || !channel_names || !data || width == 0 || height == 0 || channels == 0 ||
      width > UB_IMAGE_MAX_SIDE || height > UB_IMAGE_MAX_SIDE ||
      channels > UB_IMAGE_MAX_CHANNELS) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write EXR: bad size %ux%u×%u",
                  path ? path : "(null)", width, height, channels);
    return UB_ERR_INVALID_ARGUMENT;
  }
  for (uint32_t c = 0; c < channels; c++) {
    size_t len = channel_names[c] ? strlen(channel_names[c]) : 0;
    if (len == 0 || len > 255) {
      ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write EXR: bad name for channel %u",
                    path, c);
      return UB_ERR_INVALID_ARGUMENT;
    }
    for (uint32_t k = 0; k < c; k++)
      if (strcmp(channel_names[k], channel_names[c]) == 0) {
        ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write EXR: channel \"%s\" twice", path,
                      channel_names[c]);
        return UB_ERR_INVALID_ARGUMENT;
      }
  }

  /* Planar half copy: one contiguous plane per channel, in our channel order. */
  size_t npx = (size_t)width * height;
  uint16_t *planes = malloc(npx * channels * sizeof *planes);
  char *tmp = tmp_path_for(path);
  if (!planes || !tmp) {
    free(planes);
    free(tmp);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (uint32_t c = 0; c < channels; c++) {
    uint16_t *pl = planes + (size_t)c * npx;
    for (size_t i = 0; i < npx; i++)
      pl[i] = ub_half_from_float(data[i * channels + c]);
  }

  ub_result res = UB_OK;
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = exr_log_handler;
  init.user_data = (void *)log;
  exr_context_t ctx = NULL;
  exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
  int enc_ready = 0;
  int part = 0;
  exr_result_t rv = exr_start_write(&ctx, tmp, EXR_WRITE_FILE_DIRECTLY, &init);
  if (rv == EXR_ERR_SUCCESS)
    rv = exr_add_part(ctx, "lightmap", EXR_STORAGE_SCANLINE, &part);
  if (rv == EXR_ERR_SUCCESS)
    rv = exr_initialize_required_attr_simple(ctx, part, (int32_t)width, (int32_t)height,
                                              EXR_COMPRESSION_ZIP);
  for (uint32_t c = 0; c < channels && rv == EXR_ERR_SUCCESS; c++)
    rv = exr_add_channel(ctx, part, channel_names[c], EXR_PIXEL_HALF,
                         EXR_PERCEPTUALLY_LINEAR, 1, 1);
  if (rv == EXR_ERR_SUCCESS)
    rv = exr_write_header(ctx);
  int32_t lines = 1;
  if (rv == EXR_ERR_SUCCESS)
    rv = exr_get_scanlines_per_chunk(ctx, part, &lines);
  for (int32_t y = 0; rv == EXR_ERR_SUCCESS && y < (int32_t)height; y += lines) {
    exr_chunk_info_t cinfo;
    rv = exr_write_scanline_chunk_info(ctx, part, y, &cinfo);
    if (rv != EXR_ERR_SUCCESS)
      break;
    rv = enc_ready ? exr_encoding_update(ctx, part, &cinfo, &enc)
                   : exr_encoding_initialize(ctx, part, &cinfo, &enc);
    if (rv != EXR_ERR_SUCCESS)
      break;
    /* The library sorts channels by name: match each slot to our plane by name. */
    for (int16_t k = 0; k < enc.channel_count; k++) {
      exr_coding_channel_info_t *ch = &enc.channels[k];
      uint32_t src = 0;
      while (src < channels && strcmp(channel_names[src], ch->channel_name) != 0)
        src++;
      if (src == channels) {
        rv = EXR_ERR_INVALID_ARGUMENT;
        break;
      }
      ch->user_bytes_per_element = 2;
      ch->user_data_type = EXR_PIXEL_HALF;
      ch->user_pixel_stride = 2;
      ch->user_line_stride = (int32_t)(2 * width);
      ch->encode_from_ptr =
          (const uint8_t *)(planes + (size_t)src * npx + (size_t)cinfo.start_y * width);
    }
    if (rv != EXR_ERR_SUCCESS)
      break;
    if (!enc_ready) {
      rv = exr_encoding_choose_default_routines(ctx, part, &enc);
      if (rv != EXR_ERR_SUCCESS)
        break;
      enc_ready = 1;
    }
    rv = exr_encoding_run(ctx, part, &enc);
  }
  if (enc_ready || enc.channels)
    exr_encoding_destroy(ctx, &enc);
  if (ctx) {
    exr_result_t fr = exr_finish(&ctx);
    if (rv == EXR_ERR_SUCCESS)
      rv = fr;
  }
  if (rv != EXR_ERR_SUCCESS) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write EXR: %s", path,
                  exr_get_default_error_message(rv));
    remove(tmp);
    res = UB_ERR_IO;
  } else if (rename(tmp, path) != 0) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot rename %s into place", path, tmp);
    remove(tmp);
    res = UB_ERR_IO;
  }
  free(planes);
  free(tmp);
  return res;
}

/* ---------------------------------------------------------------------------------- */

static float srgb_encode(float x)
{
  if (!(x > 0.0f))
    return 0.0f;
  if (x >= 1.0f)
    return 1.0f;
  return x <= 0.0031308f ? 12.92f * x : 1.055f * powf(x, 1.0f / 2.4f) - 0.055f;
}

/* k-th smallest of v[0..n) (0-based), reorders v. Iterative quickselect, middle pivot. */
static float select_kth(float *v, size_t n, size_t k)
{
  size_t lo = 0, hi = n - 1;
  while (lo < hi) {
    float pivot = v[lo + (hi - lo) / 2];
    size_t i = lo, j = hi;
    while (i <= j) {
      while (v[i] < pivot)
        i++;
      while (v[j] > pivot)
        j--;
      if (i <= j) {
        float t = v[i];
        v[i] = v[j];
        v[j] = t;
        i++;
        if (j == 0)
          break;
        j--;
      }
    }
    if (k <= j)
      hi = j;
    else if (k >= i)
      lo = i;
    else
      return v[k];
  }
  return v[k];
}

/* Writes 8-bit RGB pixels to tmp, then renames it to path. */
static ub_result write_png8(const char *path, char *tmp, uint32_t width, uint32_t height,
                            const uint8_t *out, const ub_log *log)
{
  if (!stbi_write_png(tmp, (int)width, (int)height, 3, out, (int)(width * 3))) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write PNG", path);
    remove(tmp);
    return UB_ERR_IO;
  }
  if (rename(tmp, path) != 0) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot rename %s into place", path, tmp);
    remove(tmp);
    return UB_ERR_IO;
  }
  return UB_OK;
}

ub_result ub_image_write_png_false_colour(const char *path, uint32_t width, uint32_t height,
                                          const float *v, float vmin, float vmax,
                                          const ub_log *log)
{
  if (!path || !v || width == 0 || height == 0 || width > UB_IMAGE_MAX_SIDE ||
      height > UB_IMAGE_MAX_SIDE || !(vmin > 0.0f) || !(vmax > vmin)) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write PNG: bad size %ux%u or range",
                  path ? path : "(null)", width, height);
    return UB_ERR_INVALID_ARGUMENT;
  }
  /* blue → cyan → green → yellow → red at t = 0, ¼, ½, ¾, 1 */
  static const float ramp[5][3] = {{0.1f, 0.1f, 0.9f}, {0.0f, 0.8f, 0.9f}, {0.1f, 0.8f, 0.1f},
                                   {0.95f, 0.9f, 0.1f}, {0.9f, 0.1f, 0.1f}};
  size_t npx = (size_t)width * height;
  uint8_t *out = calloc(npx * 3, 1);
  char *tmp = tmp_path_for(path);
  if (!out || !tmp) {
    free(out);
    free(tmp);
    return UB_ERR_OUT_OF_MEMORY;
  }
  float lmin = logf(vmin), lspan = logf(vmax) - lmin;
  for (size_t i = 0; i < npx; i++) {
    if (!(v[i] >= 0.0f) || !isfinite(v[i]))
      continue; /* no data: black */
    float t = v[i] > vmin ? (logf(v[i]) - lmin) / lspan : 0.0f;
    t = t < 0.0f ? 0.0f : (t > 1.0f ? 1.0f : t);
    float x = t * 4.0f;
    int k = x >= 4.0f ? 3 : (int)x;
    float f = x - (float)k;
    for (int c = 0; c < 3; c++)
      out[3 * i + c] = (uint8_t)(255.0f * ((1.0f - f) * ramp[k][c] + f * ramp[k + 1][c]) + 0.5f);
  }
  ub_result res = write_png8(path, tmp, width, height, out, log);
  free(out);
  free(tmp);
  return res;
}

ub_result ub_image_write_png_preview(const char *path, uint32_t width, uint32_t height,
                                     const float *rgb, float exposure, const ub_log *log)
{
  if (!path || !rgb || width == 0 || height == 0 || width > UB_IMAGE_MAX_SIDE ||
      height > UB_IMAGE_MAX_SIDE) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot write PNG: bad size %ux%u",
                  path ? path : "(null)", width, height);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (!(exposure > 0.0f) || !isfinite(exposure))
    exposure = 1.0f;
  size_t npx = (size_t)width * height;
  float *lum = malloc(npx * sizeof *lum);
  uint8_t *out = malloc(npx * 3);
  char *tmp = tmp_path_for(path);
  if (!lum || !out || !tmp) {
    free(lum);
    free(out);
    free(tmp);
    return UB_ERR_OUT_OF_MEMORY;
  }
  size_t m = 0;
  for (size_t i = 0; i < npx; i++) {
    const float *p = rgb + 3 * i;
    if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]))
      continue;
    float l = 0.2126f * p[0] + 0.7152f * p[1] + 0.0722f * p[2];
    if (l > 0.0f)
      lum[m++] = l;
  }
  float p99 = m ? select_kth(lum, m, (size_t)((double)(m - 1) * 0.99)) : 0.0f;
  float scale = (p99 > 0.0f ? 0.9f / p99 : 1.0f) * exposure;
  for (size_t i = 0; i < npx; i++) {
    const float *p = rgb + 3 * i;
    int ok = isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]);
    for (int c = 0; c < 3; c++) {
      float v = ok ? srgb_encode(p[c] * scale) : 0.0f;
      out[3 * i + c] = (uint8_t)(v * 255.0f + 0.5f);
    }
  }
  ub_result res = write_png8(path, tmp, width, height, out, log);
  free(lum);
  free(out);
  free(tmp);
  return res;
}

/* ---------------------------------------------------------------------------------- */

void ub_image_free(ub_image *image)
{
  if (!image)
    return;
  if (image->channel_names)
    for (uint32_t c = 0; c < image->channels; c++)
      free(image->channel_names[c]);
  free(image->channel_names);
  free(image->data);
  free(image);
}

int ub_image_channel(const ub_image *image, const char *name)
{
  if (!image || !name)
    return -1;
  for (uint32_t c = 0; c < image->channels; c++)
    if (strcmp(image->channel_names[c], name) == 0)
      return (int)c;
  return -1;
}

ub_result ub_image_read_exr(const char *path, const ub_log *log, ub_image **out_image)
{
  if (!path || !out_image)
    return UB_ERR_INVALID_ARGUMENT;
  exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
  init.error_handler_fn = exr_log_handler;
  init.user_data = (void *)log;
  init.flags = EXR_CONTEXT_FLAG_DISABLE_CHUNK_RECONSTRUCTION;
  exr_context_t ctx = NULL;
  exr_result_t rv = exr_start_read(&ctx, path, &init);
  if (rv != EXR_ERR_SUCCESS) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot open EXR: %s", path,
                  exr_get_default_error_message(rv));
    if (ctx)
      exr_finish(&ctx);
    return rv == EXR_ERR_FILE_ACCESS ? UB_ERR_IO : UB_ERR_INVALID_DATA;
  }

  ub_result res = UB_OK;
  ub_image *img = NULL;
  float *planes = NULL;
  exr_decode_pipeline_t dec = EXR_DECODE_PIPELINE_INITIALIZER;
  int dec_ready = 0;
  int parts = 0;
  exr_storage_t storage;
  exr_attr_box2i_t dw;
  const exr_attr_chlist_t *chl = NULL;
  if (exr_get_count(ctx, &parts) != EXR_ERR_SUCCESS || parts < 1 ||
      exr_get_storage(ctx, 0, &storage) != EXR_ERR_SUCCESS ||
      storage != EXR_STORAGE_SCANLINE ||
      exr_get_data_window(ctx, 0, &dw) != EXR_ERR_SUCCESS ||
      exr_get_channels(ctx, 0, &chl) != EXR_ERR_SUCCESS || !chl) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: unsupported EXR (need a scanline part)", path);
    res = UB_ERR_INVALID_DATA;
    goto done;
  }
  int64_t w = (int64_t)dw.max.x - dw.min.x + 1, h = (int64_t)dw.max.y - dw.min.y + 1;
  if (w <= 0 || h <= 0 || w > UB_IMAGE_MAX_SIDE || h > UB_IMAGE_MAX_SIDE ||
      chl->num_channels <= 0 || chl->num_channels > (int)UB_IMAGE_MAX_CHANNELS) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: EXR size %lldx%lld×%d out of range", path,
                  (long long)w, (long long)h, chl->num_channels);
    res = UB_ERR_INVALID_DATA;
    goto done;
  }
  for (int c = 0; c < chl->num_channels; c++)
    if (chl->entries[c].x_sampling != 1 || chl->entries[c].y_sampling != 1) {
      ub_log_printf(log, UB_LOG_ERROR, "%s: subsampled EXR channel \"%s\" not supported",
                    path, chl->entries[c].name.str);
      res = UB_ERR_INVALID_DATA;
      goto done;
    }

  uint32_t nch = (uint32_t)chl->num_channels;
  size_t npx = (size_t)w * (size_t)h;
  img = calloc(1, sizeof *img);
  planes = malloc(npx * nch * sizeof *planes);
  if (!img || !planes || !(img->channel_names = calloc(nch, sizeof(char *))) ||
      !(img->data = malloc(npx * nch * sizeof(float)))) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto done;
  }
  img->width = (uint32_t)w;
  img->height = (uint32_t)h;
  img->channels = nch;
  for (uint32_t c = 0; c < nch; c++) {
    const char *nm = chl->entries[c].name.str;
    size_t len = nm ? strlen(nm) : 0;
    if (!(img->channel_names[c] = malloc(len + 1))) {
      res = UB_ERR_OUT_OF_MEMORY;
      goto done;
    }
    if (len)
      memcpy(img->channel_names[c], nm, len);
    img->channel_names[c][len] = '\0';
  }

  int32_t lines = 1;
  rv = exr_get_scanlines_per_chunk(ctx, 0, &lines);
  for (int64_t y = dw.min.y; rv == EXR_ERR_SUCCESS && y <= dw.max.y; y += lines) {
    exr_chunk_info_t cinfo;
    rv = exr_read_scanline_chunk_info(ctx, 0, (int)y, &cinfo);
    if (rv != EXR_ERR_SUCCESS)
      break;
    rv = dec_ready ? exr_decoding_update(ctx, 0, &cinfo, &dec)
                   : exr_decoding_initialize(ctx, 0, &cinfo, &dec);
    if (rv != EXR_ERR_SUCCESS)
      break;
    int64_t row0 = (int64_t)cinfo.start_y - dw.min.y;
    if (row0 < 0 || row0 + cinfo.height > h || cinfo.width != w ||
        dec.channel_count != (int16_t)nch) {
      rv = EXR_ERR_CORRUPT_CHUNK;
      break;
    }
    for (int16_t k = 0; k < dec.channel_count; k++) {
      exr_coding_channel_info_t *ch = &dec.channels[k];
      ch->user_bytes_per_element = 4;
      ch->user_data_type = EXR_PIXEL_FLOAT;
      ch->user_pixel_stride = 4;
      ch->user_line_stride = (int32_t)(4 * w);
      ch->decode_to_ptr = (uint8_t *)(planes + (size_t)k * npx + (size_t)row0 * (size_t)w);
    }
    if (!dec_ready) {
      rv = exr_decoding_choose_default_routines(ctx, 0, &dec);
      if (rv != EXR_ERR_SUCCESS)
        break;
      dec_ready = 1;
    }
    rv = exr_decoding_run(ctx, 0, &dec);
  }
  if (rv != EXR_ERR_SUCCESS) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot read EXR pixels: %s", path,
                  exr_get_default_error_message(rv));
    res = UB_ERR_INVALID_DATA;
    goto done;
  }
  for (size_t i = 0; i < npx; i++)
    for (uint32_t c = 0; c < nch; c++)
      img->data[i * nch + c] = planes[(size_t)c * npx + i];

done:
  if (dec_ready || dec.channels)
    exr_decoding_destroy(ctx, &dec);
  exr_finish(&ctx);
  free(planes);
  if (res != UB_OK) {
    ub_image_free(img);
    return res;
  }
  *out_image = img;
  return UB_OK;
}
