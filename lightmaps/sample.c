/* Reading stored lighting and texel footprints (see lightmap.h). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "lightmaps/lightmap.h"
#include "runtime/texel_links.h"

void ub_lightmap_image_sample(const ub_lightmap *lm, const float *img, uint32_t atlas, float u,
                              float v, float out[3])
{
  const ub_atlas *a = &lm->atlases[atlas];
  float x = u * (float)a->width - 0.5f, y = v * (float)a->height - 0.5f;
  float fx = floorf(x), fy = floorf(y);
  float tx = x - fx, ty = y - fy;
  int x0 = (int)fx, y0 = (int)fy;
  double sum[3] = {0, 0, 0}, wsum = 0.0;
  /* not across a wall standing between texels (runtime/texel_links.h) */
  unsigned keep = ub_texel_links_keep(a->link, a->width, a->height, x0, y0, tx, ty);
  for (int j = 0; j < 2; j++)
    for (int i = 0; i < 2; i++) {
      if (!(keep & (1u << (i + 2 * j))))
        continue;
      int xi = x0 + i, yj = y0 + j;
      xi = xi < 0 ? 0 : (xi >= (int)a->width ? (int)a->width - 1 : xi);
      yj = yj < 0 ? 0 : (yj >= (int)a->height ? (int)a->height - 1 : yj);
      float w = (i ? tx : 1.0f - tx) * (j ? ty : 1.0f - ty);
      const float *p = img + 4 * ((size_t)yj * a->width + (size_t)xi);
      w *= p[3];
      sum[0] += w * p[0];
      sum[1] += w * p[1];
      sum[2] += w * p[2];
      wsum += w;
    }
  for (int k = 0; k < 3; k++)
    out[k] = wsum > 1e-6 ? (float)(sum[k] / wsum) : 0.0f;
}

int ub_lightmap_texel_point(const ub_scene *s, const ub_lightmap *lm, uint32_t t, float fx,
                            float fy, float out[3])
{
  uint32_t tri = lm->texel_tri[t];
  const ub_atlas *at = &lm->atlases[lm->texel_atlas[t]];
  const float *uv = lm->tri_uv + 6 * (size_t)tri;
  float qu = ((float)lm->texel_xy[2 * t] + fx) / (float)at->width;
  float qv = ((float)lm->texel_xy[2 * t + 1] + fy) / (float)at->height;
  float e1u = uv[2] - uv[0], e1v = uv[3] - uv[1], e2u = uv[4] - uv[0], e2v = uv[5] - uv[1];
  float det = e1u * e2v - e2u * e1v;
  if (!(fabsf(det) > 1e-20f))
    return 0;
  float du = qu - uv[0], dv = qv - uv[1];
  float b1 = (du * e2v - e2u * dv) / det, b2 = (e1u * dv - du * e1v) / det;
  const float *p0 = s->positions + 3 * s->indices[3 * tri];
  const float *p1 = s->positions + 3 * s->indices[3 * tri + 1];
  const float *p2 = s->positions + 3 * s->indices[3 * tri + 2];
  for (int k = 0; k < 3; k++)
    out[k] = p0[k] + b1 * (p1[k] - p0[k]) + b2 * (p2[k] - p0[k]);
  if (!(isfinite(out[0]) && isfinite(out[1]) && isfinite(out[2])))
    return 0;
  const float tol = -1e-5f;
  return b1 >= tol && b2 >= tol && 1.0f - b1 - b2 >= tol ? 1 : 2;
}

