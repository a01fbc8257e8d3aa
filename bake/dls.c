/* Dynamic light set passes and their sparse records (see dls.h). */
#include "bake/dls.h"

#include "probes/llg.h"
#include "runtime/texel_links.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now_s(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

uint32_t ub_dls_texel_pixel(const ub_lightmap *lm, uint32_t texel)
{
  uint32_t a = lm->texel_atlas[texel];
  uint64_t base = 0;
  for (uint32_t b = 0; b < a; b++)
    base += (uint64_t)lm->atlases[b].width * lm->atlases[b].height;
  return (uint32_t)(base + (uint64_t)lm->texel_xy[2 * texel + 1] * lm->atlases[a].width +
                    lm->texel_xy[2 * texel]);
}

void ub_dls_stats_free(ub_dls_stats *st)
{
  if (!st)
    return;
  free(st->sets);
  st->sets = NULL;
}

void ub_dls_records_free(ub_bakefile_record *records, uint32_t count)
{
  if (!records)
    return;
  for (uint32_t i = 0; i < count; i++) {
    free(records[i].texel_index);
    free(records[i].texel_sh);
    free(records[i].probe_index);
    free(records[i].probe_sh);
    free(records[i].llg_probe_index);
    free(records[i].llg_probe_sh);
  }
  free(records);
}

/* (pixel, texel) pairs ordered by pixel. */
static int pixel_pair_cmp(const void *pa, const void *pb)
{
  const uint64_t x = *(const uint64_t *)pa, y = *(const uint64_t *)pb;
  return (x > y) - (x < y);
}

/* The set's texel SH at the kept texels' atlas pixels, ascending, rows that are all zero
 * left out. No padding: the run-time shows each dilated padding pixel as the covered
 * texel it copies (ub_runtime_texel_source), so padding rows would never be read. */
