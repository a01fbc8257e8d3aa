/* GLG probe placement (see placement.h). */
#include "probes/placement.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>


/* Rays per candidate for the inside test, and the back-face share that means "inside". */
#define UB_INSIDE_RAYS 24
#define UB_INSIDE_BACKFACE_SHARE 0.5
/* Coarse cells per axis at most: keeps a 20 km level from allocating a continent. */
#define UB_GLG_MAX_CELLS_AXIS 1024

static int cmp_u64(const void *a, const void *b)
{
  uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
  return x < y ? -1 : x > y;
}

/* Fine-lattice key: 21 bits per axis. */
static uint64_t key_of(uint32_t i, uint32_t j, uint32_t k)
{
  return ((uint64_t)i << 42) | ((uint64_t)j << 21) | (uint64_t)k;
}

ub_result ub_glg_place(const ub_scene *scene, const ub_rt *rt, const ub_lightmap *lm,
                       float spacing, const ub_log *log, ub_glg_points *out)
{
  memset(out, 0, sizeof *out);
  if (!(spacing > 0.0f))
    spacing = 2.0f;
  float lo[3], ext[3];
  uint32_t n[3];
  float pad = 0.05f * spacing;
  for (int a = 0; a < 3; a++) {
    lo[a] = scene->bounds_min[a] - pad;
    ext[a] = scene->bounds_max[a] + pad - lo[a];
  }
  /* Coarse cell counts; widen the spacing if the level is too large for the cap. */
  float s = spacing;
  for (int a = 0; a < 3; a++)
    if (ext[a] / s > UB_GLG_MAX_CELLS_AXIS)
      s = ext[a] / UB_GLG_MAX_CELLS_AXIS;
  if (s != spacing)
    ub_log_printf(log, UB_LOG_WARNING, "GLG spacing widened from %.3g m to %.3g m (level is %.0f m across)",
                  spacing, s, fmaxf(ext[0], fmaxf(ext[1], ext[2])));
  float step[3];
  for (int a = 0; a < 3; a++) {
    n[a] = (uint32_t)ceilf(ext[a] / s);
    if (n[a] < 1)
      n[a] = 1;
    step[a] = ext[a] / (float)n[a]; /* cells exactly tile the bounds */
  }
  /* Occupied coarse cells: any texel position or vertex inside. */
  size_t ncells = (size_t)n[0] * n[1] * n[2];
  uint8_t *occ = calloc(ncells, 1);
  if (!occ)
    return UB_ERR_OUT_OF_MEMORY;
#define CELL_OF(p, out_idx)                                                                \
  do {                                                                                     \
    uint32_t c_[3];                                                                        \
    for (int a_ = 0; a_ < 3; a_++) {                                                       \
      float f_ = ((p)[a_] - lo[a_]) / step[a_];                                            \
      int i_ = (int)floorf(f_);                                                            \
      c_[a_] = i_ < 0 ? 0 : ((uint32_t)i_ >= n[a_] ? n[a_] - 1 : (uint32_t)i_);            \
    }                                                                                      \
    (out_idx) = ((size_t)c_[2] * n[1] + c_[1]) * n[0] + c_[0];                             \
  } while (0)
  for (uint32_t t = 0; t < lm->texel_count; t++) {
    size_t ci;
    CELL_OF(lm->texel_pos + 3 * (size_t)t, ci);
    occ[ci] = 1;
  }
  for (uint32_t v = 0; v < scene->vertex_count; v++) {
    size_t ci;
    CELL_OF(scene->positions + 3 * (size_t)v, ci);
    occ[ci] = 1;
  }
#undef CELL_OF
  /* Candidate keys on the fine lattice (2× resolution): coarse points everywhere, fine
   * points inside occupied cells. */
  size_t cap = ((size_t)n[0] + 1) * (n[1] + 1) * (n[2] + 1) + 1;
  size_t nocc = 0;
  for (size_t ci = 0; ci < ncells; ci++)
    nocc += occ[ci];
  cap += nocc * 27;
  uint64_t *keys = malloc(cap * sizeof *keys);
  if (!keys) {
    free(occ);
    return UB_ERR_OUT_OF_MEMORY;
  }
  /* Coarse points only where they can matter: corners of cells within one cell of a
   * surface, plus the bounds' 8 corners (the hull). Empty space far from any surface (a
   * small room in a 20 km level) gets no probes. */
  uint8_t *nearc = calloc(ncells, 1);
  if (!nearc) {
    free(occ);
    free(keys);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (uint32_t k = 0; k < n[2]; k++)
    for (uint32_t j = 0; j < n[1]; j++)
      for (uint32_t i = 0; i < n[0]; i++) {
        if (!occ[((size_t)k * n[1] + j) * n[0] + i])
          continue;
        for (int dk = -1; dk <= 1; dk++)
          for (int dj = -1; dj <= 1; dj++)
            for (int di = -1; di <= 1; di++) {
              int64_t a = (int64_t)i + di, b = (int64_t)j + dj, cc = (int64_t)k + dk;
              if (a < 0 || b < 0 || cc < 0 || a >= n[0] || b >= n[1] || cc >= n[2])
                continue;
              nearc[((size_t)cc * n[1] + (size_t)b) * n[0] + (size_t)a] = 1;
            }
      }
  size_t nk = 0;
  for (uint32_t k = 0; k <= n[2]; k++)
    for (uint32_t j = 0; j <= n[1]; j++)
      for (uint32_t i = 0; i <= n[0]; i++) {
        int keep = (i == 0 || i == n[0]) && (j == 0 || j == n[1]) && (k == 0 || k == n[2]);
        for (int c = 0; c < 8 && !keep; c++) {
          int64_t a = (int64_t)i - (c & 1), b = (int64_t)j - ((c >> 1) & 1),
                  cc = (int64_t)k - ((c >> 2) & 1);
          if (a >= 0 && b >= 0 && cc >= 0 && a < n[0] && b < n[1] && cc < n[2])
            keep = nearc[((size_t)cc * n[1] + (size_t)b) * n[0] + (size_t)a];
        }
        if (keep)
          keys[nk++] = key_of(2 * i, 2 * j, 2 * k);
      }
  free(nearc);
  size_t ncoarse = nk;
  for (uint32_t k = 0; k < n[2]; k++)
    for (uint32_t j = 0; j < n[1]; j++)
      for (uint32_t i = 0; i < n[0]; i++) {
        if (!occ[((size_t)k * n[1] + j) * n[0] + i])
          continue;
        for (uint32_t dk = 0; dk < 3; dk++)
          for (uint32_t dj = 0; dj < 3; dj++)
            for (uint32_t di = 0; di < 3; di++)
              if ((di | dj | dk) & 1)
                keys[nk++] = key_of(2 * i + di, 2 * j + dj, 2 * k + dk);
      }
  free(occ);
  qsort(keys + ncoarse, nk - ncoarse, sizeof *keys, cmp_u64);
  size_t w = ncoarse;
  for (size_t r = ncoarse; r < nk; r++)
    if (w == ncoarse || keys[r] != keys[w - 1])
      keys[w++] = keys[r];
  nk = w;

  float *pos = malloc(nk * 3 * sizeof *pos + 1);
  uint8_t *keep = malloc(nk + 1);
  if (!pos || !keep) {
    free(keys);
    free(pos);
    free(keep);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (size_t c = 0; c < nk; c++) {
    uint64_t key = keys[c];
    uint32_t fi = (uint32_t)(key >> 42), fj = (uint32_t)(key >> 21) & 0x1FFFFF,
             fk = (uint32_t)key & 0x1FFFFF;
    pos[3 * c] = lo[0] + 0.5f * step[0] * fi;
    pos[3 * c + 1] = lo[1] + 0.5f * step[1] * fj;
    pos[3 * c + 2] = lo[2] + 0.5f * step[2] * fk;
  }
  /* Inside test: rays in a fixed set of directions; mostly back faces = inside. The 8
   * corners of the bounds are always kept so the hull covers the level. */
  uint64_t inside = 0;
#pragma omp parallel for schedule(dynamic, 256) reduction(+ : inside)
  for (size_t c = 0; c < nk; c++) {
    uint64_t key = keys[c];
    uint32_t fi = (uint32_t)(key >> 42), fj = (uint32_t)(key >> 21) & 0x1FFFFF,
             fk = (uint32_t)key & 0x1FFFFF;
    int corner = (fi == 0 || fi == 2 * n[0]) && (fj == 0 || fj == 2 * n[1]) &&
                 (fk == 0 || fk == 2 * n[2]);
    keep[c] = 1;
    if (corner)
      continue;
    ub_ray rays[UB_INSIDE_RAYS];
    ub_hit hits[UB_INSIDE_RAYS];
    for (int r = 0; r < UB_INSIDE_RAYS; r++) {
      /* Spherical Fibonacci directions: even coverage, no randomness needed. */
      float z = 1.0f - (2.0f * r + 1.0f) / UB_INSIDE_RAYS;
      float rr = sqrtf(fmaxf(0.0f, 1.0f - z * z)), phi = 2.39996323f * r;
      memcpy(rays[r].org, pos + 3 * c, 3 * sizeof(float));
      rays[r].dir[0] = rr * cosf(phi);
      rays[r].dir[1] = z;
      rays[r].dir[2] = rr * sinf(phi);
      rays[r].tnear = 0.0f;
      rays[r].tfar = INFINITY;
    }
    ub_rt_intersect(rt, rays, UB_INSIDE_RAYS, hits);
    int hit = 0, back = 0;
    for (int r = 0; r < UB_INSIDE_RAYS; r++) {
      if (hits[r].tri == UB_RT_MISS)
        continue;
      hit++;
      const float *g = hits[r].ng;
      if (g[0] * rays[r].dir[0] + g[1] * rays[r].dir[1] + g[2] * rays[r].dir[2] > 0.0f)
        back++;
    }
    if (hit > 0 && back > UB_INSIDE_BACKFACE_SHARE * hit) {
      keep[c] = 0;
      inside++;
    }
  }
  size_t kept = 0;
  uint32_t kept_coarse = 0;
  for (size_t c = 0; c < nk; c++) {
    if (!keep[c])
      continue;
    memmove(pos + 3 * kept, pos + 3 * c, 3 * sizeof(float));
    kept_coarse += c < ncoarse;
    kept++;
  }
  free(keys);
  free(keep);
  out->count = (uint32_t)kept;
  out->pos = pos;
  out->coarse = kept_coarse;
  out->fine = (uint32_t)(kept - kept_coarse);
  out->rejected_inside = (uint32_t)inside;
  out->spacing = s;
  return UB_OK;
}

void ub_glg_points_free(ub_glg_points *pts)
{
  if (!pts)
    return;
  free(pts->pos);
  pts->pos = NULL;
  pts->count = 0;
}