int ub_lightmap_image_fill(const ub_lightmap *lm, uint32_t atlas, const float *izf,
                           const double *izd, float *img)
{
  const ub_atlas *at = &lm->atlases[atlas];
  size_t npx = (size_t)at->width * at->height;
  uint8_t *cov = calloc(npx ? npx : 1, 1);
  memset(img, 0, npx * 4 * sizeof(float));
  for (uint32_t i = 0; i < at->texel_count; i++) {
    uint32_t t = at->first_texel + i;
    size_t px = (size_t)lm->texel_xy[2 * t + 1] * at->width + lm->texel_xy[2 * t];
    for (int ch = 0; ch < 3; ch++)
      img[4 * px + ch] = izf ? izf[3 * (size_t)t + ch]
                             : izd ? (float)izd[3 * (size_t)t + ch] : 0.0f;
    img[4 * px + 3] = 1.0f;
    if (cov)
      cov[px] = 1;
  }
  int ok = cov != NULL;
  if (ok)
    ub_lightmap_dilate(img, cov, at->width, at->height, 4, 2);
  free(cov);
  return ok;
}

/* Sparse refills (lightmap.h). The dilation (dilate.c, 2 passes): an uncovered pixel
 * takes the mean of its filled 8-neighbours (covered, or filled by the pass before),
 * summed in (dy, dx) order, times 1/count. Texels outside act are 0, so a pixel of ring
 * 1 with no act texel around, or of ring 2 with no recomputed ring-1 pixel around, is
 * 0 as in the zero-light fill; the others are recomputed with every neighbour (zeros
 * included) in the same order: the same float operations. */
