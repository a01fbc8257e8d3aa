/* lightmaps/dilate.c — grows covered texels into the empty padding around charts, ring by
 * ring, so bilinear filtering at chart borders reads plausible values instead of black.
 * Each pass reads a snapshot of the previous ring: the result does not depend on the scan
 * order or the thread count. */
#include "lightmaps/lightmap.h"

#include <stdlib.h>
#include <string.h>

void ub_lightmap_dilate(float *image, const uint8_t *covered, uint32_t width, uint32_t height,
                        uint32_t channels, uint32_t passes)
{
  if (!image || !covered || width == 0 || height == 0 || channels == 0 || passes == 0)
    return;
  size_t npx = (size_t)width * height;
  size_t nval = npx * channels;
  float *src = malloc(nval * sizeof *src);
  uint8_t *filled = malloc(npx);
  uint8_t *filled_next = malloc(npx);
  if (!src || !filled || !filled_next) {
    /* Out of memory: leave the image as it is (dilation is cosmetic). */
    free(src);
    free(filled);
    free(filled_next);
    return;
  }
  for (size_t i = 0; i < npx; i++)
    filled[i] = covered[i] ? 1 : 0;

  for (uint32_t pass = 0; pass < passes; pass++) {
    memcpy(src, image, nval * sizeof *src);
    memcpy(filled_next, filled, npx);
    int64_t grown = 0;
#pragma omp parallel for schedule(static) reduction(+ : grown)
    for (int64_t y = 0; y < (int64_t)height; y++) {
      float sum[64];
      for (uint32_t x = 0; x < width; x++) {
        size_t i = (size_t)y * width + x;
        if (filled[i])
          continue;
        uint32_t cnt = 0;
        uint32_t cmax = channels < 64 ? channels : 64;
        for (uint32_t c = 0; c < cmax; c++)
          sum[c] = 0.0f;
        for (int dy = -1; dy <= 1; dy++) {
          int64_t yy = y + dy;
          if (yy < 0 || yy >= (int64_t)height)
            continue;
          for (int dx = -1; dx <= 1; dx++) {
            int64_t xx = (int64_t)x + dx;
            if ((dx == 0 && dy == 0) || xx < 0 || xx >= (int64_t)width)
              continue;
            size_t j = (size_t)yy * width + (size_t)xx;
            if (!filled[j])
              continue;
            cnt++;
            for (uint32_t c = 0; c < cmax; c++)
              sum[c] += src[j * channels + c];
          }
        }
        if (cnt == 0)
          continue;
        float inv = 1.0f / (float)cnt;
        for (uint32_t c = 0; c < cmax; c++)
          image[i * channels + c] = sum[c] * inv;
        /* More than 64 channels: the rest in a second, slower sweep. */
        for (uint32_t c = cmax; c < channels; c++) {
          float s = 0.0f;
          for (int dy = -1; dy <= 1; dy++) {
            int64_t yy = y + dy;
            if (yy < 0 || yy >= (int64_t)height)
              continue;
            for (int dx = -1; dx <= 1; dx++) {
              int64_t xx = (int64_t)x + dx;
              if ((dx == 0 && dy == 0) || xx < 0 || xx >= (int64_t)width)
                continue;
              size_t j = (size_t)yy * width + (size_t)xx;
              if (filled[j])
                s += src[j * channels + c];
            }
          }
          image[i * channels + c] = s * inv;
        }
        filled_next[i] = 1;
        grown++;
      }
    }
    memcpy(filled, filled_next, npx);
    if (grown == 0)
      break;
  }
  free(src);
  free(filled);
  free(filled_next);
}

void ub_lightmap_dilate_levels(uint8_t *level, uint32_t width, uint32_t height, uint8_t rings)
{
  const uint8_t far = (uint8_t)(rings + 1), marked = (uint8_t)(rings + 2);
  size_t npx = (size_t)width * height;
  for (size_t i = 0; i < npx; i++)
    level[i] = level[i] ? far : 0;
  for (uint8_t ring = 1; ring <= rings; ring++) {
    for (size_t i = 0; i < npx; i++) {
      if (level[i] != far)
        continue;
      uint32_t x = (uint32_t)(i % width), y = (uint32_t)(i / width);
      int near = 0;
      for (int dy = -1; dy <= 1 && !near; dy++)
        for (int dx = -1; dx <= 1 && !near; dx++) {
          int64_t xx = (int64_t)x + dx, yy = (int64_t)y + dy;
          if ((dx || dy) && xx >= 0 && yy >= 0 && xx < width && yy < height)
            near = level[(size_t)yy * width + (size_t)xx] < ring;
        }
      if (near)
        level[i] = marked; /* a ring grows from the rings before it only */
    }
    for (size_t i = 0; i < npx; i++)
      if (level[i] == marked)
        level[i] = ring;
  }
}