static ub_result texel_record(const ub_lightmap *lm, const uint32_t *kept, uint32_t nkept,
                              const float *sh, int rows, ub_bakefile_record *rec)
{
  uint64_t *pair = malloc((nkept ? nkept : 1) * sizeof *pair);
  uint32_t *idx = malloc((nkept ? nkept : 1) * sizeof *idx);
  float *val = malloc((nkept ? nkept : 1) * 12 * sizeof *val);
  if (!pair || !idx || !val) {
    free(pair);
    free(idx);
    free(val);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (uint32_t i = 0; i < nkept; i++)
    pair[i] = (uint64_t)ub_dls_texel_pixel(lm, kept[i]) << 32 | (rows ? i : kept[i]);
  qsort(pair, nkept, sizeof *pair, pixel_pair_cmp);
  size_t n = 0;
  for (uint32_t i = 0; i < nkept; i++) {
    const float *v = sh + 12 * (size_t)(uint32_t)pair[i];
    int nz = 0;
    for (int k = 0; k < 12; k++)
      nz |= v[k] != 0.0f;
    if (!nz)
      continue;
    idx[n] = (uint32_t)(pair[i] >> 32);
    memcpy(val + 12 * n, v, 12 * sizeof(float));
    n++;
  }
  free(pair);
  rec->texel_count = (uint32_t)n;
  rec->texel_index = idx;
  rec->texel_sh = val;
  return UB_OK;
}

ub_result ub_dls_texel_record(const ub_lightmap *lm, const uint32_t *kept, uint32_t nkept,
                              const float *sh, ub_bakefile_record *rec)
{
  return texel_record(lm, kept, nkept, sh, 0, rec);
}

ub_result ub_dls_texel_record_rows(const ub_lightmap *lm, const uint32_t *kept, uint32_t nkept,
                                   const float *sh_rows, ub_bakefile_record *rec)
{
  return texel_record(lm, kept, nkept, sh_rows, 1, rec);
}

/* ---- Uniform voxel grids: the reach bound's and the sparse probe grid's ---- */

/* Cell of p in the grid of cubes of side `cell` from org, dim cells per axis; 0 outside. */
static int grid_cell(const float org[3], float cell, const uint32_t dim[3], const float p[3],
                     int32_t out_c[3])
{
  for (int a = 0; a < 3; a++) {
    float f = (p[a] - org[a]) / cell;
    if (!(f >= 0.0f) || f >= (float)dim[a])
      return 0;
    out_c[a] = (int32_t)f;
  }
  return 1;
}

static size_t grid_index(const uint32_t dim[3], const int32_t c[3])
{
  return ((size_t)c[2] * dim[1] + (size_t)c[1]) * dim[0] + (size_t)c[0];
}

/* The cells of the 3×3×3 block around cell c that lie in the grid (z, then y, then x
 * ascending) into out; returns their count. */
static int grid_block(const uint32_t dim[3], const int32_t c[3], size_t out[27])
{
  int n = 0;
  for (int32_t dz = -1; dz <= 1; dz++)
    for (int32_t dy = -1; dy <= 1; dy++)
      for (int32_t dx = -1; dx <= 1; dx++) {
        int32_t k[3] = {c[0] + dx, c[1] + dy, c[2] + dz};
        if (k[0] < 0 || k[1] < 0 || k[2] < 0 || k[0] >= (int32_t)dim[0] ||
            k[1] >= (int32_t)dim[1] || k[2] >= (int32_t)dim[2])
          continue;
        out[n++] = grid_index(dim, k);
      }
  return n;
}

/* ---- Reach bound (see dls.h) ---- */

static int reach_cell(const ub_dls_reach *r, const float p[3], int32_t out_c[3])
{
  return grid_cell(r->org, r->cell, r->dim, p, out_c);
}

/* Facing bits of a unit normal: every axis with |n_a| > 0.3 (so that a slanted surface
 * marks and matches the same bits from nearby points). */
static uint8_t facing_bits(const float n[3])
{
  uint8_t b = 0;
  for (int a = 0; a < 3; a++) {
    if (n[a] > 0.3f)
      b |= (uint8_t)(1u << (2 * a + 1));
    else if (n[a] < -0.3f)
      b |= (uint8_t)(1u << (2 * a));
  }
  return b ? b : 0x3f;
}

static void reach_mark(ub_dls_reach *r, const float p[3], uint8_t bits)
{
  int32_t c[3];
  if (!reach_cell(r, p, c))
    return;
  uint8_t *m = &r->mask[grid_index(r->dim, c)];
  if ((*m & bits) != bits)
    __atomic_fetch_or(m, bits, __ATOMIC_RELAXED);
}

/* Marks the voxels a segment crosses (steps of half a cell, clipped to the grid). */
static void reach_mark_segment(ub_dls_reach *r, const float o[3], const float d[3], float t)
{
  float lim = r->cell * 2.0f * (float)(r->dim[0] + r->dim[1] + r->dim[2]);
  if (!(t < lim))
    t = lim;
  float step = 0.5f * r->cell;
  for (float s = 0.0f; s <= t; s += step) {
    float p[3] = {o[0] + s * d[0], o[1] + s * d[1], o[2] + s * d[2]};
    int32_t c[3];
    if (!reach_cell(r, p, c)) {
      if (s > 0.0f)
        break; /* left the grid: receivers lie inside it */
      continue;
    }
    uint8_t *m = &r->mask[grid_index(r->dim, c)];
    if (!(*m & 0x40))
      __atomic_fetch_or(m, (uint8_t)0x40, __ATOMIC_RELAXED);
  }
}

static void basis(const float n[3], float t[3], float b[3])
{
  float a[3] = {fabsf(n[0]) > 0.9f ? 0.0f : 1.0f, fabsf(n[0]) > 0.9f ? 1.0f : 0.0f, 0.0f};
  t[0] = a[1] * n[2] - a[2] * n[1];
  t[1] = a[2] * n[0] - a[0] * n[2];
  t[2] = a[0] * n[1] - a[1] * n[0];
  float l = sqrtf(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
  t[0] /= l, t[1] /= l, t[2] /= l;
  b[0] = n[1] * t[2] - n[2] * t[1];
  b[1] = n[2] * t[0] - n[0] * t[2];
  b[2] = n[0] * t[1] - n[1] * t[0];
}

void ub_dls_bounds_add(const float p[3], float lo[3], float hi[3])
{
  for (int a = 0; a < 3; a++)
    if (isfinite(p[a])) {
      lo[a] = p[a] < lo[a] ? p[a] : lo[a];
      hi[a] = p[a] > hi[a] ? p[a] : hi[a];
    }
}

ub_result ub_dls_reach_build(const ub_scene *scene, const ub_rt *rt, const uint8_t *enabled,
                             const float lo[3], const float hi[3], uint32_t seed,
                             uint32_t set, uint32_t segments, ub_dls_reach *out)
{
  memset(out, 0, sizeof *out);
  if (segments < 1)
    segments = 1;
  if (segments > UB_DLS_REACH_SEGMENTS)
    segments = UB_DLS_REACH_SEGMENTS;
  uint32_t nlight = 0;
  for (uint32_t l = 0; l < scene->light_count; l++)
    if (enabled[l]) {
      if (scene->lights[l].type == UB_LIGHT_DIRECTIONAL) {
        out->unbounded = 1;
        return UB_OK;
      }
      nlight++;
    }
  float ext = 0.0f;
  for (int a = 0; a < 3; a++)
    ext = fmaxf(ext, hi[a] - lo[a]);
  if (!(ext > 0.0f) || !isfinite(ext)) {
    out->unbounded = 1;
    return UB_OK;
  }
  out->cell = ext / (float)UB_DLS_REACH_CELLS;
  for (int a = 0; a < 3; a++) {
    out->org[a] = lo[a] - out->cell; /* one cell of margin each side */
    out->dim[a] = (uint32_t)ceilf((hi[a] - lo[a]) / out->cell) + 2;
  }
  size_t nc = (size_t)out->dim[0] * out->dim[1] * out->dim[2];
  out->mask = calloc(nc, 1);
  if (!out->mask)
    return UB_ERR_OUT_OF_MEMORY;
  const uint32_t chunk = 1024, per = UB_DLS_REACH_PHOTONS;
  uint32_t chunks = (per + chunk - 1) / chunk;
  uint64_t rays = 0;
  float off = 0.25f * out->cell; /* hits are marked on their open side */
  for (uint32_t l = 0; l < scene->light_count; l++) {
    if (!enabled[l])
      continue;
    const ub_light *L = &scene->lights[l];
    int fail = 0;
#pragma omp parallel for schedule(dynamic, 1) reduction(+ : rays) reduction(| : fail)
    for (uint32_t c = 0; c < chunks; c++) {
      ub_ray *ray = malloc(chunk * sizeof *ray);
      ub_hit *hit = malloc(chunk * sizeof *hit);
      uint8_t *alive = malloc(chunk);
      if (!ray || !hit || !alive) {
        fail = 1;
        free(ray), free(hit), free(alive);
        continue;
      }
      float sd[3], st[3], sb[3];
      if (L->type == UB_LIGHT_SPOT) {
        memcpy(sd, L->direction, sizeof sd);
        basis(sd, st, sb);
      }
      for (uint32_t i = 0; i < chunk; i++) {
        uint32_t ph = c * chunk + i;
        uint32_t h = ub_hash4(seed ^ 0xd15ea5e5u, set, l * per + ph, 0);
        float u1 = ub_u01(ub_hash4(h, 1, 0, 0)), u2 = ub_u01(ub_hash4(h, 2, 0, 0));
        float ct = L->type == UB_LIGHT_SPOT ? 1.0f - u1 * (1.0f - fmaxf(L->cos_outer, -1.0f))
                                            : 1.0f - 2.0f * u1;
        float sn = sqrtf(fmaxf(0.0f, 1.0f - ct * ct)), phi = 6.2831853f * u2;
        float x = sn * cosf(phi), y = sn * sinf(phi);
        if (L->type == UB_LIGHT_SPOT)
          for (int a = 0; a < 3; a++)
            ray[i].dir[a] = x * st[a] + y * sb[a] + ct * sd[a];
        else
          ray[i].dir[0] = x, ray[i].dir[1] = y, ray[i].dir[2] = ct;
        memcpy(ray[i].org, L->position, sizeof ray[i].org);
        ray[i].tnear = 0.0f;
        ray[i].tfar = L->range > 0.0f ? L->range : INFINITY;
        alive[i] = ph < per;
      }
      for (uint32_t seg = 0; seg < segments; seg++) {
        uint32_t n = 0; /* compact the live photons to the front */
        for (uint32_t i = 0; i < chunk; i++)
          if (alive[i])
            ray[n] = ray[i], alive[n++] = 1;
        if (n == 0)
          break;
        ub_rt_intersect(rt, ray, n, hit);
        rays += n;
        for (uint32_t i = 0; i < n; i++) {
          ub_ray *R = &ray[i];
          float t = hit[i].tri == UB_RT_MISS ? R->tfar : hit[i].t;
          reach_mark_segment(out, R->org, R->dir, t);
          alive[i] = 0;
          if (hit[i].tri == UB_RT_MISS || !isfinite(t))
            continue;
          float ng[3] = {hit[i].ng[0], hit[i].ng[1], hit[i].ng[2]};
          float ln = sqrtf(ng[0] * ng[0] + ng[1] * ng[1] + ng[2] * ng[2]);
          if (!(ln > 0.0f))
            continue;
          float dn = ng[0] * R->dir[0] + ng[1] * R->dir[1] + ng[2] * R->dir[2];
          float sgn = dn > 0.0f ? -1.0f / ln : 1.0f / ln; /* face the incoming photon */
          for (int a = 0; a < 3; a++)
            ng[a] *= sgn;
          float p[3], q[3];
          for (int a = 0; a < 3; a++) {
            p[a] = R->org[a] + t * R->dir[a];
            q[a] = p[a] + off * ng[a];
          }
          reach_mark(out, q, facing_bits(ng));
          uint32_t h = ub_hash4(seed ^ 0xd15ea5e5u, set, l * per + c * chunk + i, seg + 1);
          /* Russian roulette on the surface's largest albedo channel: every photon then
           * carries the same share of the set's power, so the (1-p)^N bound holds for
           * the power that really arrives, not for albedo-1 light. */
          const float *rho = scene->materials[scene->tri_material[hit[i].tri]].albedo;
          float keep = fmaxf(rho[0], fmaxf(rho[1], rho[2]));
          if (!(ub_u01(ub_hash4(h, 3, 0, 0)) < keep))
            continue;
          ub_rt_offset_point(rt, p, ng, R->org);
          ub_sample_cosine(ng, ub_u01(ub_hash4(h, 1, 0, 0)), ub_u01(ub_hash4(h, 2, 0, 0)),
                           R->dir);
          R->tnear = 0.0f;
          R->tfar = INFINITY;
          alive[i] = 1;
        }
        for (uint32_t i = n; i < chunk; i++)
          alive[i] = 0;
      }
      free(ray);
      free(hit);
      free(alive);
    }
    if (fail) {
      ub_dls_reach_free(out);
      return UB_ERR_OUT_OF_MEMORY;
    }
  }
  out->rays = rays;
  /* near: the mask OR-ed over each voxel's 3×3×3 block, so a lookup is one voxel (every
   * texel of the level is tested per set: 27 reads each were ~3% of an ESTATE bake) */
  out->near = malloc(nc);
  if (out->near)
    for (int32_t z = 0; z < (int32_t)out->dim[2]; z++)
      for (int32_t y = 0; y < (int32_t)out->dim[1]; y++)
        for (int32_t x = 0; x < (int32_t)out->dim[0]; x++) {
          int32_t c[3] = {x, y, z};
          size_t cells[27];
          int n = grid_block(out->dim, c, cells);
          uint8_t m = 0;
          for (int i = 0; i < n; i++)
            m |= out->mask[cells[i]];
          out->near[grid_index(out->dim, c)] = m;
        }
  return UB_OK;
}

void ub_dls_reach_free(ub_dls_reach *r)
{
  if (!r)
    return;
  free(r->mask);
  free(r->near);
  r->mask = NULL;
  r->near = NULL;
}

/* OR of the mask over the 27 voxels around p; 0xff when p is outside the grid. */
static uint8_t reach_near(const ub_dls_reach *r, const float p[3])
{
  int32_t c[3];
  if (r->unbounded || !reach_cell(r, p, c))
    return 0xff;
  if (r->near)
    return r->near[grid_index(r->dim, c)];
  size_t cells[27];
  int n = grid_block(r->dim, c, cells);
  uint8_t m = 0;
  for (int i = 0; i < n; i++)
    m |= r->mask[cells[i]];
  return m;
}

/* One lookup a quarter cell out along n from p. */
static int reach_near_open(const ub_dls_reach *r, const float p[3], const float n[3])
{
  float q[3] = {p[0] + 0.25f * r->cell * n[0], p[1] + 0.25f * r->cell * n[1],
                p[2] + 0.25f * r->cell * n[2]};
  return reach_near(r, q) != 0;
}

int ub_dls_reach_texel(const ub_dls_reach *r, const ub_lightmap *lm, uint32_t t)
{
  if (r->unbounded)
    return 1;
  /* Any photon hit or crossing within one cell of its open side. (Requiring a hit on a
   * surface facing its way, to keep light from leaking past walls thinner than a cell,
   * dropped 1.24% of an estate_small hall set's light against --plan all, 0.96% before
   * the bound; without it 0.98%.) The centre, then the sample points the pass gathers at
   * (looking at the centre only dropped 4.2% of two_rooms' light: floor texels under
   * the walls, whose samples the back-face fix moved into the lit room). */
  const float *n = lm->texel_normal + 3 * (size_t)t;
  if (reach_near_open(r, lm->texel_pos + 3 * (size_t)t, n))
    return 1;
  for (int j = 0; lm->sample_pos && j < UB_TEXEL_SAMPLES; j++)
    if (reach_near_open(r, lm->sample_pos + ((size_t)t * UB_TEXEL_SAMPLES + j) * 3, n))
      return 1;
  return 0;
}

/* The grid index of the cell a quarter cell out along n from p, or UB_DLS_CELL_OUTSIDE
 * (reach_near_open's lookup). */
static uint32_t open_cell(const ub_dls_reach *r, const float p[3], const float n[3])
{
  float q[3] = {p[0] + 0.25f * r->cell * n[0], p[1] + 0.25f * r->cell * n[1],
                p[2] + 0.25f * r->cell * n[2]};
  int32_t c[3];
  if (!reach_cell(r, q, c))
    return UB_DLS_CELL_OUTSIDE;
  return (uint32_t)grid_index(r->dim, c);
}

int ub_dls_texel_cells_build(const ub_dls_reach *r, const ub_lightmap *lm,
                             ub_dls_texel_cells *out)
{
  memset(out, 0, sizeof *out);
  if (r->unbounded || !r->near ||
      (size_t)r->dim[0] * r->dim[1] * r->dim[2] >= (size_t)UB_DLS_CELL_OUTSIDE)
    return 0;
  uint32_t per = lm->sample_pos ? 1u + UB_TEXEL_SAMPLES : 1u;
  uint32_t *idx = malloc(((size_t)lm->texel_count * per + 1) * sizeof *idx);
  if (!idx)
    return 0;
  for (uint32_t t = 0; t < lm->texel_count; t++) {
    const float *n = lm->texel_normal + 3 * (size_t)t;
    uint32_t *o = idx + (size_t)t * per;
    o[0] = open_cell(r, lm->texel_pos + 3 * (size_t)t, n);
    for (uint32_t j = 1; j < per; j++)
      o[j] = open_cell(r, lm->sample_pos + ((size_t)t * UB_TEXEL_SAMPLES + j - 1) * 3, n);
  }
  memcpy(out->org, r->org, sizeof out->org);
  out->cell = r->cell;
  memcpy(out->dim, r->dim, sizeof out->dim);
  out->per = per;
  out->idx = idx;
  return 1;
}

void ub_dls_texel_cells_free(ub_dls_texel_cells *tc)
{
  if (tc) {
    free(tc->idx);
    memset(tc, 0, sizeof *tc);
  }
}

uint32_t ub_dls_reach_texels(const ub_dls_reach *r, const ub_dls_texel_cells *tc,
                             const ub_lightmap *lm, uint32_t *out)
{
  uint32_t n = 0;
  int fast = !r->unbounded && tc && tc->idx && r->near && tc->cell == r->cell &&
             memcmp(tc->org, r->org, sizeof tc->org) == 0 &&
             memcmp(tc->dim, r->dim, sizeof tc->dim) == 0;
  for (uint32_t t = 0; t < lm->texel_count; t++) {
    int in;
    if (fast) {
      const uint32_t *o = tc->idx + (size_t)t * tc->per;
      in = 0;
      for (uint32_t j = 0; j < tc->per && !in; j++)
        in = o[j] == UB_DLS_CELL_OUTSIDE || r->near[o[j]] != 0;
    } else {
      in = ub_dls_reach_texel(r, lm, t);
    }
    if (in && out)
      out[n] = t;
    n += (uint32_t)in;
  }
  return n;
}

int ub_dls_reach_point(const ub_dls_reach *r, const float p[3])
{
  return r->unbounded || reach_near(r, p) != 0;
}

/* World size of texel t (its larger footprint edge), 0 when unknown. */
static float texel_size_world(const ub_scene *s, const ub_lightmap *lm, uint32_t t)
{
  float o[3], a[3], b[3];
  if (!ub_lightmap_texel_point(s, lm, t, 0.0f, 0.0f, o) ||
      !ub_lightmap_texel_point(s, lm, t, 1.0f, 0.0f, a) ||
      !ub_lightmap_texel_point(s, lm, t, 0.0f, 1.0f, b))
    return 0.0f;
  float da = 0.0f, db = 0.0f;
  for (int k = 0; k < 3; k++) {
    da += (a[k] - o[k]) * (a[k] - o[k]);
    db += (b[k] - o[k]) * (b[k] - o[k]);
  }
  return sqrtf(fmaxf(da, db));
}

/* Whether the atlas step between edge-adjacent pixels (xa, ya) and (xb, yb) crosses no
 * geometry (no link bit between them; an atlas without link data has none). */
static int step_free(const ub_atlas *at, uint32_t xa, uint32_t ya, uint32_t xb, uint32_t yb)
{
  if (!at->link)
    return 1;
  uint32_t x0 = xa < xb ? xa : xb, y0 = ya < yb ? ya : yb;
  uint8_t bit = ya == yb ? UB_LINK_X : UB_LINK_Y;
  return !(at->link[(size_t)y0 * at->width + x0] & bit);
}

/* A kept receiver's ray shift in a full pass with scaled rays: the largest k with
 * 2^-k >= est / ref, at most UB_DLS_RAY_SHIFT_MAX (0 when est > ref / 2). */
static uint8_t dls_ray_shift(double est, double ref)
{
  uint8_t k = 0;
  while (k < UB_DLS_RAY_SHIFT_MAX && est * (double)(2u << k) <= ref)
    k++;
  return k;
}

/* Whether texel u may take texel g's bounce light in a sparse influence pass: atlas
 * neighbours (one of the 8 around it) on the same surface: normals within ~18°, centres
 * within 2 texels, and no geometry between them in the atlas (edge neighbours: no link
 * bit; diagonal ones: a covered pixel at one of the two corners between them reached
 * through no link bit both ways). */
static int donor_ok(const ub_scene *s, const ub_lightmap *lm, uint32_t u, uint32_t g)
{
  const float *nu = lm->texel_normal + 3 * (size_t)u, *ng = lm->texel_normal + 3 * (size_t)g;
  if (nu[0] * ng[0] + nu[1] * ng[1] + nu[2] * ng[2] < 0.95f)
    return 0;
  const float *pu = lm->texel_pos + 3 * (size_t)u, *pg = lm->texel_pos + 3 * (size_t)g;
  float d2 = 0.0f;
  for (int k = 0; k < 3; k++)
    d2 += (pu[k] - pg[k]) * (pu[k] - pg[k]);
  float w = texel_size_world(s, lm, g);
  if (!(w > 0.0f) || !(d2 <= 4.0f * w * w))
    return 0;
  const ub_atlas *at = &lm->atlases[lm->texel_atlas[u]];
  uint32_t xu = lm->texel_xy[2 * u], yu = lm->texel_xy[2 * u + 1];
  uint32_t xg = lm->texel_xy[2 * g], yg = lm->texel_xy[2 * g + 1];
  if (xu == xg || yu == yg)
    return step_free(at, xu, yu, xg, yg);
  /* diagonal: through (xg, yu) or (xu, yg) */
  uint32_t cx[2] = {xg, xu}, cy[2] = {yu, yg};
  for (int k = 0; k < 2; k++)
    if (at->texel_of[(size_t)cy[k] * at->width + cx[k]] >= 0 &&
        step_free(at, xu, yu, cx[k], cy[k]) && step_free(at, cx[k], cy[k], xg, yg))
      return 1;
  return 0;
}

/* Candidate texel at atlas pixel (x, y), or -1. */
static int32_t cand_at(const ub_atlas *at, const uint8_t *is_cand, int64_t x, int64_t y)
{
  if (x < 0 || y < 0 || x >= (int64_t)at->width || y >= (int64_t)at->height)
    return -1;
  int32_t g = at->texel_of[(size_t)y * at->width + (size_t)x];
  return g >= 0 && is_cand[g] ? g : -1;
}

/* Texel t's candidate atlas neighbours on the same surface (of the 8 around it,
 * donor_ok) into out; returns how many. */
static uint32_t surface_neighbours(const ub_scene *s, const ub_lightmap *lm,
                                   const uint8_t *is_cand, uint32_t t, uint32_t out[8])
{
  const ub_atlas *at = &lm->atlases[lm->texel_atlas[t]];
  int64_t x = lm->texel_xy[2 * t], y = lm->texel_xy[2 * t + 1];
  uint32_t n = 0;
  for (int dy = -1; dy <= 1; dy++)
    for (int dx = -1; dx <= 1; dx++) {
      if (!dx && !dy)
        continue;
      int32_t g = cand_at(at, is_cand, x + dx, y + dy);
      if (g >= 0 && donor_ok(s, lm, t, (uint32_t)g))
        out[n++] = (uint32_t)g;
    }
  return n;
}

/* The keep rule's estimate at texel t (a candidate with is_cand set): the mean of est over
 * t and its candidate atlas neighbours on the same surface (surface_neighbours).
 * The influence pass's indirect comes from a few rays at one gather per ~2×2 texels, so a
 * texel whose gather missed a faint source reads 0 where its neighbours read it: culled
 * on its own estimate, it left a hole in the set's record (q3dm6ish with three sets, draft:
 * 107 culled texels at over 10× the threshold in a dense bake, one at 75×). The mean over
 * the neighbourhood averages several gathers; light that reaches a surface at all is
 * seldom missed by all of them. */
static double keep_estimate(const ub_scene *s, const ub_lightmap *lm, const uint8_t *is_cand,
                            const float *est, uint32_t t)
{
  uint32_t nb[8], n = surface_neighbours(s, lm, is_cand, t, nb);
  double sum = est[t];
  for (uint32_t i = 0; i < n; i++)
    sum += est[nb[i]];
  return sum / (n + 1);
}

/* The keep rule's closing: whether a culled candidate t is surrounded by kept texels,
 * more than half of its candidate atlas neighbours on the same surface, and at least 3 of
 * them, carrying is_cand 2 (kept) rather than 1. keep_estimate averages the gathers
 * around a texel, but where all of them missed a faint source it still reads 0 amid kept
 * neighbours: estate_small at 2 bounces, 0.4 m texels left 25 culled texels above a tenth
 * of their set's mean in a dense bake, 11 of them with 5–7 of 8 neighbours kept; with this
 * step 15, for records 3.2% larger there. A texel just outside a straight edge of the kept
 * region has at most half (3 of 8), so the region does not grow there; a concave corner
 * (5 of 8) fills. ESTATE at scale 0.12 (draft, 2 bounces): records +1.2%, full-pass rays
 * +0.3% (scaled rays make such faint texels cheap). Requiring 3 of 4 instead: 17 holes on
 * estate_small, records +0.5% at 0.12. */
static int keep_closed(const ub_scene *s, const ub_lightmap *lm, const uint8_t *is_cand,
                       uint32_t t)
{
  uint32_t nb[8], n = surface_neighbours(s, lm, is_cand, t, nb), k = 0;
  for (uint32_t i = 0; i < n; i++)
    k += is_cand[nb[i]] == 2;
  return n >= 3 && 2 * k > n;
}

/* Sparse gathers for an influence pass over the candidates ct[0..n) (ascending, so row
 * by row within an atlas): a candidate takes the bounce light of a gathering candidate
 * already decided next to it (left, up, up-left, up-right, in that order) when donor_ok;
 * otherwise it gathers itself. On a plain surface that is one gather per 2×2 pixels, as
 * a block pattern would give, but it follows chart borders instead of cutting blocks at
 * them. Deterministic (one pass in index order). donor: texel_count entries (candidates
 * written); the gathering texels (ascending) into gat; returns their count. is_cand:
 * texel_count zero bytes (left zero). Indirect light varies little over a texel: the
 * keep rule reads it from up to 4× fewer gathers; direct light is still computed at
 * every candidate. */
static uint32_t influence_donors(const ub_scene *s, const ub_lightmap *lm, const uint32_t *ct,
                                 uint32_t n, uint8_t *is_cand, uint32_t *donor, uint32_t *gat)
{
  static const int off[4][2] = {{-1, 0}, {0, -1}, {-1, -1}, {1, -1}};
  for (uint32_t i = 0; i < n; i++)
    is_cand[ct[i]] = 1;
  uint32_t ng = 0;
  for (uint32_t i = 0; i < n; i++) {
    uint32_t t = ct[i];
    const ub_atlas *at = &lm->atlases[lm->texel_atlas[t]];
    int64_t x = lm->texel_xy[2 * t], y = lm->texel_xy[2 * t + 1];
    uint32_t d = t;
    for (int k = 0; k < 4 && d == t; k++) {
      int32_t g = cand_at(at, is_cand, x + off[k][0], y + off[k][1]);
      if (g >= 0 && (uint32_t)g < t && donor[g] == (uint32_t)g && donor_ok(s, lm, t, (uint32_t)g))
        d = (uint32_t)g;
    }
    donor[t] = d;
    if (d == t)
      gat[ng++] = t;
  }
  for (uint32_t i = 0; i < n; i++)
    is_cand[ct[i]] = 0;
  return ng;
}

/* Sparse LLG probe gathers for an influence pass over the candidates cl[0..n)
 * (ascending): as the texels', in 3D: within its model's grid a valid candidate takes the
 * bounce light of an already-decided, valid, gathering candidate among its 13 earlier grid
 * neighbours (faces first, then edges, then corners); otherwise it gathers. About one
 * probe in 8 gathers on a full grid (probes ~0.3 m apart around one prop, whose indirect
 * light varies little). donor: probe_count entries (candidates written); the gathering
 * probes (ascending) into gat; returns their count. is_cand: probe_count zero bytes
 * (left zero). */
static uint32_t llg_donors(const ub_llg_set *set, const uint32_t *cl, uint32_t n,
                           uint8_t *is_cand, uint32_t *donor, uint32_t *gat)
{
  static const int8_t off[13][3] = {{-1, 0, 0},  {0, -1, 0},  {0, 0, -1}, {-1, -1, 0},
                                    {1, -1, 0},  {-1, 0, -1}, {1, 0, -1}, {0, -1, -1},
                                    {0, 1, -1},  {-1, -1, -1}, {1, -1, -1}, {-1, 1, -1},
                                    {1, 1, -1}};
  for (uint32_t i = 0; i < n; i++)
    is_cand[cl[i]] = 1;
  uint32_t ng = 0, m = 0;
  for (uint32_t i = 0; i < n; i++) {
    uint32_t q = cl[i], d = q;
    while (m + 1 < set->model_count && set->models[m + 1].probe_first <= q)
      m++;
    const ub_llg_model *md = &set->models[m];
    uint32_t nx = md->dims[0], ny = md->dims[1], nz = md->dims[2];
    uint32_t local = q - md->probe_first;
    if (set->probe_valid[q] && local < nx * ny * nz) {
      int64_t x = local % nx, y = (local / nx) % ny, z = local / (nx * ny);
      for (int k = 0; k < 13 && d == q; k++) {
        int64_t xx = x + off[k][0], yy = y + off[k][1], zz = z + off[k][2];
        if (xx < 0 || yy < 0 || zz < 0 || xx >= nx || yy >= ny || zz >= nz)
          continue;
        uint32_t g = md->probe_first + (uint32_t)((zz * ny + yy) * nx + xx);
        if (g < q && is_cand[g] && set->probe_valid[g] && donor[g] == g)
          d = g;
      }
    }
    donor[q] = d;
    if (d == q)
      gat[ng++] = q;
  }
  for (uint32_t i = 0; i < n; i++)
    is_cand[cl[i]] = 0;
  return ng;
}

/* Sparse probe gathers for an influence pass: a hash grid of cell r over the candidate
 * probes cp[0..n) (ascending). In index order a probe gathers unless a gathering probe
 * within r is visible from it (one ray); every other probe then reads the largest
 * indirect light of the gathering probes within r it sees (probe_indirect filled in by
 * probe_fill_sparse), so the keep rule errs towards keeping. Direct light is computed at
 * every candidate. */
typedef struct probe_grid {
  float r;      /* the radius, and the cells' side */
  float lo[3];
  uint32_t dim[3];
  uint32_t *head; /* cells: first gathering probe, UINT32_MAX = none */
  uint32_t *next; /* probe_count: next gathering probe in its cell */
} probe_grid;

static int probe_grid_cell(const probe_grid *g, const float p[3], int32_t c[3])
{
  return grid_cell(g->lo, g->r, g->dim, p, c);
}

static int probes_see(const ub_rt *rt, const float *a, const float *b)
{
  ub_ray ray;
  memcpy(ray.org, a, sizeof ray.org);
  for (int k = 0; k < 3; k++)
    ray.dir[k] = b[k] - a[k];
  ray.tnear = 0.0f;
  ray.tfar = 1.0f;
  uint8_t occ = 1;
  ub_rt_occluded(rt, &ray, 1, &occ);
  return !occ;
}

/* Visits the gathering probes within r of p that p sees; fn returns 1 to stop. */
static void probe_grid_visit(const probe_grid *g, const ub_rt *rt, const float *pos,
                             uint32_t q, int (*fn)(void *, uint32_t), void *user)
{
  const float *p = pos + 3 * (size_t)q;
  int32_t c[3];
  if (!probe_grid_cell(g, p, c))
    return;
  size_t cells[27];
  int n = grid_block(g->dim, c, cells);
  for (int i = 0; i < n; i++)
    for (uint32_t o = g->head[cells[i]]; o != UINT32_MAX; o = g->next[o]) {
      const float *po = pos + 3 * (size_t)o;
      float d2 = 0.0f;
      for (int a = 0; a < 3; a++)
        d2 += (po[a] - p[a]) * (po[a] - p[a]);
      if (d2 <= g->r * g->r && probes_see(rt, p, po) && fn(user, o))
        return;
    }
}

static int visit_any(void *user, uint32_t o)
{
  (void)o;
  *(int *)user = 1;
  return 1;
}

typedef struct max_ctx {
  const float *ind;
  float m;
} max_ctx;

static int visit_max(void *user, uint32_t o)
{
  max_ctx *m = user;
  m->m = fmaxf(m->m, m->ind[o]);
  return 0;
}

/* Chooses the gathering probes (into gat, ascending; returns their count); the grid is
 * kept for probe_fill_sparse. NULL grid memory: every candidate gathers. */
static uint32_t probe_sparse_pick(probe_grid *g, const ub_rt *rt, const float *pos,
                                  const uint32_t *cp, uint32_t n, uint32_t *gat)
{
  uint32_t ng = 0;
  for (uint32_t i = 0; i < n; i++) {
    uint32_t q = cp[i];
    int seen = 0;
    if (g->head)
      probe_grid_visit(g, rt, pos, q, visit_any, &seen);
    if (seen)
      continue;
    gat[ng++] = q;
    int32_t c[3];
    if (g->head && probe_grid_cell(g, pos + 3 * (size_t)q, c)) {
      size_t ci = grid_index(g->dim, c);
      g->next[q] = g->head[ci];
      g->head[ci] = q;
    }
  }
  return ng;
}

/* The non-gathering candidates' indirect: the largest of the gathering probes they see
 * within r. Then empties the grid. */
static void probe_fill_sparse(probe_grid *g, const ub_rt *rt, const float *pos,
                              const uint32_t *cp, uint32_t n, const uint32_t *gat, uint32_t ng,
                              float *indirect)
{
  if (!g->head)
    return;
  uint32_t j = 0;
  for (uint32_t i = 0; i < n; i++) {
    uint32_t q = cp[i];
    while (j < ng && gat[j] < q)
      j++;
    if (j < ng && gat[j] == q)
      continue;
    max_ctx m = {indirect, 0.0f};
    probe_grid_visit(g, rt, pos, q, visit_max, &m);
    indirect[q] = m.m;
  }
  for (uint32_t k = 0; k < ng; k++) {
    int32_t c[3];
    if (probe_grid_cell(g, pos + 3 * (size_t)gat[k], c))
      g->head[grid_index(g->dim, c)] = UINT32_MAX;
  }
}

ub_result ub_dls_bake(const ub_pass_desc *base, const ub_plan *plan, const ub_log *log,
                      ub_bakefile_record **out_records, ub_dls_stats *out_stats)
{
  const ub_scene *s = base->scene;
  const ub_lightmap *lm = base->lightmap;
  memset(out_stats, 0, sizeof *out_stats);
  *out_records = NULL;
  if (s->dls_count == 0)
    return UB_OK;
  out_stats->sets = calloc(s->dls_count, sizeof *out_stats->sets); /* NULL: not kept */
  ub_bakefile_record *recs = calloc(s->dls_count, sizeof *recs);
  uint8_t *enabled = calloc(s->light_count ? s->light_count : 1, 1);
  uint32_t *kt = malloc(((size_t)lm->texel_count + 1) * sizeof *kt);
  uint32_t *kp = malloc(((size_t)base->probe_count + 1) * sizeof *kp);
  for (uint32_t d = 0; recs && d < s->dls_count; d++) {
    recs[d].kind = UB_ELEMENT_DLS;
    recs[d].parent[0] = recs[d].parent[1] = -1;
  }
  uint32_t nlp = base->llg ? base->llg->probe_count : 0; /* LLG probes */
  uint32_t *kl = malloc(((size_t)nlp + 1) * sizeof *kl);
  /* candidates of the reach bound; sparse influence gathers (influence_donors) */
  uint32_t *ct = malloc(((size_t)lm->texel_count + 1) * sizeof *ct);
  uint32_t *donor = plan->influence_sparse ? malloc(((size_t)lm->texel_count + 1) * sizeof *donor)
                                           : NULL;
  uint32_t *gat = plan->influence_sparse ? malloc(((size_t)lm->texel_count + 1) * sizeof *gat)
                                         : NULL;
  uint8_t *is_cand = plan->influence_sparse || plan->influence_culling
                        ? calloc((size_t)lm->texel_count + 1, 1)
                        : NULL;
  uint8_t *tsel = plan->influence_culling ? malloc((size_t)lm->texel_count + 1) : NULL;
  uint32_t *cp = malloc(((size_t)base->probe_count + 1) * sizeof *cp);
  uint32_t *cl = malloc(((size_t)nlp + 1) * sizeof *cl);
  int llg_sparse = plan->influence_sparse && nlp > 0;
  uint32_t *ldonor = llg_sparse ? malloc(((size_t)nlp + 1) * sizeof *ldonor) : NULL;
  uint32_t *lgat = llg_sparse ? malloc(((size_t)nlp + 1) * sizeof *lgat) : NULL;
  uint8_t *lcand = llg_sparse ? calloc((size_t)nlp + 1, 1) : NULL;
  /* full passes' ray shifts (dls_ray_shift), zero outside the set being baked */
  int scaled = plan->dls_scaled_rays; /* only with influence culling (ub_plan_build) */
  /* The influence pass's bounces (no more than the full passes run) and whether the full
   * passes run beyond them (then each estimate gets its geometric tail). */
  const uint32_t NB = ub_dls_influence_bounces(base->bounces);
  const int full_tail = base->bounces < 0 || (uint32_t)base->bounces > NB;
  uint8_t *tsh = scaled ? calloc((size_t)lm->texel_count + 1, 1) : NULL;
  ub_dls_texel_cells cells; /* built from the first bounded reach (ub_dls_reach_texels) */
  memset(&cells, 0, sizeof cells);
  uint8_t *psh = scaled ? calloc((size_t)base->probe_count + 1, 1) : NULL;
  uint8_t *lsh = scaled ? calloc((size_t)nlp + 1, 1) : NULL;
  /* a set's culling estimate per texel, read at its candidates only */
  float *est = malloc(((size_t)lm->texel_count + 1) * sizeof *est);
  if (!recs || !enabled || !kt || !kp || !kl || !ct || !cp || !cl || !est ||
      (scaled && (!tsh || !psh || !lsh)) ||
      (plan->influence_sparse && (!donor || !gat)) ||
      ((plan->influence_sparse || plan->influence_culling) && !is_cand) ||
      (plan->influence_culling && !tsel) ||
      (llg_sparse && (!ldonor || !lgat || !lcand))) {
    free(est);
    free(tsh);
    free(psh);
    free(lsh);
    free(ldonor);
    free(lgat);
    free(lcand);
    free(donor);
    free(gat);
    free(is_cand);
    free(tsel);
    free(recs);
    free(enabled);
    free(kt);
    free(kp);
    free(kl);
    free(ct);
    free(cp);
    free(cl);
    return UB_ERR_OUT_OF_MEMORY;
  }
  /* The reach grid spans the receivers and the lights. */
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (uint32_t t = 0; t < lm->texel_count; t++)
    ub_dls_bounds_add(lm->texel_pos + 3 * (size_t)t, lo, hi);
  for (uint32_t q = 0; q < base->probe_count; q++)
    ub_dls_bounds_add(base->probe_pos + 3 * (size_t)q, lo, hi);
  for (uint32_t q = 0; q < nlp; q++)
    ub_dls_bounds_add(base->llg->probe_pos + 3 * (size_t)q, lo, hi);
  for (uint32_t l = 0; l < s->light_count; l++)
    if (s->lights[l].dls >= 0 && s->lights[l].type != UB_LIGHT_DIRECTIONAL)
      ub_dls_bounds_add(s->lights[l].position, lo, hi);
  /* Sparse probe gathers: a grid of cells r = 1.8 × the probes' mean spacing (the cube
   * root of the receivers' box volume per probe), at most 1/16 of the longest side. */
  probe_grid pg;
  memset(&pg, 0, sizeof pg);
  uint32_t *pgat = NULL;
  if (plan->influence_sparse && base->probe_count) {
    float ext = 0.0f;
    for (int a = 0; a < 3; a++)
      ext = fmaxf(ext, hi[a] - lo[a]);
    double vol = 1.0;
    for (int a = 0; a < 3; a++)
      vol *= fmax(hi[a] - lo[a], 1e-3 * ext);
    pg.r = (float)fmin(1.8 * cbrt(vol / base->probe_count), ext / 16.0);
    if (ext > 0.0f && isfinite(ext) && pg.r > 0.0f && isfinite(pg.r)) {
      size_t nc = 1;
      for (int a = 0; a < 3; a++) {
        pg.lo[a] = lo[a] - pg.r;
        pg.dim[a] = (uint32_t)ceilf((hi[a] - lo[a]) / pg.r) + 2;
        nc *= pg.dim[a];
      }
      pg.head = malloc(nc * sizeof *pg.head);
      pg.next = malloc(((size_t)base->probe_count + 1) * sizeof *pg.next);
      pgat = malloc(((size_t)base->probe_count + 1) * sizeof *pgat);
      if (pg.head)
        memset(pg.head, 0xff, nc * sizeof *pg.head);
      if (!pg.head || !pg.next || !pgat) { /* every probe gathers */
        free(pg.head);
        free(pg.next);
        pg.head = pg.next = NULL;
      }
    }
  }
  ub_result r = UB_OK;
  for (uint32_t d = 0; d < s->dls_count && r == UB_OK; d++) {
    ub_bakefile_record *rec = &recs[d];
    snprintf(rec->name, sizeof rec->name, "%s", s->dls_names[d]);
    /* this set's share of the totals, taken from them when it is done */
    const uint64_t ri0 = out_stats->rays_influence, rf0 = out_stats->rays_full;
    const double si0 = out_stats->seconds_influence, sf0 = out_stats->seconds_full;
    uint32_t reaching = 0;
    double lum_sum = 0.0;
    for (uint32_t l = 0; l < s->light_count; l++) {
      const ub_light *L = &s->lights[l];
      enabled[l] = L->dls == (int32_t)d && plan->dls_light_reaches[l];
      if (L->dls == (int32_t)d) {
        rec->light_count++;
        lum_sum += 0.2126 * L->intensity[0] + 0.7152 * L->intensity[1] +
                   0.0722 * L->intensity[2];
      }
      reaching += enabled[l];
    }
    rec->mean_intensity = rec->light_count ? (float)(lum_sum / rec->light_count) : 0.0f;
    if (!reaching) {
      out_stats->sets_empty++;
      ub_log_printf(log, UB_LOG_INFO, "  dls %-16s: %u light(s) reach no receiver: skipped",
                    rec->name, rec->light_count);
      continue;
    }
    /* 0. Reach bound: the influence pass sees only the receivers the set's photons can
     * reach (dls.h); --plan all (no culling) keeps every receiver. */
    uint32_t nct = lm->texel_count, ncp = base->probe_count, ncl = nlp;
    ub_dls_reach reach = {.unbounded = 1};
    /* the plan's bound when it traced one (same lights, seed and set), else traced here */
    int own = plan->influence_culling && !(plan->dls_reach && d < plan->dls_reach_count);
    if (plan->influence_culling) {
      double tr = now_s();
      if (own) {
        r = ub_dls_reach_build(s, base->rt, enabled, lo, hi, base->seed, d, NB + 1u, &reach);
        if (r != UB_OK)
          break;
        out_stats->rays_influence += reach.rays;
      } else {
        reach = plan->dls_reach[d];
      }
      out_stats->rays_reach += reach.rays;
      if (!reach.unbounded) {
        ncp = ncl = 0;
        if (!cells.idx) /* every set's bound is on this grid (failing: point by point) */
          ub_dls_texel_cells_build(&reach, lm, &cells);
        nct = ub_dls_reach_texels(&reach, &cells, lm, ct);
        for (uint32_t q = 0; q < base->probe_count; q++)
          if (ub_dls_reach_point(&reach, base->probe_pos + 3 * (size_t)q))
            cp[ncp++] = q;
        /* LLG probes by model: a prop's probes see the level without the prop, but the
         * photons stop at it, so probes inside a big prop are far from any voxel they
         * crossed (estate_small's rooms lost 2.5-3.4% of their LLG light that way). A
         * model is in reach when any of its probes is, and then all of them are. */
        const ub_llg_set *ls = base->llg;
        for (uint32_t m = 0; ls && m < ls->model_count; m++) {
          const ub_llg_model *md = &ls->models[m];
          uint32_t q0 = md->probe_first, q1 = q0 + md->dims[0] * md->dims[1] * md->dims[2];
          q1 = q1 < nlp ? q1 : nlp;
          uint32_t q = q0;
          while (q < q1 && !ub_dls_reach_point(&reach, ls->probe_pos + 3 * (size_t)q))
            q++;
          if (q < q1)
            for (q = q0; q < q1; q++)
              cl[ncl++] = q;
        }
      }
      if (own)
        ub_dls_reach_free(&reach);
      double dt = now_s() - tr;
      out_stats->seconds_reach += dt;
      out_stats->seconds_influence += dt;
    }
    out_stats->texels_candidate += nct;
    out_stats->probes_candidate += ncp;
    out_stats->llg_probes_candidate += ncl;
    /* 1. Influence: direct + NB bounces at a low sample count over the candidates. */
    ub_pass_desc pd = *base;
    pd.light_enabled = enabled;
    pd.emissive = 0;
    pd.sky = 0;
    pd.gather_rays = plan->influence_rays;
    pd.probe_rays = 2 * plan->influence_rays;
    pd.shadow_samples = 1;
    pd.near_samples = UB_NEAR_SAMPLES_DEFAULT;
    pd.bounces = (int)NB;
    /* Every bounce at the influence rays: its last bounce's per-texel value is the
     * culling estimate's tail, and light culled on a noisy estimate is lost for good. */
    pd.bounce_full_rays = 1;
    pd.pass_id = 2 + 2 * d;
    int sub = plan->influence_culling && !reach.unbounded;
    pd.texel_subset = sub ? ct : NULL;
    pd.texel_subset_count = nct;
    pd.probe_subset = sub ? cp : NULL;
    pd.probe_subset_count = ncp;
    pd.llg_subset = sub ? cl : NULL;
    pd.llg_subset_count = ncl;
    pd.keep_bounce_iz = NB;
    pd.no_error_estimate = 1; /* neither pass's texel_se / probe_se is read */
    pd.no_store = 1;          /* the keep rule reads the influence measures only */
    pd.texel_lights_everywhere = 1; /* ub_pass_desc; the full pass below sets it too */
    if (plan->influence_sparse) {
      if (!sub) /* no reach bound: every texel is a candidate */
        for (uint32_t t = 0; t < lm->texel_count; t++)
          ct[t] = t;
      uint32_t n = sub ? nct : lm->texel_count;
      pd.gather_donor = donor;
      pd.gather_subset = gat;
      pd.gather_subset_count = influence_donors(s, lm, ct, n, is_cand, donor, gat);
      out_stats->texels_gathering += pd.gather_subset_count;
    }
    if (llg_sparse) {
      if (!sub)
        for (uint32_t q = 0; q < nlp; q++)
          cl[q] = q;
      pd.llg_gather_donor = ldonor;
      pd.llg_gather_subset = lgat;
      pd.llg_gather_subset_count = llg_donors(base->llg, cl, sub ? ncl : nlp, lcand, ldonor, lgat);
      out_stats->llg_probes_gathering += pd.llg_gather_subset_count;
    }
    uint32_t npg = 0;
    if (pg.head && pgat) {
      if (!sub)
        for (uint32_t q = 0; q < base->probe_count; q++)
          cp[q] = q;
      uint32_t n = sub ? ncp : base->probe_count;
      npg = probe_sparse_pick(&pg, base->rt, base->probe_pos, cp, n, pgat);
      pd.probe_gather_subset = pgat;
      pd.probe_gather_subset_count = npg;
      out_stats->probes_gathering += npg;
    }
    pd.progress = NULL;
    double t0 = now_s();
    ub_pass_result inf;
    r = ub_pass_run(&pd, NULL, &inf);
    if (r != UB_OK)
      break;
    if (pd.probe_gather_subset)
      probe_fill_sparse(&pg, base->rt, base->probe_pos, cp, sub ? ncp : base->probe_count, pgat,
                        npg, inf.probe_indirect);
    out_stats->rays_influence += inf.rays_gather + inf.rays_shadow;
    out_stats->seconds_influence += now_s() - t0;
    /* The rule sees direct + NB bounces; when the full pass runs more (until converged),
     * a texel far from the lights gets most of its light from the later bounces. Its
     * indirect is then extrapolated by the geometric tail of its own last bounce (ratio
     * r = e_NB/e_(NB−1) of the influence pass): est = I + B_NB·r/(1−r). (Without it, at full
     * bounces estate_small's hall sets lost 1.3-1.5% of their light to culling, above the
     * 1% the rule means.) A full pass of at most NB bounces has no tail. */
    double tail = 0.0;
    if (full_tail && NB >= 1) {
      double r2 = inf.bounce_energy[NB - 1] > 0.0
                      ? inf.bounce_energy[NB] / inf.bounce_energy[NB - 1]
                      : 0.0;
      r2 = r2 < 0.0 ? 0.0 : (r2 > 0.95 ? 0.95 : r2);
      tail = r2 / (1.0 - r2);
    }
    const float *b2 = inf.texel_bounce_iz && NB >= 1
                          ? inf.texel_bounce_iz + (size_t)(NB - 1) * lm->texel_count * 3
                          : NULL;
    /* The influence pass wrote its candidates only (the subset): the measures are zero
     * elsewhere, so the rule reads those (ascending: the same sums) — not the whole
     * level's arrays per set, whose reads page-faulted in 0.5 M pages at ESTATE full scale. */
    const uint32_t *cand_t = sub ? ct : NULL, *cand_p = sub ? cp : NULL, *cand_l = sub ? cl : NULL;
    const uint32_t ncand_t = sub ? nct : lm->texel_count;
    const uint32_t ncand_p = sub ? ncp : base->probe_count, ncand_l = sub ? ncl : nlp;
    double ind_sum = 0.0;
    uint64_t lit = 0;
    for (uint32_t i = 0; i < ncand_t; i++) {
      uint32_t t = cand_t ? cand_t[i] : i;
      double last = b2 ? 0.2126 * b2[3 * (size_t)t] + 0.7152 * b2[3 * (size_t)t + 1] +
                             0.0722 * b2[3 * (size_t)t + 2]
                       : 0.0;
      est[t] = (float)(inf.texel_indirect[t] + (last > 0.0 ? last * tail : 0.0));
      if (inf.texel_direct[t] > 0.0f) {
        ind_sum += est[t];
        lit++;
      }
    }
    const double frac = full_tail ? UB_DLS_INFLUENCE_FRACTION : UB_DLS_INFLUENCE_FRACTION_EXACT;
    double thr = lit ? frac * ind_sum / lit : 0.0;
    const double frac_t = full_tail ? UB_DLS_INFLUENCE_FRACTION : UB_DLS_TEXEL_FRACTION_EXACT;
    const double thr_t = lit ? frac_t * ind_sum / lit : 0.0; /* texels (keep_estimate) */
    /* Probes: the same tail on their (DC) indirect, no per-probe bounce split: the
     * level's share of bounce NB in the first NB (no tail: factor 1). */
    double ind_e = 0.0;
    for (uint32_t k = 1; k <= NB; k++)
      ind_e += inf.bounce_energy[k];
    double ptail = 1.0 + (ind_e > 0.0 ? tail * inf.bounce_energy[NB] / ind_e : 0.0);
    uint32_t nkt = 0, nkp = 0, nkl = 0, nclosed = 0;
    /* --plan all keeps every receiver (no culling), to measure what culling drops. */
    /* a texel whose own estimate is below the threshold is kept when its neighbourhood's
     * mean is above it (keep_estimate); tsel: one byte per candidate */
    if (plan->influence_culling) {
      for (uint32_t i = 0; i < ncand_t; i++)
        is_cand[cand_t ? cand_t[i] : i] = 1;
      /* decided on every thread (each reads only est, is_cand and the lightmap), then
       * listed in order */
#pragma omp parallel for schedule(dynamic, 4096)
      for (uint32_t i = 0; i < ncand_t; i++) {
        uint32_t t = cand_t ? cand_t[i] : i;
        if (inf.texel_direct[t] > 0.0f || est[t] > thr_t ||
            keep_estimate(s, lm, is_cand, est, t) > thr_t)
          tsel[i] = 1;
        else
          tsel[i] = 0;
      }
      for (uint32_t i = 0; i < ncand_t; i++)
        if (tsel[i])
          is_cand[cand_t ? cand_t[i] : i] = 2;
      /* then the culled texels amid kept ones (keep_closed: one step, reading the
       * decisions above only, so the same on any thread count) */
#pragma omp parallel for schedule(dynamic, 4096)
      for (uint32_t i = 0; i < ncand_t; i++)
        if (!tsel[i] && keep_closed(s, lm, is_cand, cand_t ? cand_t[i] : i))
          tsel[i] = 2;
      for (uint32_t i = 0; i < ncand_t; i++) {
        uint32_t t = cand_t ? cand_t[i] : i;
        if (tsel[i])
          kt[nkt++] = t;
        nclosed += tsel[i] == 2;
        is_cand[t] = 0;
      }
    } else {
      for (uint32_t i = 0; i < ncand_t; i++)
        kt[nkt++] = cand_t ? cand_t[i] : i;
    }
    for (uint32_t i = 0; i < ncand_p; i++) {
      uint32_t q = cand_p ? cand_p[i] : i;
      if (!plan->influence_culling || inf.probe_direct[q] > 0.0f ||
          inf.probe_indirect[q] * ptail > thr)
        kp[nkp++] = q;
    }
    /* LLG probes: the GLG probes' rule (they are points in free space too). */
    for (uint32_t i = 0; i < ncand_l; i++) {
      uint32_t q = cand_l ? cand_l[i] : i;
      if (!plan->influence_culling || inf.llg_direct[q] > 0.0f ||
          inf.llg_indirect[q] * ptail > thr)
        kl[nkl++] = q;
    }
    /* Scaled rays: a kept receiver whose estimated indirect is a fraction f of the set's
     * reference (the mean over its directly lit texels, thr / frac)
     * gathers with the rays scaled to the power of two at or above f (at least
     * 2^-UB_DLS_RAY_SHIFT_MAX). Its absolute standard error then stays at or below a
     * reference texel's at full rays: σ ∝ I/√(N·f) = √(I·ref/N). */
    const uint64_t full_units =
        (uint64_t)nkt * plan->gather_rays + (uint64_t)(nkp + nkl) * plan->probe_rays;
    uint64_t units = full_units;
    if (scaled && thr > 0.0) {
      double ref = thr / frac;
      units = 0;
      for (uint32_t i = 0; i < nkt; i++) {
        tsh[kt[i]] = dls_ray_shift(est[kt[i]], ref);
        units += ub_pass_shifted_rays(plan->gather_rays, tsh[kt[i]]);
      }
      for (uint32_t i = 0; i < nkp; i++) {
        psh[kp[i]] = dls_ray_shift(inf.probe_indirect[kp[i]] * ptail, ref);
        units += ub_pass_shifted_rays(plan->probe_rays, psh[kp[i]]);
      }
      for (uint32_t i = 0; i < nkl; i++) {
        lsh[kl[i]] = dls_ray_shift(inf.llg_indirect[kl[i]] * ptail, ref);
        units += ub_pass_shifted_rays(plan->probe_rays, lsh[kl[i]]);
      }
    }
    out_stats->gather_units_full += full_units;
    out_stats->gather_units += units;
    if (nkt == 0 && nkp == 0 && nkl == 0) {
      ub_pass_result_recycle(&inf);
      out_stats->sets_empty++;
      if (out_stats->sets) { /* its influence pass ran */
        out_stats->sets[d].rays_influence = out_stats->rays_influence - ri0;
        out_stats->sets[d].seconds_influence = out_stats->seconds_influence - si0;
      }
      ub_log_printf(log, UB_LOG_INFO, "  dls %-16s: no receiver above the threshold: skipped",
                    rec->name);
      continue;
    }
    /* 2. Full quality, only for the kept receivers. */
    pd = *base;
    pd.light_enabled = enabled;
    pd.emissive = 0;
    pd.sky = 0;
    pd.pass_id = 3 + 2 * d;
    pd.no_error_estimate = 1;
    /* Texel lights wherever a block sees a lit texel: with the base pass's rule (the
     * brightest texel > UB_TL_PEAK× the mean seen) a receiver seeing the set's lit room
     * through a doorway took that light from rare gather hits only, at up to 8× their
     * full-rays weight where its rays were scaled. estate_small, draft, seeds 1-6 (`ubake
     * spread`): texel values over 0.5 of |median| + the record's mean 266 -> 23, the worst
     * 5.42 -> 1.88 (with full rays and the old rule: 88, 1.92); the full passes' rays 27.0
     * -> 34.7 M (the texel lights' shadow rays, an eighth of the full gather rays per
     * receiver: a fixed count, as that is what finds the faint receivers' rare hits; an
     * eighth of each receiver's own rays gave 110 and 2.57 for 28.6 M). */
    pd.texel_lights_everywhere = 1;
    pd.compact_store = 1; /* the record reads the kept rows only */
    pd.texel_subset = kt;
    pd.texel_subset_count = nkt;
    pd.probe_subset = kp;
    pd.probe_subset_count = nkp;
    pd.llg_subset = kl;
    pd.llg_subset_count = nkl;
    /* The culled texels are not simulated, but the influence pass's estimate of their
     * bounces 1..NB (beyond NB, scaled by the full pass's bounce energies) still lights
     * the kept ones: without it, the kept texels of estate_small's sets missed 0.5-1.5% of
     * their light at full bounces. */
    pd.outside_bounce_iz = plan->influence_culling ? inf.texel_bounce_iz : NULL;
    pd.outside_bounces = inf.texel_bounce_iz ? NB : 0;
    /* the influence pass ran over the candidates only: its estimate is zero elsewhere */
    pd.outside_candidates = sub ? ct : NULL;
    pd.outside_candidate_count = sub ? nct : 0;
    if (scaled) {
      pd.texel_ray_shift = tsh;
      pd.probe_ray_shift = psh;
      pd.llg_ray_shift = lsh;
    }
    pd.progress = NULL;
    t0 = now_s();
    ub_pass_result full;
    r = ub_pass_run(&pd, NULL, &full);
    ub_pass_result_recycle(&inf);
    if (r != UB_OK)
      break;
    out_stats->rays_full += full.rays_gather + full.rays_shadow;
    out_stats->seconds_full += now_s() - t0;
    r = full.compact ? ub_dls_texel_record_rows(lm, kt, nkt, full.sh, rec)
                     : ub_dls_texel_record(lm, kt, nkt, full.sh, rec);
    if (r == UB_OK && nkp) {
      rec->probe_index = malloc((size_t)nkp * sizeof *rec->probe_index);
      rec->probe_sh = malloc((size_t)nkp * 27 * sizeof *rec->probe_sh);
      if (!rec->probe_index || !rec->probe_sh) {
        r = UB_ERR_OUT_OF_MEMORY;
      } else {
        rec->probe_count = nkp;
        for (uint32_t i = 0; i < nkp; i++) {
          rec->probe_index[i] = kp[i];
          memcpy(rec->probe_sh + 27 * (size_t)i,
                 full.probe_sh + 27 * (size_t)(full.compact ? i : kp[i]), 27 * sizeof(float));
        }
      }
    }
    if (r == UB_OK && nkl) {
      rec->llg_probe_index = malloc((size_t)nkl * sizeof *rec->llg_probe_index);
      rec->llg_probe_sh = malloc((size_t)nkl * 27 * sizeof *rec->llg_probe_sh);
      if (!rec->llg_probe_index || !rec->llg_probe_sh) {
        r = UB_ERR_OUT_OF_MEMORY;
      } else {
        rec->llg_probe_count = nkl;
        for (uint32_t i = 0; i < nkl; i++) {
          rec->llg_probe_index[i] = kl[i];
          memcpy(rec->llg_probe_sh + 27 * (size_t)i, full.llg_sh + 27 * (size_t)kl[i],
                 27 * sizeof(float));
        }
      }
    }
    ub_pass_result_recycle(&full);
    if (scaled) { /* back to zero for the next set */
      for (uint32_t i = 0; i < nkt; i++)
        tsh[kt[i]] = 0;
      for (uint32_t i = 0; i < nkp; i++)
        psh[kp[i]] = 0;
      for (uint32_t i = 0; i < nkl; i++)
        lsh[kl[i]] = 0;
    }
    if (r != UB_OK)
      break;
    out_stats->sets_baked++;
    out_stats->texels_kept += nkt;
    out_stats->probes_kept += nkp;
    out_stats->llg_probes_kept += nkl;
    ub_dls_set_stats ss = {out_stats->rays_influence - ri0, out_stats->rays_full - rf0,
                           out_stats->seconds_influence - si0, out_stats->seconds_full - sf0};
    if (out_stats->sets)
      out_stats->sets[d] = ss;
    ub_log_printf(log, UB_LOG_INFO,
                  "  dls %-16s: %u light(s), %u of %u texels (%u amid kept ones), %u of %u "
                  "probes and %u of %u LLG probes in its influence (threshold %.3g W/m²; "
                  "reach bound %u texels, "
                  "%u probes, %u LLG probes), record %u pixels; influence %.2f M rays %.2f s, "
                  "full %.2f M rays %.2f s",
                  rec->name, reaching, nkt, lm->texel_count, nclosed, nkp, base->probe_count,
                  nkl, nlp,
                  thr, nct, ncp, ncl, rec->texel_count, ss.rays_influence * 1e-6,
                  ss.seconds_influence, ss.rays_full * 1e-6, ss.seconds_full);
  }
  if (r == UB_OK && plan->influence_culling && out_stats->sets_baked + out_stats->sets_empty)
    ub_log_printf(log, UB_LOG_INFO,
                  "  dls reach bound: %.1f M photon rays, %.2f s; influence passes over %llu "
                  "texels (%llu gathering), %llu probes (%llu gathering), %llu LLG probes "
                  "(%llu gathering) (%.2f%%, %.2f%%, %.2f%% of sets x level)",
                  out_stats->rays_reach * 1e-6, out_stats->seconds_reach,
                  (unsigned long long)out_stats->texels_candidate,
                  (unsigned long long)(plan->influence_sparse ? out_stats->texels_gathering
                                                              : out_stats->texels_candidate),
                  (unsigned long long)out_stats->probes_candidate,
                  (unsigned long long)(pg.head ? out_stats->probes_gathering
                                               : out_stats->probes_candidate),
                  (unsigned long long)out_stats->llg_probes_candidate,
                  (unsigned long long)(llg_sparse ? out_stats->llg_probes_gathering
                                                  : out_stats->llg_probes_candidate),
                  100.0 * out_stats->texels_candidate / ((double)s->dls_count * (lm->texel_count + 1)),
                  100.0 * out_stats->probes_candidate / ((double)s->dls_count * (base->probe_count + 1)),
                  100.0 * out_stats->llg_probes_candidate / ((double)s->dls_count * (nlp + 1)));
  ub_dls_texel_cells_free(&cells);
  free(est);
  free(tsh);
  free(psh);
  free(lsh);
  free(ldonor);
  free(lgat);
  free(lcand);
  free(donor);
  free(gat);
  free(is_cand);
  free(tsel);
  free(pg.head);
  free(pg.next);
  free(pgat);
  free(enabled);
  free(kt);
  free(kp);
  free(kl);
  free(ct);
  free(cp);
  free(cl);
  if (r != UB_OK) {
    ub_dls_records_free(recs, s->dls_count);
    return r;
  }
  *out_records = recs;
  return UB_OK;
}
