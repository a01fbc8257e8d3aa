/* GLG leak planes (see leak.h). */
#include "probes/leak.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static const int UB_TET_EDGES[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};

ub_result ub_glg_leak_build(const ub_rt *rt, uint32_t point_count, const float *points,
                            uint32_t tet_count, const uint32_t *tets, ub_glg_leak *out)
{
  (void)point_count;
  memset(out, 0, sizeof *out);
  out->plane_of = malloc(((size_t)tet_count + 1) * sizeof *out->plane_of);
  float *plane_tmp = malloc(((size_t)tet_count + 1) * 4 * sizeof(float));
  if (!out->plane_of || !plane_tmp) {
    free(plane_tmp);
    ub_glg_leak_free(out);
    return UB_ERR_OUT_OF_MEMORY;
  }
#pragma omp parallel for schedule(dynamic, 256)
  for (uint32_t t = 0; t < tet_count; t++) {
    const float *p[4];
    float cen[3] = {0, 0, 0};
    for (int i = 0; i < 4; i++) {
      p[i] = points + 3 * (size_t)tets[4 * (size_t)t + i];
      for (int a = 0; a < 3; a++)
        cen[a] += 0.25f * p[i][a];
    }
    /* Both directions of every edge: a one-sided surface blocks only from its front. */
    ub_ray rays[12];
    ub_hit hits[12];
    for (int e = 0; e < 6; e++)
      for (int dir = 0; dir < 2; dir++) {
        const float *a = p[UB_TET_EDGES[e][dir]], *b = p[UB_TET_EDGES[e][1 - dir]];
        ub_ray *r = &rays[2 * e + dir];
        memcpy(r->org, a, 3 * sizeof(float));
        for (int k = 0; k < 3; k++)
          r->dir[k] = b[k] - a[k];
        r->tnear = 0.0f;
        r->tfar = 1.0f;
      }
    ub_rt_intersect(rt, rays, 12, hits);
    float best = INFINITY;
    float plane[4] = {0, 0, 0, 0};
    for (int j = 0; j < 12; j++) {
      if (hits[j].tri == UB_RT_MISS)
        continue;
      float hp[3], n[3];
      for (int k = 0; k < 3; k++)
        hp[k] = rays[j].org[k] + hits[j].t * rays[j].dir[k];
      float len = sqrtf(hits[j].ng[0] * hits[j].ng[0] + hits[j].ng[1] * hits[j].ng[1] +
                        hits[j].ng[2] * hits[j].ng[2]);
      if (!(len > 0.0f))
        continue;
      for (int k = 0; k < 3; k++)
        n[k] = hits[j].ng[k] / len;
      float d2 = (hp[0] - cen[0]) * (hp[0] - cen[0]) + (hp[1] - cen[1]) * (hp[1] - cen[1]) +
                 (hp[2] - cen[2]) * (hp[2] - cen[2]);
      if (d2 < best) {
        best = d2;
        memcpy(plane, n, sizeof n);
        plane[3] = -(n[0] * hp[0] + n[1] * hp[1] + n[2] * hp[2]);
      }
    }
    if (isfinite(best)) {
      memcpy(plane_tmp + 4 * (size_t)t, plane, sizeof plane);
      out->plane_of[t] = 0; /* marked; compacted below */
    } else {
      out->plane_of[t] = UB_GLG_NO_PLANE;
    }
  }
  /* Compact in tet order (deterministic), one copy per distinct plane: the tets along a
   * wall all take its triangle's normal and mostly the same d to the bit (full ESTATE:
   * 434,092 tets with a plane, 3,793 distinct planes). Equal bits only: the run-time's
   * answers are those of a plane per tet. */
  uint32_t marked = 0;
  for (uint32_t t = 0; t < tet_count; t++)
    marked += out->plane_of[t] != UB_GLG_NO_PLANE;
  size_t cap = 16;
  while (cap < 2 * (size_t)marked)
    cap *= 2;
  uint32_t *slot = malloc(cap * sizeof *slot); /* plane index + 1, 0 empty */
  if (!slot) {
    free(plane_tmp);
    ub_glg_leak_free(out);
    return UB_ERR_OUT_OF_MEMORY;
  }
  memset(slot, 0, cap * sizeof *slot);
  uint32_t np = 0;
  for (uint32_t t = 0; t < tet_count; t++) {
    if (out->plane_of[t] == UB_GLG_NO_PLANE)
      continue;
    const float *pl = plane_tmp + 4 * (size_t)t;
    uint32_t w[4];
    memcpy(w, pl, sizeof w);
    uint64_t h = 0x9E3779B97F4A7C15ull;
    for (int k = 0; k < 4; k++)
      h = (h ^ w[k]) * 0xFF51AFD7ED558CCDull;
    size_t i = (size_t)(h >> 17) & (cap - 1);
    while (slot[i] && memcmp(plane_tmp + 4 * (size_t)(slot[i] - 1), w, sizeof w) != 0)
      i = (i + 1) & (cap - 1);
    if (!slot[i]) { /* new: to its place in the compact array (np ≤ t: not yet read) */
      memmove(plane_tmp + 4 * (size_t)np, pl, 4 * sizeof(float));
      slot[i] = ++np;
    }
    out->plane_of[t] = slot[i] - 1;
  }
  free(slot);
  /* a fresh right-sized copy (not realloc: GCC's -Wuse-after-free flags the fallback to
   * plane_tmp when a shrinking realloc fails) */
  out->planes = malloc(((size_t)np + 1) * 4 * sizeof(float));
  if (out->planes) {
    memcpy(out->planes, plane_tmp, (size_t)np * 4 * sizeof(float));
    free(plane_tmp);
  } else {
    out->planes = plane_tmp;
  }
  out->plane_count = np;
  out->tets = marked;
  out->rays = (uint64_t)tet_count * 12;
  return UB_OK;
}

void ub_glg_leak_free(ub_glg_leak *leak)
{
  if (!leak)
    return;
  free(leak->planes);
  free(leak->plane_of);
  leak->planes = NULL;
  leak->plane_of = NULL;
}
