/* GLG probe placement (see placement.h). */
#include "probes/placement.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>


/* Rays per candidate for the inside test, and the back-face share that means "inside". */
#define UB_INSIDE_RAYS 24
#define UB_INSIDE_BACKFACE_SHARE 0.5
/* Coarse cells per axis at most: what the fine lattice's 21-bit keys hold (2 m spacing:
 * 2,000 km). Only occupied cells and their neighbours are stored, so the count costs
 * nothing by itself. */
#define UB_GLG_MAX_CELLS_AXIS ((1u << 20) - 1u)

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

/* Coarse cell (or coarse lattice point) key, ordered as a scan of the lattice: k, then j,
 * then i (21 bits each). */
static uint64_t cell_key(uint32_t i, uint32_t j, uint32_t k)
{
  return ((uint64_t)k << 42) | ((uint64_t)j << 21) | (uint64_t)i;
}
static uint32_t cell_i(uint64_t key) { return (uint32_t)key & 0x1FFFFF; }
static uint32_t cell_j(uint64_t key) { return (uint32_t)(key >> 21) & 0x1FFFFF; }
static uint32_t cell_k(uint64_t key) { return (uint32_t)(key >> 42); }

/* Sorts v[0..n) and drops repeats; returns how many are left. */
static size_t sort_unique(uint64_t *v, size_t n)
{
  if (n < 2)
    return n;
  qsort(v, n, sizeof *v, cmp_u64);
  size_t w = 1;
  for (size_t r = 1; r < n; r++)
    if (v[r] != v[w - 1])
      v[w++] = v[r];
  return w;
}

