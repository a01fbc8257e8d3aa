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
  return isfinite(out[0]) && isfinite(out[1]) && isfinite(out[2]);
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
      img[4 * px + ch] = izf ? izf[3 * (size_t)t + ch] : (float)izd[3 * (size_t)t + ch];
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