static void sparse_ring(const ub_atlas *at, const uint8_t *level, uint8_t ring,
                        const uint32_t *px, uint32_t n, float *img)
{
  /* A ring's pixels are distinct and read only lower levels: on every thread. */
#pragma omp parallel for schedule(static) if (n > 4096)
  for (uint32_t k = 0; k < n; k++) {
    uint32_t i = px[k], x = i % at->width, y = i / at->width;
    float sum[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    uint32_t cnt = 0;
    for (int dy = -1; dy <= 1; dy++) {
      int64_t yy = (int64_t)y + dy;
      if (yy < 0 || yy >= (int64_t)at->height)
        continue;
      for (int dx = -1; dx <= 1; dx++) {
        int64_t xx = (int64_t)x + dx;
        if ((dx == 0 && dy == 0) || xx < 0 || xx >= (int64_t)at->width)
          continue;
        size_t j = (size_t)yy * at->width + (size_t)xx;
        if (level[j] >= ring)
          continue;
        cnt++;
        for (int c = 0; c < 4; c++)
          sum[c] += img[4 * j + c];
      }
    }
    if (cnt == 0)
      continue;
    float inv = 1.0f / (float)cnt;
    for (int c = 0; c < 3; c++) /* the coverage channel is the zero-light fill's */
      img[4 * (size_t)i + c] = sum[c] * inv;
  }
}

int ub_lightmap_sparse_base(const ub_lightmap *lm, uint32_t atlas, float *img, uint8_t *level)
{
  const ub_atlas *at = &lm->atlases[atlas];
  size_t npx = (size_t)at->width * at->height;
  /* the zero-light fill: coverage and the dilated rings */
  if (!ub_lightmap_image_fill(lm, atlas, NULL, NULL, img))
    return 0;
  memset(level, 1, npx);
  for (uint32_t i = 0; i < at->texel_count; i++) {
    uint32_t t = at->first_texel + i;
    level[(size_t)lm->texel_xy[2 * t + 1] * at->width + lm->texel_xy[2 * t]] = 0;
  }
  ub_lightmap_dilate_levels(level, at->width, at->height, 2);
  return 1;
}

int ub_lightmap_sparse_init(const ub_lightmap *lm, uint32_t atlas, const uint32_t *act,
                            uint32_t n, const float *base_img, const uint8_t *base_level,
                            float *img, ub_lightmap_sparse *sp)
{
  memset(sp, 0, sizeof *sp);
  const ub_atlas *at = &lm->atlases[atlas];
  size_t npx = (size_t)at->width * at->height;
  sp->atlas = atlas;
  uint32_t lo = at->first_texel, hi = at->first_texel + at->texel_count;
  for (uint32_t i = 0; i < n; i++)
    sp->n0 += act[i] >= lo && act[i] < hi;
  sp->t0 = malloc(((size_t)sp->n0 + 1) * sizeof *sp->t0);
  uint8_t *mark = calloc(npx ? npx : 1, 1);
  int ok = sp->t0 && mark;
  if (ok && base_level) {
    if (base_img) /* else img holds the zero-light fill already */
      memcpy(img, base_img, npx * 4 * sizeof *img);
    sp->level = (uint8_t *)base_level;
  } else if (ok) {
    sp->level = malloc(npx ? npx : 1);
    sp->own_level = 1;
    ok = sp->level && ub_lightmap_sparse_base(lm, atlas, img, sp->level);
  }
  if (!ok) {
    free(mark);
    ub_lightmap_sparse_free(sp);
    return 0;
  }
  /* ring-1 pixels next to an act texel, ring-2 pixels next to those */
  size_t cap = 1 + (size_t)sp->n0 * 9, cap2 = cap * 9;
  sp->px = malloc((sp->n0 + cap + cap2) * sizeof *sp->px);
  if (!sp->px) {
    free(mark);
    ub_lightmap_sparse_free(sp);
    return 0;
  }
  uint32_t k = 0;
  for (uint32_t i = 0; i < n; i++)
    if (act[i] >= lo && act[i] < hi) {
      uint32_t t = act[i];
      sp->t0[k] = t;
      sp->px[k++] = lm->texel_xy[2 * t + 1] * at->width + lm->texel_xy[2 * t];
    }
  for (uint8_t ring = 1; ring <= 2; ring++) {
    uint32_t from = ring == 1 ? 0 : sp->n0, to = ring == 1 ? sp->n0 : sp->n0 + sp->n1, m = 0;
    for (uint32_t q = from; q < to; q++) {
      uint32_t x = sp->px[q] % at->width, y = sp->px[q] / at->width;
      for (int dy = -1; dy <= 1; dy++)
        for (int dx = -1; dx <= 1; dx++) {
          int64_t xx = (int64_t)x + dx, yy = (int64_t)y + dy;
          if (!(dx || dy) || xx < 0 || yy < 0 || xx >= at->width || yy >= at->height)
            continue;
          size_t j = (size_t)yy * at->width + (size_t)xx;
          if (sp->level[j] == ring && !mark[j]) {
            mark[j] = 1;
            sp->px[to + m++] = (uint32_t)j;
          }
        }
    }
    if (ring == 1)
      sp->n1 = m;
    else
      sp->n2 = m;
  }
  free(mark);
  return 1;
}

void ub_lightmap_sparse_fill(const ub_lightmap *lm, const ub_lightmap_sparse *sp,
                             const double *izd, float *img)
{
  const ub_atlas *at = &lm->atlases[sp->atlas];
#pragma omp parallel for schedule(static) if (sp->n0 > 4096)
  for (uint32_t k = 0; k < sp->n0; k++)
    for (int c = 0; c < 3; c++)
      img[4 * (size_t)sp->px[k] + c] = (float)izd[3 * (size_t)sp->t0[k] + c];
  sparse_ring(at, sp->level, 1, sp->px + sp->n0, sp->n1, img);
  sparse_ring(at, sp->level, 2, sp->px + sp->n0 + sp->n1, sp->n2, img);
}

void ub_lightmap_sparse_restore(const ub_lightmap_sparse *sp, const float *base_img, float *img)
{
  size_t n = (size_t)sp->n0 + sp->n1 + sp->n2;
  for (size_t k = 0; k < n; k++)
    memcpy(img + 4 * (size_t)sp->px[k], base_img + 4 * (size_t)sp->px[k], 4 * sizeof *img);
}

void ub_lightmap_sparse_free(ub_lightmap_sparse *sp)
{
  if (!sp)
    return;
  free(sp->t0);
  free(sp->px);
  if (sp->own_level)
    free(sp->level);
  memset(sp, 0, sizeof *sp);
}