ub_result ub_glg_place(const ub_scene *scene, const ub_rt *rt, const ub_lightmap *lm,
                       float spacing, uint32_t max_occupied, const ub_log *log,
                       ub_glg_points *out)
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
  /* Coarse cell counts; widen the spacing if the level is too large for the cap, or if it
   * has more cells holding surfaces than max_occupied (each brings up to 26 fine and 8
   * coarse candidates: an open terrain at a room's spacing would bring tens of millions). */
  float s = spacing;
  for (int a = 0; a < 3; a++)
    if (ext[a] / s > UB_GLG_MAX_CELLS_AXIS)
      s = ext[a] / UB_GLG_MAX_CELLS_AXIS;
  float step[3];
  /* Occupied coarse cells (any texel position or vertex inside), as a sorted list of cell
   * keys: a level's few occupied cells cost memory, its empty space none, so a small room
   * far out in a 20 km level keeps its spacing. */
  const size_t nsrc = (size_t)lm->texel_count + scene->vertex_count;
  uint64_t *occ = malloc((nsrc ? nsrc : 1) * sizeof *occ);
  if (!occ)
    return UB_ERR_OUT_OF_MEMORY;
  size_t nocc = 0, nocc_first = 0;
  for (;;) {
    for (int a = 0; a < 3; a++) {
      n[a] = (uint32_t)ceilf(ext[a] / s);
      if (n[a] < 1)
        n[a] = 1;
      if (n[a] > UB_GLG_MAX_CELLS_AXIS) /* ext / s rounded up past the cap */
        n[a] = UB_GLG_MAX_CELLS_AXIS;
      step[a] = ext[a] / (float)n[a]; /* cells exactly tile the bounds */
    }
    nocc = 0;
    for (size_t q = 0; q < nsrc; q++) {
      const float *p = q < lm->texel_count ? lm->texel_pos + 3 * q
                                           : scene->positions + 3 * (q - lm->texel_count);
      uint32_t c[3];
      for (int a = 0; a < 3; a++) {
        int64_t i = (int64_t)floorf((p[a] - lo[a]) / step[a]);
        c[a] = i < 0 ? 0 : (i >= (int64_t)n[a] ? n[a] - 1 : (uint32_t)i);
      }
      const uint64_t key = cell_key(c[0], c[1], c[2]);
      if (nocc == 0 || occ[nocc - 1] != key) /* neighbouring texels share cells */
        occ[nocc++] = key;
    }
    nocc = sort_unique(occ, nocc);
    if (!nocc_first)
      nocc_first = nocc;
    if (max_occupied == 0 || nocc <= max_occupied)
      break;
    /* surfaces: occupied cells go as 1/s²; a little more, so one step usually does */
    s *= 1.05f * sqrtf((float)nocc / (float)max_occupied);
  }
  if (s != spacing) {
    if (nocc_first > nocc)
      ub_log_printf(log, UB_LOG_WARNING,
                    "GLG spacing widened from %.3g m to %.3g m (%zu cells hold surfaces at "
                    "%.3g m, more than the %u allowed; now %zu)",
                    spacing, s, nocc_first, spacing, max_occupied, nocc);
    else
      ub_log_printf(log, UB_LOG_WARNING,
                    "GLG spacing widened from %.3g m to %.3g m (level is %.0f m across)",
                    spacing, s, fmaxf(ext[0], fmaxf(ext[1], ext[2])));
  }
  /* Coarse points only where they can matter: corners of cells within one cell of a
   * surface, plus the bounds' 8 corners (the hull). Empty space far from any surface gets
   * no probes. In the order of a scan of the lattice (k, then j, then i). */
  uint64_t *nearc = malloc((nocc * 27 + 1) * sizeof *nearc);
  if (!nearc) {
    free(occ);
    return UB_ERR_OUT_OF_MEMORY;
  }
  size_t nnear = 0;
  for (size_t o = 0; o < nocc; o++) {
    const uint32_t i = cell_i(occ[o]), j = cell_j(occ[o]), k = cell_k(occ[o]);
    for (int dk = -1; dk <= 1; dk++)
      for (int dj = -1; dj <= 1; dj++)
        for (int di = -1; di <= 1; di++) {
          int64_t x = (int64_t)i + di, y = (int64_t)j + dj, z = (int64_t)k + dk;
          if (x < 0 || y < 0 || z < 0 || x >= n[0] || y >= n[1] || z >= n[2])
            continue;
          nearc[nnear++] = cell_key((uint32_t)x, (uint32_t)y, (uint32_t)z);
        }
  }
  nnear = sort_unique(nearc, nnear);
  uint64_t *cand = malloc((nnear * 8 + 8) * sizeof *cand);
  if (!cand) {
    free(occ);
    free(nearc);
    return UB_ERR_OUT_OF_MEMORY;
  }
  size_t nc = 0;
  for (size_t q = 0; q < nnear; q++) /* a near cell's 8 corners are coarse points */
    for (int c = 0; c < 8; c++)
      cand[nc++] = cell_key(cell_i(nearc[q]) + (c & 1), cell_j(nearc[q]) + ((c >> 1) & 1),
                            cell_k(nearc[q]) + ((c >> 2) & 1));
  for (int c = 0; c < 8; c++)
    cand[nc++] = cell_key(c & 1 ? n[0] : 0, c & 2 ? n[1] : 0, c & 4 ? n[2] : 0);
  free(nearc);
  nc = sort_unique(cand, nc);
  /* Candidate keys on the fine lattice (2× resolution): the coarse points, then the fine
   * points inside occupied cells, ascending. */
  size_t nk = nc + nocc * 26;
  uint64_t *keys = malloc((nk ? nk : 1) * sizeof *keys);
  if (!keys) {
    free(occ);
    free(cand);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (size_t q = 0; q < nc; q++)
    keys[q] = key_of(2 * cell_i(cand[q]), 2 * cell_j(cand[q]), 2 * cell_k(cand[q]));
  free(cand);
  const size_t ncoarse = nc;
  nk = nc;
  for (size_t o = 0; o < nocc; o++) {
    const uint32_t i = cell_i(occ[o]), j = cell_j(occ[o]), k = cell_k(occ[o]);
    for (uint32_t dk = 0; dk < 3; dk++)
      for (uint32_t dj = 0; dj < 3; dj++)
        for (uint32_t di = 0; di < 3; di++)
          if ((di | dj | dk) & 1)
            keys[nk++] = key_of(2 * i + di, 2 * j + dj, 2 * k + dk);
  }
  free(occ);
  nk = ncoarse + sort_unique(keys + ncoarse, nk - ncoarse);

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
