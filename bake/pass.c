/* Series-expansion pass over every receiver: lightmap texels and probes (see pass.h). */
#include "bake/pass.h"

#include <math.h>
#include <omp.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "probes/llg.h"
#include "ubake/sh.h"

/* Rays traced per block: large enough to sort into coherent streams, small enough that
 * a block's scratch stays a few megabytes. */
#define UB_BLOCK_RAYS 16384
#define UB_DIR_BUCKETS 64
/* Receiver ids for hashing: probes live above texels so their random numbers differ. */
#define UB_PROBE_ID_BASE 0x40000000u
/* Auto-stop: at most this share of the lit texels may still gain more than stop_fraction
 * of their own light in a bounce. */
#define UB_STOP_TEXEL_SHARE 0.01
/* Texel lights are used for a block of receivers when the brightest texel it can see
 * carries this many times the mean power of the texels it can see. */
#define UB_TL_PEAK 30.0
/* Texel lights closer than 2 texel widths are left to the gathers (squared: 4 texel
 * areas): there a texel is no small light, and its sample point stands for it badly. */
#define UB_TL_NEAR2 4.0f
/* Texel-light clusters: cells on the level's longest axis (× 6 normal directions). */
#define UB_TL_CELLS 16
#define UB_LLG_ID_BASE 0x60000000u

static const double UB_Y0 = 0.282094792;
static const double UB_Y1 = 0.488602512;

typedef struct tl_cluster {
  float lo[3], hi[3];   /* box of its texels (centres ± 1.5 texel sizes) */
  float nlo[3], nhi[3]; /* bounds of its texels' normal components */
  double power, peak;   /* this bounce: sum and maximum of its texels' power (W) */
  uint32_t n;           /* texels */
} tl_cluster;

/* One texel as the texel-light readers see it (a gather ray's hit, a texel-light sample):
 * the five values they read at a random texel in one 32-byte record, so each such read
 * costs one cache line instead of five separate arrays' (full ESTATE DLS, perf: those
 * five loads were a third of gather_block's samples, prefetched or not; one thread, the
 * sets' stage 4–8% faster at scale 0.12, 1.4% at full scale, where the one load stays the
 * hot spot). area, texel_area and of never change for a level; rad and pc are this
 * bounce's, zero where no light. */
typedef struct tl_texel {
  _Alignas(32) float rad[3]; /* outgoing radiance albedo/π·E of the previous bounce */
  float pc;                  /* probability of the texel within its cluster */
  float area;                /* = tl_area */
  float texel_area;          /* = lm->texel_area */
  uint32_t of;               /* = tl_of */
  float unused;
} tl_texel;
_Static_assert(sizeof(tl_texel) == 32, "tl_texel: one half cache line");

/* One kind of receiver, seen uniformly by the direct and gather kernels. */
typedef struct recv_set {
  int texels;            /* 1: lightmap texels (footprints known), 0: probes */
  uint32_t count;
  const uint32_t *index; /* active receivers (a pass's influence subset), NULL = all */
  uint32_t active;       /* receivers processed: index ? its length : count */
  const float *normal;   /* count × 3, or NULL: points gathering over the full sphere */
  const float *samples;  /* count × spr × 3: ray origins (already offset) */
  uint32_t spr;          /* sample points per receiver */
  uint32_t nsh;          /* SH coefficients per channel: 4 (L1) or 9 (L2) */
  uint32_t rays;         /* gather rays per receiver per bounce */
  const uint8_t *ray_shift; /* count entries, or NULL: receiver r's gathers of bounces >= 1
                               trace rays >> ray_shift[r] (recv_rays) */
  const uint8_t *pass_shift; /* the pass's own (ub_pass_desc.*_ray_shift), or NULL */
  uint8_t *bshift;       /* count entries or NULL: ray_shift once later bounces have faded
                            (bounce_shifts) */
  float *peak;           /* count entries: each receiver's brightest bounce so far */
  uint32_t id_base;
  const ub_rt *rt;       /* the geometry its rays see (LLG probes: the level without LLGs) */
  double *acc_sh_np;     /* bounce 0 only (LLG probes): its non-punctual part, or NULL */
  double *acc_sh;        /* count × nsh × 3, this bounce */
  double *acc_iz;        /* count × 3 (normal receivers), this bounce, stored result */
  double *acc_src;       /* count × 3, bounce 0 only: irradiance incl. primary lights */
  double *acc_src_np;    /* count × 3, bounce 0 only: its non-punctual part (sky, emitters) */
  double *acc_var;       /* count, this bounce: variance of the stored result's luminance
                            (texels: irradiance along the normal; probes: DC irradiance),
                            estimated from the samples themselves (see stratified_var) */
  double *acc_pvar;      /* count, this bounce: the part inherited from the noise of the
                            lightmap it reads (prop_var); rounds do not reduce it */
} recv_set;

/* The gather rays receiver r traces this bounce: rs->rays, or fewer where the pass asks
 * for them (ub_pass_desc.*_ray_shift, and from bounce 2 on bounce_shifts' per-receiver
 * shift: bounces >= 1 only; at least min(rays, 4)). */
static inline uint32_t recv_rays(uint32_t bounce, const recv_set *rs, uint32_t r)
{
  if (!rs->ray_shift || bounce < 1 || !rs->ray_shift[r])
    return rs->rays;
  return ub_pass_shifted_rays(rs->rays, rs->ray_shift[r]);
}

typedef struct pass_ctx {
  const ub_pass_desc *d;
  const ub_scene *s;
  const ub_lightmap *lm;
  int32_t *emitter_of;        /* triangle → emitter index, -1 (bounce 0 MIS) */
  float **img;                /* per atlas: w×h×4 (irradiance rgb, filled) of bounce k-1 */
  ub_lightmap_sparse *sparse; /* per atlas, a subset pass's sparse refills (or NULL) */
  const uint32_t *act;        /* a subset pass's texels that can hold light (or NULL: all) */
  uint32_t nact;
  uint8_t *tl_hot;            /* per cluster: holds an act texel (subset passes) */
  int tl_borrowed;            /* tl_list, tl_start belong to desc.cache (tl_area and tl_of
                                 NULL then: tl_tex has them) */
  recv_set sets[3];           /* 0: texels, 1: GLG probes, 2: LLG probes */
  const ub_llg_set *llg;      /* LLG models, or NULL */
  float *llg_prev;            /* LLG probes' SH of bounce k-1 (what LLG-lit hits read) */
  /* Texel lights (bounces ≥ 1): the previous bounce's texels as area lights, sampled in
   * proportion to their power and combined with the gather rays by the balance heuristic,
   * so a small bright spot (a sun patch, the ceiling above a lamp) is found by every
   * receiver instead of by a few gather rays (fireflies). */
  /* A texel is picked in two steps: a cluster (texels of one coarse cell whose normals
   * share a dominant axis) by a per-block table — its power over its distance to the
   * block, zero when it faces away from every point of the block (the sunlit roof above a
   * room) — then a texel of it in proportion to power. */
  tl_texel *tl_tex;           /* texel: what the readers read (radiance, share, areas,
                                 cluster), from tl_area, tl_of and this bounce's light */
  int tl_tex_borrowed;        /* tl_tex belongs to desc.cache (its rad and pc zeroed after) */
  float *tl_area;             /* texel: its square's world area (m²): its power, the near
                                 field; the strategy's density is per lm->texel_area */
  uint32_t *tl_of;            /* texel → cluster, UINT32_MAX: none (no area) */
  uint32_t *tl_start;         /* cluster → first entry of tl_list; tl_K + 1 entries */
  uint32_t *tl_list;          /* texels ordered by cluster */
  float *tl_ccdf;             /* tl_list order: cumulative power within the cluster, last 1 */
  struct tl_cluster *tl_cl;   /* tl_K clusters */
  uint32_t tl_K;
  int tl_on;                  /* some texel has power this bounce */
  int tl_full;                /* the tables hold all of bounce 0 (NEE on): a gather hit read
                                 as a texel light takes no separate punctual NEE */
  uint32_t tl_samples;        /* per receiver per bounce */
  int nee;                    /* bounce 1 takes punctual light at its hits by next-event
                                 estimation instead of reading the bounce-0 lightmap */
  uint32_t *light_on;         /* the enabled punctual lights, ascending (a set's pass has
                                 2 of ESTATE's 297: per gather hit, only those are looked at) */
  uint32_t light_on_count;
  uint32_t bounce;
  float *prev_rel2;           /* texel: relative variance (var/E²) of what this bounce reads
                                 from the lightmap (the previous bounce), or NULL */
  uint32_t seed;              /* d->seed in a bounce's first round; a hash of it and the
                                 round number in adaptive rounds (refine_bounce) */
  _Atomic uint64_t rays_gather, rays_shadow, clamped, backface, unlit, misses;
  _Atomic uint64_t rays_emissive, sky_hits, emitter_hits;
  _Atomic uint32_t blocks_done;
  _Atomic int cancelled;
} pass_ctx;

static inline float dot3(const float a[3], const float b[3])
{
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static inline void sh_accum(double *sh, uint32_t nsh, const float w[3], const float L[3],
                            double wt)
{
  float y[9];
  ub_sh2_eval_basis(w, y);
  for (uint32_t k = 0; k < nsh; k++)
    for (int c = 0; c < 3; c++)
      sh[k * 3 + c] += (double)y[k] * L[c] * wt;
}

static inline int finite3(const float v[3])
{
  return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

/* Direction bucket for sorting gather rays into coherent streams: octahedral 8×8. */
static inline uint32_t dir_bucket(const float w[3])
{
  float a = fabsf(w[0]) + fabsf(w[1]) + fabsf(w[2]);
  float u = w[0] / a, v = w[2] / a;
  if (w[1] < 0.0f) {
    float tu = (1.0f - fabsf(v)) * copysignf(1.0f, u);
    float tv = (1.0f - fabsf(u)) * copysignf(1.0f, v);
    u = tu;
    v = tv;
  }
  int iu = (int)((u * 0.5f + 0.5f) * 8.0f), iv = (int)((v * 0.5f + 0.5f) * 8.0f);
  iu = iu < 0 ? 0 : (iu > 7 ? 7 : iu);
  iv = iv < 0 ? 0 : (iv > 7 ? 7 : iv);
  return (uint32_t)(iv * 8 + iu);
}

static void tri_normal(const ub_scene *s, uint32_t t, float out[3])
{
  const float *a = s->positions + 3 * s->indices[3 * t];
  const float *b = s->positions + 3 * s->indices[3 * t + 1];
  const float *q = s->positions + 3 * s->indices[3 * t + 2];
  float e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
  float e2[3] = {q[0] - a[0], q[1] - a[1], q[2] - a[2]};
  float n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0]};
  float l = sqrtf(dot3(n, n));
  for (int i = 0; i < 3; i++)
    out[i] = l > 0.0f ? n[i] / l : 0.0f;
}

/* pdf (per steradian) of the gather direction w for a receiver: cosine about its normal,
 * or uniform over the sphere for a point receiver. */
static inline double gather_pdf(const float *nrm, const float w[3])
{
  return nrm ? fmax(0.0, dot3(nrm, w)) / M_PI : 1.0 / (4.0 * M_PI);
}

/* Point lights closer than this many texel widths get their irradiance averaged over the
 * texel's footprint with desc.near_samples jittered points (k × k strata) instead of the 4
 * fixed sample points: a 1/d² peak under a lamp is badly point-sampled (a lamp 10 cm under
 * a ceiling with 25 cm texels loses ~30% of the power the ceiling receives, and with it
 * the indirect light). */
#define UB_NEAR_TEXELS 6.0f

/* desc.near_samples as k × k strata (0 = UB_NEAR_SAMPLES_DEFAULT; at least 1). */
static uint32_t near_side(const ub_pass_desc *d)
{
  uint32_t n = d->near_samples ? d->near_samples : UB_NEAR_SAMPLES_DEFAULT, k = 1;
  while ((k + 1) * (k + 1) <= n && k < 64)
    k++;
  return k;
}

/* World width of a texel (metres) from its owning triangle's world/UV area ratio. */
static float texel_world_size(const pass_ctx *c, uint32_t t)
{
  float a[3], b[3], o[3];
  if (!ub_lightmap_texel_point(c->s, c->lm, t, 0.0f, 0.0f, o) ||
      !ub_lightmap_texel_point(c->s, c->lm, t, 1.0f, 0.0f, a) ||
      !ub_lightmap_texel_point(c->s, c->lm, t, 0.0f, 1.0f, b))
    return 0.0f;
  float da = sqrtf((a[0] - o[0]) * (a[0] - o[0]) + (a[1] - o[1]) * (a[1] - o[1]) +
                   (a[2] - o[2]) * (a[2] - o[2]));
  float db = sqrtf((b[0] - o[0]) * (b[0] - o[0]) + (b[1] - o[1]) * (b[1] - o[1]) +
                   (b[2] - o[2]) * (b[2] - o[2]));
  return fmaxf(da, db);
}

typedef struct shadow_rec {
  uint32_t recv;    /* local index in block */
  uint8_t primary;  /* 1 = counts only toward the next bounce's source */
  uint8_t emissive; /* an emissive-triangle sample (counted) */
  float dir[3];
  float e[3];       /* weights applied: SH gets e·Y(dir), I_z gets e·cos */
  float cos;
  /* Variance groups: the samples of one receiver's estimate of one quantity (a near light's
   * jittered footprint samples, its emissive samples, its texel-light samples), recorded
   * contiguously; grp_first marks a group's first record, grp_n its sample count (records
   * skipped before tracing count as zeros). grp_n 0: not random (fixed sample points).
   * grp_k: the sample's index in its group; grp_kx: the group's samples are stratified on
   * a grp_kx × grp_kx grid in index order (0: independent). */
  uint32_t grp_n, grp_k;
  uint8_t grp_first, grp_kx;
  int32_t src_texel; /* texel-light samples: the texel whose previous-bounce value it reads */
} shadow_rec;

/* Scratch for a block's shadow rays; 0 (and the pass cancelled as out of memory) if it
 * cannot be had. */
static int shadow_alloc(pass_ctx *c, size_t cap, ub_ray **rays, shadow_rec **rec, uint8_t **occ)
{
  *rays = malloc((cap ? cap : 1) * sizeof **rays);
  *rec = malloc((cap ? cap : 1) * sizeof **rec);
  *occ = malloc(cap ? cap : 1);
  if (*rays && *rec && *occ)
    return 1;
  free(*rays);
  free(*rec);
  free(*occ);
  atomic_store(&c->cancelled, 2);
  return 0;
}

/* Luminance a shadow record adds to its receiver's stored result: irradiance along the
 * normal (texels), DC irradiance π·Y0·(Y0·e) = e/4 (probes); 0 if occluded or primary. */
static double shadow_value(const recv_set *rs, const shadow_rec *sr, uint8_t occluded)
{
  if (occluded || sr->primary)
    return 0.0;
  double l = 0.2126 * sr->e[0] + 0.7152 * sr->e[1] + 0.0722 * sr->e[2];
  return rs->normal ? l * sr->cos : 0.25 * l;
}

/* Variance of a sum Σc over n samples c[0..n) (each already divided by n), estimated
 * from the samples. The first kx·ky samples are stratified (sample j in cell (j mod kx,
 * j div kx) of a jittered grid): the plain sample variance would overstate their variance
 * (it counts the variation between cells, which stratification removes), so cells are
 * paired with a neighbour along a serpentine walk and Var ≈ Σ_pairs (c_a − c_b)²
 * (collapsed strata; exact when paired cells have equal means, conservative otherwise).
 * An unpaired last cell and the samples past the grid (independent over the whole domain)
 * add (c − mean)². kx = ky = 0: all independent, the unbiased n/(n−1)·Σ(c − mean)². */
static double stratified_var(const double *c, uint32_t n, uint32_t kx, uint32_t ky)
{
  if (n < 2)
    return 0.0;
  double sum = 0.0;
  for (uint32_t j = 0; j < n; j++)
    sum += c[j];
  double mean = sum / n, v = 0.0;
  uint32_t ns = kx * ky <= n ? kx * ky : 0, prev = 0;
  for (uint32_t q = 0; q < ns; q++) {
    uint32_t row = q / kx, col = q % kx;
    uint32_t j = row * kx + (row & 1 ? kx - 1 - col : col);
    if (q & 1) {
      double dd = c[j] - c[prev];
      v += dd * dd;
    } else {
      prev = j;
    }
  }
  if (ns & 1)
    v += (c[prev] - mean) * (c[prev] - mean);
  for (uint32_t j = ns; j < n; j++)
    v += (c[j] - mean) * (c[j] - mean);
  if (ns == 0)
    v *= (double)n / (n - 1);
  return v > 0.0 && isfinite(v) ? v : 0.0;
}

/* One sample's reading of the previous bounce's lightmap: the texel and the luminance it
 * added. */
typedef struct prop_read {
  uint32_t t;
  double c;
} prop_read;

#define PROP_STACK_SLOTS 1024

/* Variance a receiver inherits from the noise of the lightmap values its samples read:
 * each texel t's value has relative variance rel2[t] (independent between texels), and
 * every sample that read t scales with it, so Var ≈ Σ_t (Σ_{samples reading t} c)²·rel2[t]
 * (samples reading the same texel err together). The per-texel sums in an open-addressing
 * table (twice the samples, at least), summed in order of first reading: a qsort per
 * receiver per bounce here was a tenth of a bake's profile (perf, estate_small draft). */
static double prop_var(const prop_read *p, uint32_t n, const float *rel2)
{
  if (!n || !rel2)
    return 0.0;
  uint32_t bits = 1;
  while ((1u << bits) < 2 * n && bits < 31)
    bits++;
  uint32_t size = 1u << bits, mask = size - 1;
  uint32_t key_s[PROP_STACK_SLOTS], first_s[PROP_STACK_SLOTS / 2];
  double sum_s[PROP_STACK_SLOTS];
  uint32_t *key = key_s, *first = first_s;
  double *sum = sum_s;
  void *heap = NULL;
  if (size > PROP_STACK_SLOTS) {
    heap = malloc((size_t)size * (sizeof *key + sizeof *sum) + (size_t)n * sizeof *first);
    if (!heap)
      return 0.0; /* the estimate only: the bake goes on */
    sum = heap;
    key = (uint32_t *)(sum + size);
    first = key + size;
  }
  memset(key, 0xff, (size_t)size * sizeof *key);
  uint32_t used = 0;
  for (uint32_t i = 0; i < n; i++) {
    uint32_t h = (uint32_t)(p[i].t * 0x9E3779B1u) >> (32 - bits);
    while (key[h] != p[i].t && key[h] != UINT32_MAX)
      h = (h + 1) & mask;
    if (key[h] == UINT32_MAX) {
      key[h] = p[i].t;
      sum[h] = 0.0;
      first[used++] = h;
    }
    sum[h] += p[i].c;
  }
  double v = 0.0;
  for (uint32_t u = 0; u < used; u++) {
    uint32_t h = first[u];
    v += sum[h] * sum[h] * rel2[key[h]];
  }
  free(heap);
  return v > 0.0 && isfinite(v) ? v : 0.0;
}

/* Adds each variance group's variance of its sum to its receiver's acc_var. */
static void shadow_var(const recv_set *rs, uint32_t r0, const shadow_rec *rec,
                       const uint8_t *occ, size_t n, const float *c_prev_rel2)
{
  uint32_t gmax = 0;
  for (size_t j = 0; j < n; j++)
    gmax = rec[j].grp_n > gmax ? rec[j].grp_n : gmax;
  if (gmax < 2)
    return;
  double *buf = calloc(gmax, sizeof *buf);
  prop_read *pr = malloc(gmax * sizeof *pr);
  if (!buf || !pr) {
    free(buf);
    free(pr);
    return; /* the estimate only: the bake itself goes on */
  }
  for (size_t j = 0; j < n;) {
    size_t e = j + 1;
    while (e < n && !rec[e].grp_first)
      e++;
    uint32_t gn = rec[j].grp_n;
    if (gn > 1) {
      memset(buf, 0, gn * sizeof *buf);
      uint32_t np = 0;
      for (size_t k = j; k < e; k++)
        if (rec[k].grp_k < gn) {
          buf[rec[k].grp_k] = shadow_value(rs, &rec[k], occ[k]);
          if (rec[k].src_texel >= 0 && np < gmax) {
            pr[np].t = (uint32_t)rec[k].src_texel;
            pr[np++].c = buf[rec[k].grp_k];
          }
        }
      uint32_t kx = rec[j].grp_kx;
      uint32_t r = rs->index ? rs->index[r0 + rec[j].recv] : r0 + rec[j].recv;
      rs->acc_var[r] += stratified_var(buf, gn, kx, kx);
      rs->acc_pvar[r] += prop_var(pr, np, c_prev_rel2);
    }
    j = e;
  }
  free(buf);
  free(pr);
}

/* Traces a block's shadow rays (unless occ already holds them: traced) and adds the
 * unoccluded ones to their receivers: the stored result (not for primary lights), the
 * next bounce's source (bounce 0) and its non-punctual part. Frees the scratch. */
static void shadow_flush(pass_ctx *c, const recv_set *rs, uint32_t r0, ub_ray *rays,
                         shadow_rec *rec, uint8_t *occ, size_t n, int traced)
{
  if (!traced)
    ub_rt_occluded(rs->rt, rays, (uint32_t)n, occ);
  atomic_fetch_add(&c->rays_shadow, n);
  uint64_t nem = 0;
  for (size_t j = 0; j < n; j++)
    nem += rec[j].emissive;
  atomic_fetch_add(&c->rays_emissive, nem);
  if (rs->acc_var && rs->acc_pvar)
    shadow_var(rs, r0, rec, occ, n, c->prev_rel2);
  for (size_t j = 0; j < n; j++) {
    if (occ[j])
      continue;
    const shadow_rec *sr = &rec[j];
    uint32_t r = rs->index ? rs->index[r0 + sr->recv] : r0 + sr->recv;
    if (rs->acc_src)
      for (int ch = 0; ch < 3; ch++)
        rs->acc_src[3 * (size_t)r + ch] += (double)sr->e[ch] * sr->cos;
    if (rs->acc_src_np && sr->emissive)
      for (int ch = 0; ch < 3; ch++)
        rs->acc_src_np[3 * (size_t)r + ch] += (double)sr->e[ch] * sr->cos;
    if (sr->primary)
      continue;
    if (rs->acc_sh_np && sr->emissive)
      sh_accum(rs->acc_sh_np + (size_t)rs->nsh * 3 * r, rs->nsh, sr->dir, sr->e, 1.0);
    if (rs->acc_iz)
      for (int ch = 0; ch < 3; ch++)
        rs->acc_iz[3 * (size_t)r + ch] += (double)sr->e[ch] * sr->cos;
    if (rs->acc_sh)
      sh_accum(rs->acc_sh + (size_t)rs->nsh * 3 * r, rs->nsh, sr->dir, sr->e, 1.0);
  }
  free(rays);
  free(rec);
  free(occ);
}

static inline size_t hit_pixel(const ub_lightmap *lm, const ub_atlas *at, const ub_hit *h,
                               float out_uv[2]);

/* Whether point q on the plane of texel t's owning triangle, past that triangle's edges,
 * still lies on a surface that the lightmap maps to texel t (a coplanar neighbour of its
 * chart), not past the chart's edge in the open or inside a wall: a short ray along the
 * triangle's normal through q must hit such a surface there. */
static int on_texel(const pass_ctx *c, uint32_t t, const float q[3])
{
  const ub_lightmap *lm = c->lm;
  float ng[3];
  tri_normal(c->s, lm->texel_tri[t], ng);
  float e = 4.0f * ub_rt_epsilon(c->d->rt, q);
  ub_ray ray;
  for (int k = 0; k < 3; k++) {
    ray.org[k] = q[k] + e * ng[k];
    ray.dir[k] = -ng[k];
  }
  ray.tnear = 0.0f;
  ray.tfar = 2.0f * e;
  ub_hit h;
  ub_rt_intersect(c->d->rt, &ray, 1, &h);
  if (h.tri == UB_RT_MISS || lm->tri_atlas[h.tri] != (int32_t)lm->texel_atlas[t])
    return 0;
  float uv[2];
  const ub_atlas *at = &lm->atlases[lm->texel_atlas[t]];
  return at->texel_of[hit_pixel(lm, at, &h, uv)] == (int32_t)t;
}

/* Rays j < n in a stable order by key[j] < nkeys (counting sort; start: nkeys + 1
 * counters): sorted[i] = rays[order[i]]. The gathers by direction bucket, the shadow rays
 * by light: runs Embree traces as packets. */
static void sort_rays(const ub_ray *rays, const uint32_t *key, size_t n, uint32_t nkeys,
                      uint32_t *start, uint32_t *order, ub_ray *sorted)
{
  memset(start, 0, ((size_t)nkeys + 1) * sizeof *start);
  for (size_t j = 0; j < n; j++)
    start[key[j] + 1]++;
  for (uint32_t q = 0; q < nkeys; q++)
    start[q + 1] += start[q];
  for (size_t j = 0; j < n; j++) {
    uint32_t dst = start[key[j]]++;
    order[dst] = (uint32_t)j;
    sorted[dst] = rays[j];
  }
}

/* The occlusion of a block's n shadow rays (occ), traced grouped by light (slot[j] <
 * slots: ray j's light): the rays of one light leave nearby receivers toward one point,
 * which Embree traces as packets (ub_rt_occluded_sorted). 0 without memory (the caller
 * traces them as they are). Full ESTATE, base pass (33 lights), one thread each, two runs
 * at once, order swapped: 95.1 / 97.7 s in the rays' order, 89.0 / 93.5 s grouped, the same
 * answers; oa_dm4 (13.5 M shadow rays of 143 M, emitters' samples too) within 2%. */
static int trace_by_light(const ub_rt *rt, const ub_ray *rays, const uint32_t *slot,
                          uint32_t slots, size_t n, uint8_t *occ)
{
  uint32_t *start = malloc(((size_t)slots + 1) * sizeof *start);
  uint32_t *order = malloc((n ? n : 1) * sizeof *order);
  ub_ray *sorted = malloc((n ? n : 1) * sizeof *sorted);
  uint8_t *socc = malloc(n ? n : 1);
  int ok = start && order && sorted && socc;
  if (ok) {
    sort_rays(rays, slot, n, slots, start, order, sorted); /* a light's rays in receiver order */
    ub_rt_occluded_sorted(rt, sorted, (uint32_t)n, socc);
    for (size_t j = 0; j < n; j++)
      occ[order[j]] = socc[j];
  }
  free(start);
  free(order);
  free(sorted);
  free(socc);
  return ok;
}

/* Bounce 0: punctual lights and emissive area samples with shadow rays. */
static void direct_block(pass_ctx *c, const recv_set *rs, uint32_t r0, uint32_t nr)
{
  const ub_pass_desc *d = c->d;
  const ub_scene *s = c->s;
  uint32_t nlights = c->light_on_count;
  uint32_t ns = d->shadow_samples ? d->shadow_samples : 1;
  if (ns > rs->spr)
    ns = rs->spr;
  uint32_t ne = (d->emissive && d->emitters && d->emitters->count) ? d->emissive_samples : 0;
  uint32_t nside = near_side(d), nnear = nside * nside;
  size_t per = (size_t)nlights * (rs->texels && ns < nnear ? nnear : ns) + ne;
  if (per == 0)
    return;
  size_t cap = per * nr;
  ub_ray *rays;
  shadow_rec *rec;
  uint8_t *occ;
  if (!shadow_alloc(c, cap, &rays, &rec, &occ))
    return;
  size_t n = 0;
  uint32_t N = rs->rays;
  int mis_gather = d->sky || ne; /* gather rays also see emitters in bounce 0 */
  /* a near texel's footprint points kept; without memory the sample points stand in */
  float *fp = rs->texels ? malloc((size_t)nnear * 3 * sizeof *fp) : NULL;
  uint32_t *slot = malloc((cap ? cap : 1) * sizeof *slot); /* a ray's light (trace_by_light) */
  /* the receiver's emitter probabilities (ub_emitters_local_cdf), as gather_block's MIS */
  float *ebuf = ne ? malloc((size_t)d->emitters->count * sizeof *ebuf) : NULL;
  if (ne && !ebuf) {
    atomic_store(&c->cancelled, 2); /* (out of memory: as shadow_alloc) */
    ne = 0;
  }
  for (uint32_t i = 0; i < nr; i++) {
    uint32_t r = rs->index ? rs->index[r0 + i] : r0 + i;
    const float *nrm = rs->normal ? rs->normal + 3 * (size_t)r : NULL;
    float tw = -1.0f; /* texel width, computed on first need */
    for (uint32_t li = 0; li < nlights; li++) {
      uint32_t l = c->light_on[li];
      const ub_light *L = &s->lights[l];
      /* Near a point or spot light: average over the texel's footprint. */
      uint32_t nk = ns;
      int near = 0;
      if (rs->texels && L->type != UB_LIGHT_DIRECTIONAL) {
        const float *tp = c->lm->texel_pos + 3 * (size_t)r;
        float dl = sqrtf((L->position[0] - tp[0]) * (L->position[0] - tp[0]) +
                         (L->position[1] - tp[1]) * (L->position[1] - tp[1]) +
                         (L->position[2] - tp[2]) * (L->position[2] - tp[2]));
        if (tw < 0.0f)
          tw = texel_world_size(c, r);
        if (tw > 0.0f && dl < UB_NEAR_TEXELS * tw) {
          near = 1;
          nk = nnear;
        }
      }
      /* Near: stratified nside × nside jittered positions over the texel, on its plane;
       * those off its surface are dropped and the rest averaged. At a chart's edge part of
       * the square lies past the surface (a wall's top texels above the ceiling, a door
       * leaf's edge inside the jamb), where a point on the plane is in the dark: the edge
       * texels of a wall under a lamp read half its light. When none is on it (a
       * degenerate UV), the texel's sample points, as for a far light. */
      uint32_t nacc = nk;
      if (near && fp) {
        nacc = 0;
        for (uint32_t k = 0; k < nk; k++) {
          uint32_t h = ub_hash4(c->seed, d->pass_id * 0x10000u + 0x4000u + l, r, k);
          float inv = 1.0f / (float)nside;
          float fx = ((float)(k % nside) + ub_u01(h)) * inv;
          float fy = ((float)(k / nside) + ub_u01(ub_hash4(h, 3, 0, 0))) * inv;
          float q[3];
          int on = ub_lightmap_texel_point(c->s, c->lm, r, fx, fy, q);
          if (on == 1 || (on == 2 && on_texel(c, r, q))) {
            ub_rt_offset_point(d->rt, q, nrm, fp + 3 * (size_t)nacc++);
          }
        }
        if (!nacc) {
          near = 0;
          nk = nacc = ns;
        }
      }
      int first = 1; /* the next record starts this light's variance group */
      for (uint32_t k = 0; k < nacc; k++) {
        const float *p = near && fp ? fp + 3 * (size_t)k
                                    : rs->samples + ((size_t)r * rs->spr + k % rs->spr) * 3;
        float dir[3], dist, e[3];
        if (!ub_light_incident(L, p, dir, &dist, e))
          continue;
        float cs = nrm ? dot3(nrm, dir) : 1.0f;
        if (cs <= 0.0f)
          continue;
        shadow_rec *sr = &rec[n];
        sr->recv = i;
        sr->primary = L->cls == UB_LIGHT_PRIMARY;
        sr->emissive = 0;
        memcpy(sr->dir, dir, sizeof dir);
        for (int ch = 0; ch < 3; ch++)
          sr->e[ch] = e[ch] / (float)nacc;
        sr->cos = cs;
        /* Random only near the light (jittered footprint samples); elsewhere the texel's
         * fixed sample points: a quadrature, the same for every seed. The strata stand
         * only when every one kept its sample. */
        int all = nacc == nk;
        sr->grp_n = near && fp && !sr->primary ? nacc : 0;
        sr->grp_k = k;
        sr->grp_kx = (uint8_t)(all ? nside : 0);
        sr->grp_first = (uint8_t)first;
        sr->src_texel = -1;
        first = 0;
        ub_ray *ray = &rays[n];
        memcpy(ray->org, p, sizeof ray->org);
        memcpy(ray->dir, dir, sizeof dir);
        ray->tnear = 0.0f;
        ray->tfar = isfinite(dist) ? dist * (1.0f - 1e-4f) : INFINITY;
        if (slot)
          slot[n] = li;
        n++;
      }
    }
    int efirst = 1;
    const float *ecdf = !ne                   ? NULL
                        : d->emitters_by_power ? d->emitters->cdf
                                               : ub_emitters_local_cdf(
                                                     d->emitters,
                                                     rs->samples + (size_t)r * rs->spr * 3,
                                                     nrm, ebuf);
    for (uint32_t k = 0; k < ne; k++) {
      uint32_t h = ub_hash4(c->seed, d->pass_id * 0x10000u + 0x8000u, rs->id_base + r, k);
      float u0 = ub_u01(h), u1 = ub_u01(ub_hash4(h, 1, 0, 0)), u2 = ub_u01(ub_hash4(h, 2, 0, 0));
      const float *p = rs->samples + ((size_t)r * rs->spr + k % rs->spr) * 3;
      float q[3], qn[3], le[3], pdf_area;
      ub_emitters_sample_cdf(d->emitters, ecdf, s, u0, u1, u2, q, qn, le, &pdf_area);
      float w[3] = {q[0] - p[0], q[1] - p[1], q[2] - p[2]};
      float d2 = dot3(w, w);
      if (!(d2 > 0.0f) || !(pdf_area > 0.0f))
        continue;
      float dist = sqrtf(d2);
      for (int ch = 0; ch < 3; ch++)
        w[ch] /= dist;
      float cs = nrm ? dot3(nrm, w) : 1.0f, ce = -dot3(qn, w);
      if (cs <= 0.0f || ce <= 0.0f)
        continue;
      double pdf_sa = (double)pdf_area * d2 / ce;
      /* Balance heuristic with the gather rays of bounce 0 (sample counts ne and N). */
      double denom = ne * pdf_sa + (mis_gather ? N * gather_pdf(nrm, w) : 0.0);
      shadow_rec *sr = &rec[n];
      sr->recv = i;
      sr->primary = 0;
      sr->emissive = 1;
      memcpy(sr->dir, w, sizeof w);
      for (int ch = 0; ch < 3; ch++)
        sr->e[ch] = (float)(le[ch] / denom);
      sr->cos = cs;
      if (!finite3(sr->e)) {
        atomic_fetch_add(&c->clamped, 1);
        continue;
      }
      sr->grp_n = ne;
      sr->grp_k = k;
      sr->grp_kx = 0;
      sr->grp_first = (uint8_t)efirst;
      sr->src_texel = -1;
      efirst = 0;
      ub_ray *ray = &rays[n];
      memcpy(ray->org, p, sizeof ray->org);
      memcpy(ray->dir, w, sizeof w);
      ray->tnear = 0.0f;
      ray->tfar = dist - 2.0f * ub_rt_epsilon(d->rt, q);
      if (slot)
        slot[n] = nlights; /* the emitters' samples after the lights' */
      n++;
    }
  }
  free(fp);
  free(ebuf);
  int traced = slot && trace_by_light(rs->rt, rays, slot, nlights + 1, n, occ);
  shadow_flush(c, rs, r0, rays, rec, occ, n, traced);
  free(slot);
}

/* Next-event estimation at bounce-1 hits (shadow rays against the whole level, also for
 * LLG probes, whose own rays ignore the LLG models: the surfaces they see are lit as the
 * level really is): the punctual lights' direct irradiance at each
 * hit point, one light chosen per hit in proportion to its unoccluded irradiance there and
 * one shadow ray. Reading it from the bounce-0 lightmap instead turns the bright, small
 * spots next to lamps into fireflies (a gather ray rarely hits them, and then very hard).
 * Returns per-ray outgoing radiance albedo/π·E (n × 3), or NULL (no light, no memory). */
static float *nee_block(pass_ctx *c, const ub_rt *rt, const ub_ray *rays, const ub_hit *hits,
                        const uint32_t *sorted_of, const uint8_t *skip, size_t n, uint32_t id)
{
  const ub_pass_desc *d = c->d;
  const ub_scene *s = c->s;
  float *nee = calloc(n * 3, sizeof *nee);
  ub_ray *sr = malloc(n * sizeof *sr);
  uint32_t *sj = malloc(n * sizeof *sj);
  float *se = malloc(n * 3 * sizeof *se);
  uint8_t *occ = malloc(n);
  const uint32_t *on = c->light_on, non = c->light_on_count;
  float *w = malloc((non + 1) * sizeof *w);
  if (!nee || !sr || !sj || !se || !occ || !w) {
    free(nee);
    free(sr);
    free(sj);
    free(se);
    free(occ);
    free(w);
    return NULL;
  }
  /* ub_hash4(seed, key, id, j) for the pick below */
  uint32_t hb = ub_hash_mix(ub_hash_mix(ub_hash_mix(UB_HASH_SEED, c->seed),
                                        d->pass_id * 0x10000u + 0x2000u), id);
  size_t m = 0;
  for (size_t j = 0; j < n; j++) {
    const ub_hit *h = &hits[sorted_of[j]];
    const ub_ray *ray = &rays[j];
    if ((skip && skip[j]) || h->tri == UB_RT_MISS || dot3(h->ng, ray->dir) >= 0.0f)
      continue;
    float len = sqrtf(dot3(h->ng, h->ng));
    if (!(len > 0.0f))
      continue;
    float hn[3] = {h->ng[0] / len, h->ng[1] / len, h->ng[2] / len};
    float hp[3] = {ray->org[0] + h->t * ray->dir[0], ray->org[1] + h->t * ray->dir[1],
                   ray->org[2] + h->t * ray->dir[2]};
    float po[3];
    ub_rt_offset_point(rt, hp, hn, po);
    double total = 0.0;
    for (uint32_t k = 0; k < non; k++) {
      w[k] = 0.0f;
      float dir[3], dist, e[3];
      if (!ub_light_incident(&s->lights[on[k]], po, dir, &dist, e))
        continue;
      float cs = dot3(hn, dir);
      if (cs <= 0.0f)
        continue;
      w[k] = (0.2126f * e[0] + 0.7152f * e[1] + 0.0722f * e[2]) * cs;
      total += w[k];
    }
    if (!(total > 0.0))
      continue;
    double u = ub_u01(ub_hash_mix(hb, (uint32_t)j)) * total;
    uint32_t pick = 0;
    double acc = 0.0;
    for (uint32_t k = 0; k < non; k++) {
      if (w[k] <= 0.0f)
        continue;
      pick = k;
      acc += w[k];
      if (u < acc)
        break;
    }
    float dir[3], dist, e[3];
    ub_light_incident(&s->lights[on[pick]], po, dir, &dist, e);
    double scale = dot3(hn, dir) * total / w[pick];
    const float *alb = s->materials[s->tri_material[h->tri]].albedo;
    for (int ch = 0; ch < 3; ch++)
      se[3 * m + ch] = (float)(alb[ch] * M_1_PI * e[ch] * scale);
    memcpy(sr[m].org, po, sizeof po);
    memcpy(sr[m].dir, dir, sizeof dir);
    sr[m].tnear = 0.0f;
    sr[m].tfar = isfinite(dist) ? dist * (1.0f - 1e-4f) : INFINITY;
    sj[m] = (uint32_t)j;
    m++;
  }
  ub_rt_occluded(rt, sr, (uint32_t)m, occ);
  atomic_fetch_add(&c->rays_shadow, m);
  for (size_t k = 0; k < m; k++)
    if (!occ[k] && isfinite(se[3 * k]) && isfinite(se[3 * k + 1]) && isfinite(se[3 * k + 2]))
      memcpy(nee + 3 * (size_t)sj[k], se + 3 * k, 3 * sizeof(float));
  free(sr);
  free(sj);
  free(se);
  free(occ);
  free(w);
  return nee;
}

/* Receivers share a texel-light table by the dominant axis of their normal (6 groups) or
 * have none (probes, group 6). */
#define UB_TL_GROUPS 7
static inline int tl_group(const float *nrm)
{
  if (!nrm)
    return 6;
  int ax = fabsf(nrm[0]) >= fabsf(nrm[1]) ? (fabsf(nrm[0]) >= fabsf(nrm[2]) ? 0 : 2)
                                          : (fabsf(nrm[1]) >= fabsf(nrm[2]) ? 1 : 2);
  return 2 * ax + (nrm[ax] < 0.0f);
}

/* max of n·d over n in [nlo, nhi] and d in [dl, dh], per axis (interval bound) */
static inline double dot_bound(const float nlo[3], const float nhi[3], const double dl[3],
                               const double dh[3])
{
  double m = 0.0;
  for (int j = 0; j < 3; j++)
    m += fmax(fmax(nlo[j] * dl[j], nlo[j] * dh[j]), fmax(nhi[j] * dl[j], nhi[j] * dh[j]));
  return m;
}

/* Receivers per round of tl_pick_round: their texel-light picks' lines (~6 each, M picks a
 * receiver) stay in L1/L2 until texel_light_block reads them. */
#define UB_TL_PICK_RECV 16

/* A texel-light sample's texel and cluster (t = UINT32_MAX: an empty cluster) and which of
 * the texel's sample points it starts from. */
typedef struct tl_pick {
  uint32_t cl, t, sp;
} tl_pick;

/* The picks of receivers i0 .. i1-1 of a block (out[(i - i0) · M + k]), with the draws
 * texel_light_block made inline before (same hashes, same order), and their texels' data
 * asked of the memory system: each pick is a chain of random reads (cluster table, texel
 * list, then the texel's sample point, area, normal, radiance) that stalled the sample
 * loop on every sample (es25 DLS: the sample point's load was the hottest instruction of
 * the bounce kernels after the gather's); a round of independent picks overlaps them. */
static void tl_pick_round(const pass_ctx *c, const recv_set *rs, uint32_t r0, uint32_t i0,
                          uint32_t i1, const float *const *tl, uint32_t hk, tl_pick *out)
{
  const ub_lightmap *lm = c->lm;
  uint32_t M = c->tl_samples, K = c->tl_K;
  for (uint32_t i = i0; i < i1; i++) {
    uint32_t r = rs->index ? rs->index[r0 + i] : r0 + i;
    const float *cdf = tl[tl_group(rs->normal ? rs->normal + 3 * (size_t)r : NULL)];
    uint32_t hr = ub_hash_mix(hk, rs->id_base + r);
    for (uint32_t k = 0; cdf && k < M; k++) {
      tl_pick *o = &out[(size_t)(i - i0) * M + k];
      uint32_t h = ub_hash_mix(hr, k);
      uint32_t cl = ub_cdf_pick(cdf, K, ub_u01(h));
      uint32_t b0 = c->tl_start[cl], b1 = c->tl_start[cl + 1];
      o->cl = cl;
      o->t = UINT32_MAX;
      if (b1 <= b0)
        continue;
      uint32_t t = c->tl_list[b0 + ub_cdf_pick(c->tl_ccdf + b0, b1 - b0,
                                               ub_u01(ub_hash4(h, 3, 0, 0)))];
      o->t = t;
      o->sp = ub_hash4(h, 1, 0, 0) % UB_TEXEL_SAMPLES;
      const float *qo = lm->sample_pos + ((size_t)t * UB_TEXEL_SAMPLES + o->sp) * 3;
      __builtin_prefetch(qo);
      __builtin_prefetch(qo + 2); /* the point may straddle two lines */
      __builtin_prefetch(&c->tl_tex[t]);
      __builtin_prefetch(lm->texel_normal + 3 * (size_t)t);
    }
  }
}

/* Bounces ≥ 1: samples toward the previous bounce's texels as area lights (see tl_*);
 * tl: the block's cluster tables per receiver group (tl_block_table), NULL where off. */
static void texel_light_block(pass_ctx *c, const recv_set *rs, uint32_t r0, uint32_t nr,
                              const float *const *tl)
{
  const ub_pass_desc *d = c->d;
  const ub_lightmap *lm = c->lm;
  uint32_t M = c->tl_samples;
  size_t cap = (size_t)M * nr;
  ub_ray *rays;
  shadow_rec *rec;
  uint8_t *occ;
  if (!shadow_alloc(c, cap, &rays, &rec, &occ))
    return;
  size_t n = 0;
  uint32_t hk = ub_hash_mix(ub_hash_mix(UB_HASH_SEED, c->seed),
                            d->pass_id * 0x10000u + 0x1000u + c->bounce);
  tl_pick *pk = malloc((size_t)UB_TL_PICK_RECV * M * sizeof *pk);
  if (!pk) {
    atomic_store(&c->cancelled, 2);
    free(rays);
    free(rec);
    free(occ);
    return;
  }
  for (uint32_t i = 0; i < nr; i++) {
    if (i % UB_TL_PICK_RECV == 0)
      tl_pick_round(c, rs, r0, i, nr - i < UB_TL_PICK_RECV ? nr : i + UB_TL_PICK_RECV, tl, hk,
                    pk);
    uint32_t r = rs->index ? rs->index[r0 + i] : r0 + i;
    const float *nrm = rs->normal ? rs->normal + 3 * (size_t)r : NULL;
    const float *cdf = tl[tl_group(nrm)];
    uint32_t N = recv_rays(c->bounce, rs, r); /* the gather's rays, for the MIS weight */
    int first = 1;
    uint32_t hr = ub_hash_mix(hk, rs->id_base + r); /* the picks' too (tl_pick_round) */
    uint32_t po = rs->spr > 1 ? ub_hash4(hr, 13, 0, 0) % rs->spr : 0;
    for (uint32_t k = 0; cdf && k < M; k++) {
      const tl_pick *pq = &pk[(size_t)(i % UB_TL_PICK_RECV) * M + k];
      uint32_t cl = pq->cl, t = pq->t;
      if (t == UINT32_MAX)
        continue;
      const tl_texel *tt = &c->tl_tex[t];
      if (!(tt->area > 0.0f))
        continue;
      /* One of the texel's sample points (already off the surface): the points its value
       * was gathered at, on its chart's open side. A random point of the texel's square
       * could lie past a wall standing on it (a sunlit floor texel under a closed door
       * leaf would light the dark room behind it). */
      const float *tn = lm->texel_normal + 3 * (size_t)t;
      const float *qo = lm->sample_pos + ((size_t)t * UB_TEXEL_SAMPLES + pq->sp) * 3;
      /* the receiver's sample points in turn from a random one: with fewer samples than
       * points (ray shifts) k mod spr would use the first points only */
      const float *p = rs->samples + ((size_t)r * rs->spr + (k + po) % rs->spr) * 3;
      float w[3] = {qo[0] - p[0], qo[1] - p[1], qo[2] - p[2]};
      float d2 = dot3(w, w);
      if (!(d2 >= UB_TL_NEAR2 * tt->area) || !(d2 > 0.0f))
        continue; /* near field: gathers read it (tl_readable) */
      float dist = sqrtf(d2);
      for (int ch = 0; ch < 3; ch++)
        w[ch] /= dist;
      float cs = nrm ? dot3(nrm, w) : 1.0f, ce = -dot3(tn, w);
      if (cs <= 1e-4f || ce <= 0.0f)
        continue;
      double p_t = (double)(cdf[cl] - (cl ? cdf[cl - 1] : 0.0f)) * tt->pc;
      double pdf_sa = p_t / tt->texel_area * d2 / ce;
      double denom = M * pdf_sa + N * gather_pdf(nrm, w);
      shadow_rec *sr = &rec[n];
      sr->recv = i;
      sr->primary = 0;
      sr->emissive = 0;
      memcpy(sr->dir, w, sizeof w);
      for (int ch = 0; ch < 3; ch++)
        sr->e[ch] = (float)(tt->rad[ch] / denom);
      sr->cos = cs;
      if (!finite3(sr->e))
        continue;
      sr->grp_n = M;
      sr->grp_k = k;
      sr->grp_kx = 0;
      sr->grp_first = (uint8_t)first;
      sr->src_texel = (int32_t)t;
      first = 0;
      ub_ray *ray = &rays[n];
      memcpy(ray->org, p, sizeof ray->org);
      memcpy(ray->dir, w, sizeof w);
      ray->tnear = 0.0f;
      ray->tfar = dist * (1.0f - 1e-4f);
      n++;
    }
  }
  free(pk);
  shadow_flush(c, rs, r0, rays, rec, occ, n, 0);
}

static int cmp_u64(const void *a, const void *b)
{
  uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
  return (x > y) - (x < y);
}

/* The texel-light clusters (geometry only, once per pass). 0 when out of memory. */
/* A subset pass: which clusters hold one of its act texels (the others never light).
 * Returns 0 when out of memory. */
static int tl_hot_build(pass_ctx *c)
{
  if (!c->act)
    return 1;
  c->tl_hot = calloc((size_t)c->tl_K + 1, 1);
  if (!c->tl_hot)
    return 0;
  for (uint32_t i = 0; i < c->nact; i++) {
    uint32_t k = c->tl_of ? c->tl_of[c->act[i]] : c->tl_tex[c->act[i]].of;
    if (k != UINT32_MAX)
      c->tl_hot[k] = 1;
  }
  return 1;
}

static int texel_clusters_build(pass_ctx *c)
{
  const ub_lightmap *lm = c->lm;
  uint32_t T = lm->texel_count;
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (uint32_t t = 0; t < T; t++)
    for (int j = 0; j < 3; j++) {
      lo[j] = fminf(lo[j], lm->texel_pos[3 * (size_t)t + j]);
      hi[j] = fmaxf(hi[j], lm->texel_pos[3 * (size_t)t + j]);
    }
  float ext = fmaxf(hi[0] - lo[0], fmaxf(hi[1] - lo[1], hi[2] - lo[2]));
  float cell = ext > 0.0f ? ext / UB_TL_CELLS : 1.0f;
  uint64_t *key = malloc(((size_t)T + 1) * sizeof *key);
  c->tl_of = malloc(((size_t)T + 1) * sizeof *c->tl_of);
  c->tl_list = malloc(((size_t)T + 1) * sizeof *c->tl_list);
  c->tl_ccdf = calloc((size_t)T + 1, sizeof *c->tl_ccdf); /* 0: clusters never lit */
  if (!key || !c->tl_of || !c->tl_list || !c->tl_ccdf) {
    free(key);
    return 0;
  }
  /* key: cell (x, y, z) and normal direction in the high bits, the texel in the low 32 */
  size_t m = 0;
  for (uint32_t t = 0; t < T; t++) {
    c->tl_of[t] = UINT32_MAX;
    if (!(c->tl_area[t] > 0.0f))
      continue;
    const float *p = lm->texel_pos + 3 * (size_t)t, *nn = lm->texel_normal + 3 * (size_t)t;
    uint64_t k = 0;
    for (int j = 0; j < 3; j++) {
      int64_t ci = (int64_t)((p[j] - lo[j]) / cell);
      ci = ci < 0 ? 0 : (ci >= UB_TL_CELLS ? UB_TL_CELLS - 1 : ci);
      k = k * UB_TL_CELLS + (uint64_t)ci;
    }
    int ax = fabsf(nn[0]) >= fabsf(nn[1]) ? (fabsf(nn[0]) >= fabsf(nn[2]) ? 0 : 2)
                                          : (fabsf(nn[1]) >= fabsf(nn[2]) ? 1 : 2);
    k = k * 6 + (uint64_t)(2 * ax + (nn[ax] < 0.0f));
    key[m++] = k << 32 | t;
  }
  qsort(key, m, sizeof *key, cmp_u64);
  uint32_t K = 0;
  for (size_t i = 0; i < m; i++)
    K += i == 0 || key[i] >> 32 != key[i - 1] >> 32;
  c->tl_start = malloc(((size_t)K + 1) * sizeof *c->tl_start);
  c->tl_cl = calloc((size_t)K + 1, sizeof *c->tl_cl);
  if (!c->tl_start || !c->tl_cl) {
    free(key);
    return 0;
  }
  uint32_t k = UINT32_MAX;
  for (size_t i = 0; i < m; i++) {
    uint32_t t = (uint32_t)key[i];
    if (i == 0 || key[i] >> 32 != key[i - 1] >> 32) {
      tl_cluster *cl = &c->tl_cl[++k];
      c->tl_start[k] = (uint32_t)i;
      for (int j = 0; j < 3; j++) {
        cl->lo[j] = cl->nlo[j] = INFINITY;
        cl->hi[j] = cl->nhi[j] = -INFINITY;
      }
    }
    tl_cluster *cl = &c->tl_cl[k];
    c->tl_list[i] = t;
    c->tl_of[t] = k;
    cl->n++;
    /* the texel's square in its plane (a texel size, with a margin), cut to its
     * triangle's box. The boxes only steer sampling: a texel left out of a block's table
     * is still found by the gather rays, at full weight (its pdf there is 0). */
    float r = 0.75f * texel_world_size(c, t);
    const ub_scene *s = c->s;
    const float *v0 = s->positions + 3 * (size_t)s->indices[3 * (size_t)lm->texel_tri[t]];
    const float *v1 = s->positions + 3 * (size_t)s->indices[3 * (size_t)lm->texel_tri[t] + 1];
    const float *v2 = s->positions + 3 * (size_t)s->indices[3 * (size_t)lm->texel_tri[t] + 2];
    for (int j = 0; j < 3; j++) {
      float pj = lm->texel_pos[3 * (size_t)t + j], nj = lm->texel_normal[3 * (size_t)t + j];
      float rj = r * sqrtf(fmaxf(0.0f, 1.0f - nj * nj)) + 1e-4f * r;
      float tlo = fminf(v0[j], fminf(v1[j], v2[j])), thi = fmaxf(v0[j], fmaxf(v1[j], v2[j]));
      cl->lo[j] = fminf(cl->lo[j], fmaxf(pj - rj, tlo));
      cl->hi[j] = fmaxf(cl->hi[j], fminf(pj + rj, thi));
      cl->nlo[j] = fminf(cl->nlo[j], nj);
      cl->nhi[j] = fmaxf(cl->nhi[j], nj);
    }
  }
  c->tl_start[K] = (uint32_t)m;
  c->tl_K = K;
  free(key);
  return tl_hot_build(c);
}

/* Level-sized scratch arrays a subset pass borrows from the cache (scr_take / scr_give). */
enum {
  SCR_SH_TOTAL, SCR_IZ_TOTAL, SCR_PROBE_TOTAL, SCR_ACC_SH, SCR_ACC_IZ, SCR_ACC_SRC,
  SCR_ACC_SRC_NP, SCR_ACC_VAR, SCR_ACC_PVAR, SCR_REL2, SCR_VAR_TX, SCR_PR_ACC_SH,
  SCR_PR_ACC_VAR, SCR_PR_ACC_PVAR, SCR_VAR_PR, SCR_LLG_ACC_SH, SCR_LLG_ACC_NP, SCR_LLG_TOTAL,
  SCR_LLG_PREV, SCR_TL_CCDF, UB_SCR_SLOTS
};
#define UB_POOL_SLOTS 24

/* The clusters' geometry (texel areas, membership, bounds) depends on the scene and the
 * lightmap only: passes sharing a desc.cache build it once (a qsort of every texel per
 * pass was ~0.2 s at ESTATE full scale, × 264 subset passes). */
struct ub_pass_cache {
  int ok;
  const ub_lightmap *lm;
  const ub_scene *s;
  uint32_t T, K;
  tl_texel *tl_tex; /* areas and clusters; rad and pc zero between passes (a pass
                       borrowing it zeroes what it wrote) */
  uint32_t *tl_list, *tl_start;
  tl_cluster *cl; /* bounds and counts; power and peak 0 */
  /* per atlas: the zero-light image and pixel levels subset passes start from
   * (ub_lightmap_sparse_base), built by the first subset pass; zbuilt: 1 ok, -1 failed */
  int zbuilt;
  uint32_t zatlases;
  float **zimg;
  uint8_t **zlevel;
  /* Scratch of subset passes (scr_take / scr_give): arrays all zero, and per atlas an
   * image holding zimg's fill, that the next subset pass takes instead of allocating
   * (and page-faulting in) level-sized arrays again; NULL while a pass holds one. */
  void *scr[UB_SCR_SLOTS];
  size_t scr_bytes[UB_SCR_SLOTS];
  float **simg; /* zatlases */
  /* Output arrays of subset passes given back by ub_pass_result_recycle (all zero) and
   * taken by the next pass of the same sizes (pool_take): each of a set's two passes
   * wrote fresh level-sized outputs (the influence measures and bounce planes, 51 MB at
   * ESTATE full scale), and the page faults of those first writes, × 264 passes, were
   * ~0.5 M of the bake's 2.6 M (perf record -e page-faults). Held whole (+36 MB of peak
   * RSS there: they fill in over the sets), for −9% of the sets' stage with the compact
   * store (desc.compact_store). */
  void *pool[UB_POOL_SLOTS];
  size_t pool_bytes[UB_POOL_SLOTS];
};

/* A zeroed array of `bytes` from the pool (ub_pass_cache.pool), else calloc'd. */
static void *pool_take(ub_pass_cache *cache, size_t bytes)
{
  for (int i = 0; cache && i < UB_POOL_SLOTS; i++)
    if (cache->pool[i] && cache->pool_bytes[i] == bytes) {
      void *p = cache->pool[i];
      cache->pool[i] = NULL;
      return p;
    }
  return calloc(bytes, 1);
}

/* p (all zero, `bytes` long) into a free pool slot, else freed. */
static void pool_give(ub_pass_cache *cache, void *p, size_t bytes)
{
  if (!p)
    return;
  for (int i = 0; cache && i < UB_POOL_SLOTS; i++)
    if (!cache->pool[i]) {
      cache->pool[i] = p;
      cache->pool_bytes[i] = bytes;
      return;
    }
  free(p);
}

/* The n rows idx[i] of row_bytes each in p set to 0: the only rows a pass wrote. */
static void zero_rows(void *p, const uint32_t *idx, uint32_t n, size_t row_bytes)
{
#pragma omp parallel for schedule(static)
  for (uint32_t i = 0; i < n; i++)
    memset((char *)p + (size_t)idx[i] * row_bytes, 0, row_bytes);
}

static void *scr_take(ub_pass_cache *cache, int slot, size_t bytes)
{
  if (cache && cache->scr[slot] && cache->scr_bytes[slot] == bytes) {
    void *p = cache->scr[slot];
    cache->scr[slot] = NULL;
    return p;
  }
  return calloc(bytes, 1);
}

/* p back to the cache (or freed, without one or when the slot holds one of its size),
 * zeroed first at the rows idx[0..n) of row_bytes each: the only rows the pass wrote. */
static void scr_give(ub_pass_cache *cache, int slot, void *p, size_t bytes, const uint32_t *idx,
                     uint32_t n, size_t row_bytes)
{
  if (!p)
    return;
  if (!cache || (cache->scr[slot] && cache->scr_bytes[slot] == bytes)) {
    free(p);
    return;
  }
  free(cache->scr[slot]); /* another size (another level's pass): the newer one stays */
  zero_rows(p, idx, n, row_bytes);
  cache->scr[slot] = p;
  cache->scr_bytes[slot] = bytes;
}

ub_pass_cache *ub_pass_cache_create(void)
{
  return calloc(1, sizeof(ub_pass_cache));
}

void ub_pass_cache_free(ub_pass_cache *cache)
{
  if (!cache)
    return;
  free(cache->tl_tex);
  free(cache->tl_list);
  free(cache->tl_start);
  free(cache->cl);
  for (uint32_t a = 0; a < cache->zatlases; a++) {
    free(cache->zimg ? cache->zimg[a] : NULL);
    free(cache->zlevel ? cache->zlevel[a] : NULL);
  }
  for (int i = 0; i < UB_SCR_SLOTS; i++)
    free(cache->scr[i]);
  for (int i = 0; i < UB_POOL_SLOTS; i++)
    free(cache->pool[i]);
  for (uint32_t a = 0; cache->simg && a < cache->zatlases; a++)
    free(cache->simg[a]);
  free(cache->simg);
  free(cache->zimg);
  free(cache->zlevel);
  free(cache);
}

/* The cache's zero-light images for lm (built on first use); 0 when unavailable. */
static int sparse_base_ready(ub_pass_cache *cache, const ub_lightmap *lm)
{
  if (!cache || (cache->zbuilt && cache->zatlases != lm->atlas_count))
    return 0;
  if (!cache->zbuilt) {
    cache->zbuilt = -1;
    cache->zatlases = lm->atlas_count;
    cache->zimg = calloc(lm->atlas_count + 1, sizeof *cache->zimg);
    cache->zlevel = calloc(lm->atlas_count + 1, sizeof *cache->zlevel);
    if (!cache->zimg || !cache->zlevel)
      return 0;
    for (uint32_t a = 0; a < lm->atlas_count; a++) {
      size_t npx = (size_t)lm->atlases[a].width * lm->atlases[a].height;
      cache->zimg[a] = malloc((npx + 1) * 4 * sizeof(float));
      cache->zlevel[a] = malloc(npx + 1);
      if (!cache->zimg[a] || !cache->zlevel[a] ||
          !ub_lightmap_sparse_base(lm, a, cache->zimg[a], cache->zlevel[a]))
        return 0;
    }
    cache->zbuilt = 1;
  }
  return cache->zbuilt == 1;
}

/* The readers' records of T texels from the clusters' arrays: rad and pc zero. NULL when
 * out of memory. */
static tl_texel *tl_tex_new(const ub_lightmap *lm, const float *tl_area, const uint32_t *tl_of)
{
  size_t T = lm->texel_count;
  tl_texel *tx = aligned_alloc(_Alignof(tl_texel), (T + 1) * sizeof *tx);
  if (!tx)
    return NULL;
  memset(tx, 0, (T + 1) * sizeof *tx);
  for (size_t t = 0; t < T; t++) {
    tx[t].area = tl_area[t];
    tx[t].texel_area = lm->texel_area[t];
    tx[t].of = tl_of[t];
  }
  return tx;
}

/* The pass's cluster cdf back to the scratch slot it came from (texel_clusters_from_cache
 * borrows the cache's clusters and takes it there), zeroed where texel_lights_build wrote
 * it (the hot clusters' ranges); else freed. */
static void tl_ccdf_give(const pass_ctx *c)
{
  ub_pass_cache *cache = c->tl_borrowed ? c->d->cache : NULL;
  const size_t bytes = ((size_t)c->lm->texel_count + 1) * sizeof *c->tl_ccdf;
  if (cache && c->tl_ccdf && (!c->act || !c->tl_hot)) {
    memset(c->tl_ccdf, 0, bytes);
  } else if (cache && c->tl_ccdf) {
#pragma omp parallel for schedule(dynamic, 64)
    for (uint32_t k = 0; k < c->tl_K; k++)
      if (c->tl_hot[k])
        memset(c->tl_ccdf + c->tl_start[k], 0,
               (size_t)(c->tl_start[k + 1] - c->tl_start[k]) * sizeof *c->tl_ccdf);
  }
  scr_give(cache, SCR_TL_CCDF, c->tl_ccdf, bytes, NULL, 0, 0);
}

/* A borrowed tl_tex back to the state the cache keeps (rad and pc zero): the rows this
 * pass's texel_lights_build wrote, rad at its act texels and pc in its hot clusters; all
 * rows for a pass over every texel. */
static void tl_tex_reset(const pass_ctx *c)
{
  tl_texel *tx = c->tl_tex;
  if (!c->act || !c->tl_hot) {
    uint32_t T = c->lm->texel_count;
#pragma omp parallel for schedule(static)
    for (uint32_t t = 0; t < T; t++) {
      memset(tx[t].rad, 0, sizeof tx[t].rad);
      tx[t].pc = 0.0f;
    }
    return;
  }
#pragma omp parallel for schedule(static)
  for (uint32_t i = 0; i < c->nact; i++)
    memset(tx[c->act[i]].rad, 0, sizeof tx[c->act[i]].rad);
#pragma omp parallel for schedule(dynamic, 64)
  for (uint32_t k = 0; k < c->tl_K; k++)
    for (uint32_t i = c->tl_start[k]; c->tl_hot[k] && i < c->tl_start[k + 1]; i++)
      tx[c->tl_list[i]].pc = 0.0f;
}

static void texel_clusters_to_cache(const pass_ctx *c, const ub_lightmap *lm,
                                    const ub_scene *s, ub_pass_cache *cache)
{
  size_t T = lm->texel_count, K = c->tl_K;
  cache->tl_tex = tl_tex_new(lm, c->tl_area, c->tl_of);
  cache->tl_list = malloc((T + 1) * sizeof(uint32_t));
  cache->tl_start = malloc((K + 1) * sizeof(uint32_t));
  cache->cl = malloc((K + 1) * sizeof(tl_cluster));
  if (!cache->tl_tex || !cache->tl_list || !cache->tl_start || !cache->cl) {
    free(cache->tl_tex), free(cache->tl_list), free(cache->tl_start), free(cache->cl);
    cache->tl_tex = NULL; /* the clusters only: the images and scratch stay */
    cache->tl_list = cache->tl_start = NULL;
    cache->cl = NULL;
    cache->ok = 0;
    return;
  }
  memcpy(cache->tl_list, c->tl_list, (size_t)c->tl_start[K] * sizeof(uint32_t)); /* the rest unused */
  memcpy(cache->tl_start, c->tl_start, (K + 1) * sizeof(uint32_t));
  for (size_t k = 0; k < K; k++) {
    cache->cl[k] = c->tl_cl[k];
    cache->cl[k].power = cache->cl[k].peak = 0.0;
  }
  cache->lm = lm;
  cache->s = s;
  cache->T = (uint32_t)T;
  cache->K = (uint32_t)K;
  cache->ok = 1;
}

/* texel_clusters_build's result from the cache: the geometry borrowed, the per-pass
 * arrays (cluster power, cdfs, shares, hot flags) new. */
static int texel_clusters_from_cache(pass_ctx *c, ub_pass_cache *cache)
{
  size_t T = cache->T, K = cache->K;
  c->tl_borrowed = 1;
  c->tl_area = NULL; /* the areas and clusters are tl_tex's */
  c->tl_of = NULL;
  c->tl_list = cache->tl_list;
  c->tl_start = cache->tl_start;
  c->tl_K = cache->K;
  c->tl_cl = malloc((K + 1) * sizeof *c->tl_cl);
  c->tl_ccdf = scr_take(cache, SCR_TL_CCDF, (T + 1) * sizeof *c->tl_ccdf); /* tl_ccdf_give */
  c->tl_tex = cache->tl_tex;
  c->tl_tex_borrowed = 1;
  if (!c->tl_cl || !c->tl_ccdf)
    return 0;
  memcpy(c->tl_cl, cache->cl, K * sizeof *c->tl_cl);
  return tl_hot_build(c);
}

/* Builds the texel-light tables from the irradiance the next bounce reads. */
static void texel_lights_build(pass_ctx *c, const double *e_prev)
{
  const ub_lightmap *lm = c->lm;
  const ub_scene *s = c->s;
  uint32_t T = lm->texel_count;
  c->tl_on = 0;
  if (!c->tl_tex || !c->tl_samples || !c->tl_K)
    return;
  /* A subset pass: only its act texels hold light (rad is 0 elsewhere from the start),
   * and a cluster without one has no power: its cdf and texel shares stay 0. */
  uint32_t n = c->act ? c->nact : T;
#pragma omp parallel for schedule(static)
  for (uint32_t i = 0; i < n; i++) {
    uint32_t t = c->act ? c->act[i] : i;
    const float *alb = s->materials[s->tri_material[lm->texel_tri[t]]].albedo;
    for (int ch = 0; ch < 3; ch++)
      c->tl_tex[t].rad[ch] = (float)(alb[ch] * M_1_PI * e_prev[3 * (size_t)t + ch]);
  }
  int on = 0; /* clusters are independent: each its own texels, cdf range and fields */
#pragma omp parallel for schedule(dynamic, 64) reduction(| : on)
  for (uint32_t k = 0; k < c->tl_K; k++) {
    tl_cluster *cl = &c->tl_cl[k];
    if (c->tl_hot && !c->tl_hot[k]) {
      cl->power = cl->peak = 0.0;
      continue;
    }
    double sum = 0.0, peak = 0.0;
    for (uint32_t i = c->tl_start[k]; i < c->tl_start[k + 1]; i++) {
      uint32_t t = c->tl_list[i];
      const float *L = c->tl_tex[t].rad;
      double pw = (0.2126 * L[0] + 0.7152 * L[1] + 0.0722 * L[2]) * c->tl_tex[t].area;
      pw = pw > 0.0 && isfinite(pw) ? pw : 0.0;
      peak = pw > peak ? pw : peak;
      sum += pw;
      c->tl_ccdf[i] = (float)sum;
      c->tl_tex[t].pc = (float)pw;
    }
    for (uint32_t i = c->tl_start[k]; sum > 0.0 && i < c->tl_start[k + 1]; i++) {
      c->tl_ccdf[i] = (float)(c->tl_ccdf[i] / sum);
      c->tl_tex[c->tl_list[i]].pc = (float)(c->tl_tex[c->tl_list[i]].pc / sum);
    }
    if (sum > 0.0)
      c->tl_ccdf[c->tl_start[k + 1] - 1] = 1.0f;
    cl->power = sum;
    cl->peak = peak;
    on |= sum > 0.0;
  }
  c->tl_on = on;
}

/* The cluster table (cdf, tl_K entries) for the receivers of group g in a block: 1 when
 * texel lights are worth their shadow rays there — the brightest texel they can see carries
 * UB_TL_PEAK× the mean power of the texels they can see (in an evenly lit room the gather
 * rays alone do better), or with ub_pass_desc.texel_lights_everywhere whenever they see
 * a lit texel. A cluster is seen unless every texel of it faces away from every
 * point of the receivers' box, or lies behind every receiver (bounds over the boxes and
 * the normal components); its weight is its power over its squared distance. */
static int tl_block_table(const pass_ctx *c, const recv_set *rs, uint32_t r0, uint32_t nr,
                          int g, float *cdf)
{
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  float nlo[3] = {INFINITY, INFINITY, INFINITY}, nhi[3] = {-INFINITY, -INFINITY, -INFINITY};
  uint32_t m = 0;
  for (uint32_t i = 0; i < nr; i++) {
    uint32_t r = rs->index ? rs->index[r0 + i] : r0 + i;
    const float *nrm = rs->normal ? rs->normal + 3 * (size_t)r : NULL;
    if (tl_group(nrm) != g)
      continue;
    m++;
    for (int j = 0; nrm && j < 3; j++) {
      nlo[j] = fminf(nlo[j], nrm[j]);
      nhi[j] = fmaxf(nhi[j], nrm[j]);
    }
    for (uint32_t k = 0; k < rs->spr; k++)
      for (int j = 0; j < 3; j++) {
        float v = rs->samples[((size_t)r * rs->spr + k) * 3 + j];
        lo[j] = fminf(lo[j], v);
        hi[j] = fmaxf(hi[j], v);
      }
  }
  if (!m)
    return 0;
  double sum = 0.0, seen_power = 0.0, seen_n = 0.0, peak = 0.0;
  for (uint32_t k = 0; k < c->tl_K; k++) {
    const tl_cluster *cl = &c->tl_cl[k];
    double w = 0.0;
    if (cl->power > 0.0) {
      double dl[3], dh[3], d2 = 0.0, h2 = 0.0; /* d = p − q: receiver minus cluster */
      for (int j = 0; j < 3; j++) {
        dl[j] = (double)lo[j] - cl->hi[j];
        dh[j] = (double)hi[j] - cl->lo[j];
        double gap = dl[j] > 0.0 ? dl[j] : (dh[j] < 0.0 ? -dh[j] : 0.0);
        d2 += gap * gap;
        h2 += 0.25 * ((double)cl->hi[j] - cl->lo[j]) * ((double)cl->hi[j] - cl->lo[j]);
      }
      double ml[3] = {-dh[0], -dh[1], -dh[2]}, mh[3] = {-dl[0], -dl[1], -dl[2]};
      if (dot_bound(cl->nlo, cl->nhi, dl, dh) > 0.0 &&
          (g == 6 || dot_bound(nlo, nhi, ml, mh) > 0.0)) {
        w = cl->power / (d2 + h2);
        seen_power += cl->power;
        seen_n += cl->n;
        peak = cl->peak > peak ? cl->peak : peak;
      }
    }
    sum += w;
    cdf[k] = (float)sum;
  }
  double peak_min = c->d->texel_lights_everywhere ? 0.0 : UB_TL_PEAK * seen_power / seen_n;
  if (!(sum > 0.0) || !isfinite(sum) || peak < peak_min)
    return 0;
  for (uint32_t k = 0; k < c->tl_K; k++)
    cdf[k] = (float)(cdf[k] / sum);
  cdf[c->tl_K - 1] = 1.0f;
  return 1;
}

/* A hit's lightmap UV (out_uv) and the atlas pixel under it (the bilinear lookup's
 * nearest), on a lightmapped triangle. */
static inline size_t hit_pixel(const ub_lightmap *lm, const ub_atlas *at, const ub_hit *h,
                               float out_uv[2])
{
  const float *uv = lm->tri_uv + 6 * (size_t)h->tri;
  float b0 = 1.0f - h->u - h->v;
  float u = b0 * uv[0] + h->u * uv[2] + h->v * uv[4];
  float v = b0 * uv[1] + h->u * uv[3] + h->v * uv[5];
  int64_t tx = (int64_t)(u * (float)at->width), ty = (int64_t)(v * (float)at->height);
  tx = tx < 0 ? 0 : (tx >= at->width ? at->width - 1 : tx);
  ty = ty < 0 ? 0 : (ty >= at->height ? at->height - 1 : ty);
  out_uv[0] = u;
  out_uv[1] = v;
  return (size_t)ty * at->width + (size_t)tx;
}

/* Where a gather hit lands in the lightmap, worked out once per block at bounces >= 1 for
 * its three readers (nee_skip_mask, prefetch_hits, the shading in gather_block; each
 * computed it again, up to three tri_uv and texel_of reads per hit). */
typedef struct hit_texel {
  float u, v;  /* lightmap UV of the hit (hit_pixel) */
  uint32_t px; /* the atlas pixel under it */
  int32_t a;   /* its atlas, -1: a miss or a triangle without lightmap */
  int32_t t;   /* the texel at px, -1: none */
} hit_texel;

/* Hits per round of hit_texels: enough texel_of misses in flight to hide their latency,
 * few enough that the prefetched lines are still in L1 when read. */
#define UB_HX_CHUNK 64

/* Fills out[q] for each ray q of a block, in the hits' order (hits[j] is ray order[j]'s):
 * reading the hits in ray order was a cache miss per hit. The texel under a hit is a read
 * at a random atlas pixel, a cache miss per hit that stalled each iteration (perf of the
 * es25 DLS stage: the hottest instruction of gather_block); a round of hits first works
 * out the pixels and asks for them, then reads them. */
static void hit_texels(const pass_ctx *c, const ub_hit *hits, const uint32_t *order, size_t n,
                       hit_texel *out)
{
  const ub_lightmap *lm = c->lm;
  for (size_t j0 = 0; j0 < n; j0 += UB_HX_CHUNK) {
    size_t j1 = n - j0 < UB_HX_CHUNK ? n : j0 + UB_HX_CHUNK, m = 0;
    const int32_t *from[UB_HX_CHUNK];
    hit_texel *to[UB_HX_CHUNK];
    for (size_t j = j0; j < j1; j++) {
      const ub_hit *h = &hits[j];
      hit_texel *o = &out[order[j]];
      o->a = o->t = -1;
      if (h->tri == UB_RT_MISS)
        continue;
      int32_t a = lm->tri_atlas[h->tri];
      if (a < 0)
        continue;
      const ub_atlas *at = &lm->atlases[a];
      float uv[2];
      size_t px = hit_pixel(lm, at, h, uv);
      o->u = uv[0];
      o->v = uv[1];
      o->px = (uint32_t)px; /* atlases are at most UB_ATLAS_MAX_SIZE² pixels */
      o->a = a;
      from[m] = &at->texel_of[px];
      __builtin_prefetch(from[m]);
      to[m++] = o;
    }
    for (size_t k = 0; k < m; k++)
      to[k]->t = *from[k];
  }
}

/* What the shading of gather rays q0 .. q0+n-1 of a block will read at random (the hit;
 * in level-sized arrays, the lightmap image around it and, with texel lights, the texel
 * under it and its tables), asked of the memory system a round of rays ahead of the
 * shading: it then finds them in cache instead of waiting out one dependent miss after
 * another per hit (perf of the full ESTATE bake: a third of the pass kernels' time). All
 * of a block's hits asked at once (~5 lines each, 16384 rays) no longer fit in L2 by the
 * time the shading reached them (es25 DLS: tl_area and tl_of were still its hottest
 * loads). Reads nothing the results depend on. */
static void prefetch_hits(const pass_ctx *c, const ub_hit *hits, const uint32_t *sorted_of,
                          const hit_texel *hx, size_t q0, size_t n, const float *const *tl)
{
  int tl_any = 0;
  for (int g = 0; tl && g < UB_TL_GROUPS; g++)
    tl_any |= tl[g] != NULL;
  for (size_t j = q0; j < q0 + n; j++) {
    __builtin_prefetch(&hits[sorted_of[j]]);
    if (hx[j].a < 0)
      continue;
    __builtin_prefetch(c->img[hx[j].a] + 4 * (size_t)hx[j].px);
    if (!tl_any || hx[j].t < 0)
      continue;
    __builtin_prefetch(&c->tl_tex[hx[j].t]);
  }
}

/* Whether a gather hit on texel t (-1: none) is read as a texel light: it faces the ray
 * (ce, the cosine at the hit, out) and the texel holds light this bounce. The shading and
 * nee_skip_mask ask the same question with the same arithmetic. */
static inline int tl_readable(const pass_ctx *c, const ub_hit *h, const float dir[3], int32_t t,
                              float *ce)
{
  float gl = sqrtf(dot3(h->ng, h->ng));
  *ce = gl > 0.0f ? -dot3(h->ng, dir) / gl : 0.0f;
  return t >= 0 && *ce > 0.0f && c->tl_tex[t].area > 0.0f &&
         h->t * h->t >= UB_TL_NEAR2 * c->tl_tex[t].area;
}

/* The gather rays whose bounce-1 NEE the shading would drop (gather_block: a ray at
 * cs <= 1e-4, or a front hit on a lightmapped texel read as a texel light while the
 * tables hold all of bounce 0, tl_full): nee_block traces no shadow ray for them. The same
 * tests on the same values as the shading, so the output does not change. NULL: none (or
 * no memory: every ray gets its NEE, as before). */
static uint8_t *nee_skip_mask(const pass_ctx *c, const recv_set *rs, uint32_t r0, uint32_t nr,
                              const ub_ray *rays, const ub_hit *hits, const uint32_t *sorted_of,
                              const hit_texel *hx, const float *const *tl, const size_t *off)
{
  if (!c->tl_full || !tl)
    return NULL;
  uint8_t *skip = calloc(off[nr] ? off[nr] : 1, 1);
  if (!skip)
    return NULL;
  for (uint32_t i = 0; i < nr; i++) {
    uint32_t r = rs->index ? rs->index[r0 + i] : r0 + i;
    const float *nrm = rs->normal ? rs->normal + 3 * (size_t)r : NULL;
    const float *tl_cdf = tl[tl_group(nrm)];
    for (size_t q = off[i]; q < off[i + 1]; q++) {
      const ub_ray *ray = &rays[q];
      const ub_hit *h = &hits[sorted_of[q]];
      float cs = nrm ? dot3(nrm, ray->dir) : 1.0f;
      if (cs <= 1e-4f) {
        skip[q] = 1;
        continue;
      }
      if (!tl_cdf || h->tri == UB_RT_MISS || dot3(h->ng, ray->dir) >= 0.0f || hx[q].a < 0)
        continue;
      float ce;
      skip[q] = (uint8_t)tl_readable(c, h, ray->dir, hx[q].t, &ce);
    }
  }
  return skip;
}

/* A thread's gather arrays, kept from block to block of a run_blocks call. A block's are
 * ~2 MB; allocated and freed per block, glibc gave the pages back and faulted them in
 * again (estate_small draft: 1.3-1.5 s of system time per bake, 0.2 s with these). */
typedef struct gather_scratch {
  size_t cap; /* rays each array holds */
  ub_ray *rays, *sorted;
  ub_hit *hits;
  uint32_t *order, *bucket;
  hit_texel *hx;
} gather_scratch;

static void gather_scratch_free(gather_scratch *g)
{
  free(g->rays);
  free(g->sorted);
  free(g->hits);
  free(g->order);
  free(g->bucket);
  free(g->hx);
  memset(g, 0, sizeof *g);
}

/* Room for n rays; 0 when out of memory (then holds none). */
static int gather_scratch_reserve(gather_scratch *g, size_t n)
{
  if (n <= g->cap)
    return 1;
  gather_scratch_free(g);
  g->rays = malloc(n * sizeof *g->rays);
  g->sorted = malloc(n * sizeof *g->sorted);
  g->hits = malloc(n * sizeof *g->hits);
  g->order = malloc(n * sizeof *g->order);
  g->bucket = malloc(n * sizeof *g->bucket);
  g->hx = malloc(n * sizeof *g->hx);
  if (!g->rays || !g->sorted || !g->hits || !g->order || !g->bucket || !g->hx) {
    gather_scratch_free(g);
    return 0;
  }
  g->cap = n;
  return 1;
}

/* Columns of the stratified grid of n gather rays (kx = ⌊√n⌋, at least 1; kx × ⌊n/kx⌋
 * cells): what the directions are drawn on and what stratified_var reads them back by. */
static inline uint32_t strat_cols(uint32_t n)
{
  uint32_t kx = (uint32_t)sqrtf((float)n);
  return kx < 1 ? 1 : kx;
}

/* Gather rays: bounce 0 sees the sky and emitters (MIS), bounce k reads bounce k-1. */
static void gather_block(pass_ctx *c, const recv_set *rs, uint32_t r0, uint32_t nr,
                         const float *const *tl, gather_scratch *gs)
{
  const ub_pass_desc *d = c->d;
  const ub_scene *s = c->s;
  /* Receiver i's rays are off[i] .. off[i+1]-1 of the block (recv_rays each; nr <= 256) */
  size_t off[257];
  off[0] = 0;
  for (uint32_t i = 0; i < nr; i++)
    off[i + 1] = off[i] + recv_rays(c->bounce, rs, rs->index ? rs->index[r0 + i] : r0 + i);
  size_t n = off[nr];
  if (!gather_scratch_reserve(gs, n)) {
    atomic_store(&c->cancelled, 2);
    return;
  }
  ub_ray *rays = gs->rays, *sorted = gs->sorted;
  ub_hit *hits = gs->hits;
  uint32_t *order = gs->order, *bucket = gs->bucket;
  hit_texel *hx = c->bounce >= 1 ? gs->hx : NULL;
  /* Stratified directions: the first kx·ky rays on a jittered kx × ky grid (kx = ⌊√N⌋),
   * the few left over (N not a multiple of kx) uniformly random. N: the receiver's rays. */
  uint32_t hk = ub_hash_mix(ub_hash_mix(UB_HASH_SEED, c->seed), d->pass_id * 0x10000u + c->bounce);
  for (uint32_t i = 0; i < nr; i++) {
    uint32_t r = rs->index ? rs->index[r0 + i] : r0 + i;
    const float *nrm = rs->normal ? rs->normal + 3 * (size_t)r : NULL;
    uint32_t hr = ub_hash_mix(hk, rs->id_base + r); /* ub_hash4(seed, key, id, j) below */
    uint32_t N = (uint32_t)(off[i + 1] - off[i]);
    uint32_t kx = strat_cols(N), ky = N / kx;
    /* The ray's sample point: (column + row + o) mod spr on the grid, o random per
     * receiver. Each point shoots into every column and row of the grid in turn and, over
     * o, every cell equally often, so where a point stands and where it looks are
     * independent. (j mod spr tied point k to columns k, k + spr, …: at 16 rays each of a
     * texel's 4 points saw one elevation band only, and a texel whose points see
     * different things, e.g. at a wall, settled on a value that depended on the ray
     * count: up to 10% on cornell between 16 and 64 rays.) */
    uint32_t po = rs->spr > 1 ? ub_hash4(hr, 11, 0, 0) % rs->spr : 0;
    for (uint32_t j = 0; j < N; j++) {
      uint32_t h = ub_hash_mix(hr, j);
      float u1 = ub_u01(h), u2 = ub_u01(ub_hash4(h, 7, 0, 0));
      uint32_t pk = j + po;
      if (j < kx * ky) {
        u1 = ((float)(j % kx) + u1) / (float)kx;
        u2 = ((float)(j / kx) + u2) / (float)ky;
        pk = j % kx + j / kx + po;
      }
      ub_ray *ray = &rays[off[i] + j];
      const float *p = rs->samples + ((size_t)r * rs->spr + pk % rs->spr) * 3;
      memcpy(ray->org, p, sizeof ray->org);
      if (nrm) {
        ub_sample_cosine(nrm, u1, u2, ray->dir);
      } else {
        float z = 1.0f - 2.0f * u1, rr = sqrtf(fmaxf(0.0f, 1.0f - z * z));
        float phi = 2.0f * (float)M_PI * u2;
        ray->dir[0] = rr * cosf(phi);
        ray->dir[1] = z;
        ray->dir[2] = rr * sinf(phi);
      }
      ray->tnear = 0.0f;
      ray->tfar = INFINITY;
    }
  }
  /* Sorted by direction bucket: rays of a block start close together, so equal
   * directions make coherent streams. */
  uint32_t count[UB_DIR_BUCKETS + 1];
  for (size_t j = 0; j < n; j++)
    bucket[j] = dir_bucket(rays[j].dir);
  sort_rays(rays, bucket, n, UB_DIR_BUCKETS, count, order, sorted);
  ub_rt_intersect_sorted(rs->rt, sorted, (uint32_t)n, hits);
  atomic_fetch_add(&c->rays_gather, n);
  /* Scatter hits back to ray order (bucket reused as the inverse permutation). */
  for (size_t j = 0; j < n; j++)
    bucket[order[j]] = (uint32_t)j;
  if (hx)
    hit_texels(c, hits, order, n, hx);
  float *nee = NULL;
  if (c->bounce == 1 && c->nee) {
    uint8_t *skip = nee_skip_mask(c, rs, r0, nr, rays, hits, bucket, hx, tl, off);
    nee = nee_block(c, d->rt, rays, hits, bucket, skip, n, rs->id_base + r0);
    free(skip);
  }
  if (hx)
    prefetch_hits(c, hits, bucket, hx, 0, n < UB_HX_CHUNK ? n : UB_HX_CHUNK, tl);

  uint64_t backface = 0, unlit = 0, clamped = 0, misses = 0, sky_hits = 0, emitter_hits = 0;
  uint32_t ne = (d->emissive && d->emitters) ? d->emitters->count : 0;
  /* Per-ray luminance contributions of one receiver, for its variance (stratified_var). */
  double *contrib = rs->acc_var ? malloc((rs->rays + 1) * sizeof *contrib) : NULL;
  prop_read *prop = rs->acc_pvar && c->prev_rel2 ? malloc((rs->rays + 1) * sizeof *prop) : NULL;
  /* bounce 0: a receiver's emitter probabilities, as direct_block's (on its first hit) */
  float *ebuf = c->bounce == 0 && ne ? malloc((size_t)ne * sizeof *ebuf) : NULL;
  if (c->bounce == 0 && ne && !ebuf) {
    atomic_store(&c->cancelled, 2); /* (out of memory: as shadow_alloc) */
    ne = 0;
  }
  uint32_t np = 0;
  for (uint32_t i = 0; i < nr; i++) {
    uint32_t r = rs->index ? rs->index[r0 + i] : r0 + i;
    const float *nrm = rs->normal ? rs->normal + 3 * (size_t)r : NULL;
    const float *ecdf = NULL;
    double *sh = rs->acc_sh ? rs->acc_sh + (size_t)rs->nsh * 3 * r : NULL;
    double *iz = rs->acc_iz ? rs->acc_iz + 3 * (size_t)r : NULL;
    double *src = rs->acc_src ? rs->acc_src + 3 * (size_t)r : NULL;
    double *src_np = rs->acc_src_np ? rs->acc_src_np + 3 * (size_t)r : NULL;
    double *sh_np = rs->acc_sh_np ? rs->acc_sh_np + (size_t)rs->nsh * 3 * r : NULL;
    uint32_t N = (uint32_t)(off[i + 1] - off[i]);
    if (contrib)
      memset(contrib, 0, N * sizeof *contrib);
    np = 0;
    for (uint32_t j = 0; j < N; j++) {
      size_t q = off[i] + j; /* the ray's index in the block */
      if (hx && q % UB_HX_CHUNK == 0 && n - q > UB_HX_CHUNK)
        prefetch_hits(c, hits, bucket, hx, q + UB_HX_CHUNK,
                      n - q - UB_HX_CHUNK < UB_HX_CHUNK ? n - q - UB_HX_CHUNK : UB_HX_CHUNK, tl);
      const ub_ray *ray = &rays[q];
      const ub_hit *h = &hits[bucket[q]];
      float L[3] = {0, 0, 0};
      float cs = nrm ? dot3(nrm, ray->dir) : 1.0f;
      double pdf = gather_pdf(nrm, ray->dir);
      if (cs <= 1e-4f)
        continue;
      double wt = 1.0 / (N * pdf); /* plain estimator: L·f/(N·pdf) */
      int tl_read = 0;             /* L is a texel light's radiance (tl_tex rad) */
      if (h->tri == UB_RT_MISS) {
        misses++;
        if (c->bounce == 0 && d->sky) {
          memcpy(L, s->sky, sizeof L);
          sky_hits++;
        } else {
          continue;
        }
      } else {
        int front = dot3(h->ng, ray->dir) < 0.0f;
        if (c->bounce == 0) {
          if (!front || !ne || c->emitter_of[h->tri] < 0)
            continue;
          /* Emitter seen by a gather ray: balance heuristic against area sampling. */
          const ub_emitters *em = d->emitters;
          int32_t ei = c->emitter_of[h->tri];
          if (!ecdf)
            ecdf = d->emitters_by_power ? em->cdf
                                        : ub_emitters_local_cdf(
                                              em, rs->samples + (size_t)r * rs->spr * 3, nrm,
                                              ebuf);
          float p_tri = ecdf[ei] - (ei ? ecdf[ei - 1] : 0.0f);
          float ce = -dot3(em->normal + 3 * (size_t)ei, ray->dir);
          if (ce <= 0.0f)
            continue;
          double pdf_sa = (double)p_tri / em->area[ei] * h->t * h->t / ce;
          wt = 1.0 / (d->emissive_samples * pdf_sa + N * pdf);
          memcpy(L, s->materials[s->tri_material[h->tri]].emission, sizeof L);
          emitter_hits++;
        } else {
          if (!front) {
            backface++;
            continue;
          }
          const hit_texel *hq = &hx[q];
          int32_t a = hq->a;
          float e[3] = {0.0f, 0.0f, 0.0f};
          int llg_lit = 0;
          if (a < 0 && c->llg_prev) {
            float hp[3] = {ray->org[0] + h->t * ray->dir[0], ray->org[1] + h->t * ray->dir[1],
                           ray->org[2] + h->t * ray->dir[2]};
            llg_lit = ub_llg_hit_irradiance(c->llg, s, c->llg_prev, h->tri, h->u, h->v, hp,
                                            ray->dir, e);
          }
          if (a < 0 && !llg_lit &&
              !(nee && (nee[3 * q] > 0.0f || nee[3 * q + 1] > 0.0f || nee[3 * q + 2] > 0.0f))) {
            unlit++;
            continue;
          }
          int tl_hit = 0;
          /* the texel under the hit: what the texel-light strategy and the propagated
           * variance see */
          int32_t t_hit = -1;
          if (a >= 0) {
            t_hit = hq->t;
            float u = hq->u, v = hq->v;
            const float *tl_cdf = tl ? tl[tl_group(nrm)] : NULL;
            if (tl_cdf) {
              int32_t t = t_hit;
              float ce;
              if (tl_readable(c, h, ray->dir, t, &ce)) {
                const tl_texel *tt = &c->tl_tex[t];
                uint32_t k = tt->of;
                double p_t = k == UINT32_MAX ? 0.0
                                             : (double)(tl_cdf[k] - (k ? tl_cdf[k - 1] : 0.0f)) *
                                                   tt->pc;
                double pdf_sa = p_t / tt->texel_area * h->t * h->t / ce;
                wt = 1.0 / (c->tl_samples * pdf_sa + N * pdf);
                memcpy(L, tt->rad, sizeof L);
                tl_hit = 1;
                tl_read = 1;
              }
            }
            if (!tl_hit)
              ub_lightmap_image_sample(c->lm, c->img[a], (uint32_t)a, u, v, e);
          }
          if (!tl_hit) {
            const float *alb = s->materials[s->tri_material[h->tri]].albedo;
            for (int ch = 0; ch < 3; ch++)
              L[ch] = alb[ch] * (float)M_1_PI * e[ch];
          }
          if (prop && a >= 0 && finite3(L)) {
            /* The lightmap-read part of this sample and the texel under the hit (the
             * bilinear lookup's nearest texel), for the propagated variance. */
            double l = 0.2126 * L[0] + 0.7152 * L[1] + 0.0722 * L[2];
            if (t_hit >= 0) {
              prop[np].t = (uint32_t)t_hit;
              prop[np++].c = nrm ? l * cs * wt : 0.25 * l * wt;
            }
          }
        }
        if (nee && !(tl_read && c->tl_full)) {
          /* Punctual light at the hit: its own estimator, weight 1/(N·pdf) (none when the
           * texel light read holds it already). */
          double wn = 1.0 / (N * pdf) / wt;
          for (int ch = 0; ch < 3; ch++)
            L[ch] += (float)(nee[3 * q + ch] * wn);
        }
      }
      if (!finite3(L)) {
        clamped++;
        continue;
      }
      if (iz)
        for (int ch = 0; ch < 3; ch++) {
          iz[ch] += L[ch] * cs * wt;
          if (src)
            src[ch] += L[ch] * cs * wt;
          if (src_np)
            src_np[ch] += L[ch] * cs * wt;
        }
      double wsh = nrm ? ub_texel_sh_weight(wt, N) : wt; /* UB_SH_COS_FLOOR */
      if (sh)
        sh_accum(sh, rs->nsh, ray->dir, L, wsh);
      if (sh_np)
        sh_accum(sh_np, rs->nsh, ray->dir, L, wsh);
      if (contrib) {
        /* Texels: irradiance along the normal; probes: DC irradiance π·Y0·(Y0·L·wt). */
        double l = 0.2126 * L[0] + 0.7152 * L[1] + 0.0722 * L[2];
        contrib[j] = nrm ? l * cs * wt : 0.25 * l * wt;
      }
    }
    if (contrib) {
      uint32_t kx = strat_cols(N);
      rs->acc_var[r] += stratified_var(contrib, N, kx, N / kx);
    }
    if (prop)
      rs->acc_pvar[r] += prop_var(prop, np, c->prev_rel2);
  }
  free(contrib);
  free(prop);
  free(ebuf);
  atomic_fetch_add(&c->backface, backface);
  atomic_fetch_add(&c->unlit, unlit);
  atomic_fetch_add(&c->clamped, clamped);
  atomic_fetch_add(&c->misses, misses);
  atomic_fetch_add(&c->sky_hits, sky_hits);
  atomic_fetch_add(&c->emitter_hits, emitter_hits);
  free(nee);
}

/* Builds the per-atlas image of the irradiance a later bounce reads, dilated. */
static void build_images(pass_ctx *c, const double *iz)
{
  /* Without memory for the dilation scratch the image is used undilated. A subset pass
   * refills only around its texels (the same images). */
  for (uint32_t a = 0; a < c->lm->atlas_count; a++)
    if (c->sparse)
      ub_lightmap_sparse_fill(c->lm, &c->sparse[a], iz, c->img[a]);
    else
      ub_lightmap_image_fill(c->lm, a, NULL, iz, c->img[a]);
}

/* Radiosity the next bounce could read: Σ albedo·E over texels (luminance). Zero means
 * another bounce cannot add anything (black level or no light). */
static double outgoing_energy(const pass_ctx *c, const double *iz, const uint32_t *act,
                              uint32_t n)
{
  double e = 0.0;
  for (uint32_t i = 0; i < n; i++) {
    uint32_t t = act ? act[i] : i;
    const float *a = c->s->materials[c->s->tri_material[c->lm->texel_tri[t]]].albedo;
    e += a[0] * iz[3 * (size_t)t] + a[1] * iz[3 * (size_t)t + 1] + a[2] * iz[3 * (size_t)t + 2];
  }
  return e;
}

/* Rows of `width` doubles as floats, non-finite values 0 (counted in clamped): the rows
 * listed in idx (n of them), the others 0; idx NULL: rows 0..n-1. A subset pass converts
 * only its own receivers' rows (the rest of v is zero). */
static float *finite_rows(const double *v, size_t rows, size_t width, const uint32_t *idx,
                          size_t n, int compact, ub_pass_cache *pool, uint64_t *clamped)
{
  /* compact: row k of the result is row idx[k] of v, n rows and no others */
  float *out = compact ? malloc((n * width + 1) * sizeof(float))
               : idx   ? pool_take(pool, (rows * width + 1) * sizeof(float))
                       : malloc((rows * width + 1) * sizeof(float));
  if (!out)
    return NULL;
  for (size_t k = 0; k < n; k++) {
    size_t o = (idx ? idx[k] : k) * width, w = compact ? k * width : o;
    for (size_t i = 0; i < width; i++) {
      float f = (float)v[o + i];
      if (!isfinite(f)) {
        f = 0.0f;
        (*clamped)++;
      }
      out[w + i] = f;
    }
  }
  return out;
}

static double lum3d(const double *rgb)
{
  return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
}

/* Later bounces with fewer rays (ub_pass_desc.bounce_full_rays = 0). Called after bounce b
 * (≥ 1) with the bounce's results in acc (stride doubles a receiver; the luminance of the
 * first 3: texels' I_z, probes' DC): receiver r's gathers of bounce b + 1 trace rays >> k
 * more, 2^k ≤ its brightest bounce so far / this one (ub_pass_bounce_shift). A bounce's
 * share of a receiver's noise goes as its light over √rays, so the rays follow the light
 * (N_b ∝ the bounce's light is what minimises the summed variance at a given ray count):
 * where light still arrives late (a room lit through a doorway) the peak comes late and
 * the rays stay. A receiver that has seen no light keeps its rays. The choice depends on
 * the bounce's results only (no thread count), and each bounce's estimate stays unbiased
 * (test_ray_shift, test_late_expectation). */
static void bounce_shifts(recv_set *rs, const double *acc, size_t stride)
{
  if (!rs->bshift)
    return;
  for (uint32_t i = 0; i < rs->active; i++) {
    uint32_t r = rs->index ? rs->index[i] : i;
    double v = lum3d(acc + stride * (size_t)r);
    float pk = rs->peak[r];
    if (v > (double)pk)
      rs->peak[r] = pk = (float)v;
    rs->bshift[r] =
        (uint8_t)ub_pass_bounce_shift((double)pk, v, rs->pass_shift ? rs->pass_shift[r] : 0u);
  }
  rs->ray_shift = rs->bshift;
}

/* Σ luminance of iz over the texels act[0..n) (ascending), or the first n without act. */
static double energy_of(const double *iz, const uint32_t *act, uint32_t n)
{
  double e = 0.0;
  for (uint32_t i = 0; i < n; i++) {
    size_t t = act ? act[i] : i;
    e += 0.2126 * iz[3 * t] + 0.7152 * iz[3 * t + 1] + 0.0722 * iz[3 * t + 2];
  }
  return e;
}

static int report(pass_ctx *c, const char *stage, double frac, double bounce_share)
{
  const ub_pass_desc *d = c->d;
  if (!d->progress)
    return 0;
  double total = d->progress_base + d->progress_span * fmin(1.0, bounce_share);
  return d->progress(d->progress_user, stage, frac, total);
}

/* One item-parallel stage over every receiver set, in fixed blocks (thread-count
 * independent, so results are deterministic). */
static void run_blocks(pass_ctx *c, int direct, int gather, const char *stage, double share0,
                       double share1)
{
  uint32_t per_set[3], first[4] = {0, 0, 0, 0};
  for (int s = 0; s < 3; s++) {
    const recv_set *rs = &c->sets[s];
    uint32_t tpb = rs->rays ? UB_BLOCK_RAYS / rs->rays : 256;
    per_set[s] = tpb < 1 ? 1 : (tpb > 256 ? 256 : tpb);
    first[s + 1] = first[s] + (rs->active + per_set[s] - 1) / per_set[s];
  }
  uint32_t nblocks = first[3];
  atomic_store(&c->blocks_done, 0);
#pragma omp parallel
  {
    gather_scratch gs = {0};
#pragma omp for schedule(dynamic, 1)
    for (uint32_t b = 0; b < nblocks; b++) {
      if (atomic_load(&c->cancelled))
        continue;
      int s = b >= first[2] ? 2 : b >= first[1];
      const recv_set *rs = &c->sets[s];
      uint32_t r0 = (b - first[s]) * per_set[s];
      uint32_t nr = rs->active - r0 < per_set[s] ? rs->active - r0 : per_set[s];
      if (direct)
        direct_block(c, rs, r0, nr);
      /* this block's texel-light tables per receiver group, NULL where they are off */
      const float *tl[UB_TL_GROUPS] = {NULL};
      float *tl_buf = NULL;
      int tl_any = 0;
      if (gather && c->bounce >= 1 && c->tl_on && rs->samples) {
        tl_buf = malloc((size_t)UB_TL_GROUPS * c->tl_K * sizeof *tl_buf);
        for (int g = 0; tl_buf && g < UB_TL_GROUPS; g++)
          if (tl_block_table(c, rs, r0, nr, g, tl_buf + (size_t)g * c->tl_K)) {
            tl[g] = tl_buf + (size_t)g * c->tl_K;
            tl_any = 1;
          }
      }
      if (gather)
        gather_block(c, rs, r0, nr, tl, &gs);
      if (tl_any)
        texel_light_block(c, rs, r0, nr, tl);
      free(tl_buf);
      uint32_t done = atomic_fetch_add(&c->blocks_done, 1) + 1;
      if (omp_get_thread_num() == 0) {
        double f = (double)done / nblocks;
        if (report(c, stage, f, share0 + (share1 - share0) * f))
          atomic_store(&c->cancelled, 1);
      }
    }
    gather_scratch_free(&gs);
  }
}

/* rel2[t]: relative variance of texel t's value as the next bounce reads it (read,
 * count × 3), from this bounce's variance; the stored value stands in where the read part
 * is smaller (bounce 0 with NEE: the read part is the non-punctual light only). */
static void relative_variance(const pass_ctx *c, const double *read, float *rel2,
                              const uint32_t *act, uint32_t n)
{
  const recv_set *tx = &c->sets[0];
#pragma omp parallel for schedule(static)
  for (uint32_t i = 0; i < n; i++) {
    uint32_t t = act ? act[i] : i;
    double e = fmax(lum3d(read + 3 * (size_t)t), lum3d(tx->acc_iz + 3 * (size_t)t));
    double v = tx->acc_var[t] + tx->acc_pvar[t];
    double r = e > 0.0 ? v / (e * e) : 0.0;
    rel2[t] = isfinite(r) && r > 0.0 ? (float)fmin(r, 1e6) : 0.0f;
  }
}

double ub_err_floor(const float *e, uint32_t n)
{
  double sum = 0.0;
  for (uint32_t i = 0; i < n; i++)
    sum += isfinite(e[i]) ? e[i] : 0.0;
  return n ? UB_ERR_FLOOR * sum / n : 0.0;
}

/* Luminance of receiver r's result in acc (texels: iz, count × 3; probes: SH, DC term). */
static double recv_lum(const recv_set *rs, const double *acc, uint32_t r)
{
  return rs->texels ? lum3d(acc + 3 * (size_t)r)
                    : M_PI * UB_Y0 * lum3d(acc + (size_t)rs->nsh * 3 * r);
}

/* Adaptive sampling of one bounce (desc.target_error). The bounce's first round is a
 * pilot; from it each texel / GLG probe gets a number of rounds in all (see the plan
 * below), each further round running the same kernels (direct and/or gather + texel
 * lights, as run_blocks ran them) with its own seed (a hash of the pass seed and the
 * round), averaged into the bounce's accumulators: after n rounds the estimate is the
 * mean of n independent estimates, its variance the sum of theirs / n².
 * Variance budget per bounce: the receiver's total allowed variance (target · max(E,
 * floor))², minus what earlier bounces already hold, halved (so bounces 0, 1, 2, … get
 * at most 1/2, 1/4, 1/8, … when each just meets its budget and the sum stays within the
 * target), but never below a tenth of it (earlier bounces that overshot must not send
 * this one to the cap for nothing). Deterministic: the plan reads only accumulated
 * values, rounds are fixed blocks like the first. prev_*: results of the earlier
 * bounces; var_prev_*: their summed variance. Returns 0, or -1 if cancelled / out of
 * memory (c->cancelled set). */
static int refine_bounce(pass_ctx *c, int direct, int gather, const char *stage, double share,
                         const double *prev_tx, const double *prev_pr, const double *var_prev_tx,
                         const double *var_prev_pr, ub_pass_result *out, const ub_log *log)
{
  const ub_pass_desc *d = c->d;
  if (!(d->target_error > 0.0))
    return 0;
  uint32_t maxr = d->max_rounds ? d->max_rounds : UB_ADAPT_MAX_ROUNDS;
  const double *prev[2] = {prev_tx, prev_pr}, *vprev[2] = {var_prev_tx, var_prev_pr};
  enum { NARR = 6 };
  double **acc[2][NARR];
  size_t stride[2][NARR];
  double *fresh[2][NARR];
  uint16_t *nround[2] = {NULL, NULL};
  uint32_t *idx[2] = {NULL, NULL};
  double floor_e[2] = {0.0, 0.0};
  const uint32_t *save_index[3];
  uint32_t save_active[3];
  memset(fresh, 0, sizeof fresh);
  int res = 0;
  uint64_t rays0 = atomic_load(&c->rays_gather) + atomic_load(&c->rays_shadow);
  uint64_t refined = 0;
  uint32_t round;
  for (int k = 0; k < 2; k++) {
    recv_set *rs = &c->sets[k];
    acc[k][0] = &rs->acc_sh;
    stride[k][0] = (size_t)rs->nsh * 3;
    acc[k][1] = &rs->acc_iz;
    acc[k][2] = &rs->acc_src;
    acc[k][3] = &rs->acc_src_np;
    stride[k][1] = stride[k][2] = stride[k][3] = 3;
    acc[k][4] = &rs->acc_var;
    acc[k][5] = &rs->acc_pvar;
    stride[k][4] = stride[k][5] = 1;
    for (int a = 0; a < NARR; a++)
      if (*acc[k][a] && rs->count) {
        fresh[k][a] = calloc((size_t)rs->count * stride[k][a], sizeof(double));
        res |= !fresh[k][a];
      }
    nround[k] = calloc(rs->count + 1, sizeof(uint16_t));
    idx[k] = malloc(((size_t)rs->active + 1) * sizeof(uint32_t));
    res |= !nround[k] || !idx[k];
    double sum = 0.0;
    for (uint32_t i = 0; !res && i < rs->active; i++) {
      uint32_t r = rs->index ? rs->index[i] : i;
      sum += recv_lum(rs, prev[k], r) + recv_lum(rs, rs->acc_iz ? rs->acc_iz : rs->acc_sh, r);
    }
    floor_e[k] = rs->active ? UB_ERR_FLOOR * sum / rs->active : 0.0;
  }
  if (res) {
    atomic_store(&c->cancelled, 2);
    res = -1;
    goto done;
  }
  for (int k = 0; k < 3; k++) {
    save_index[k] = c->sets[k].index;
    save_active[k] = c->sets[k].active;
  }
  /* Plan from the first round (the pilot), but not from the receiver's own pilot: a
   * receiver whose sample count depended on its own samples would be biased (a pilot that
   * caught a rare bright hit has a large variance, gets refined and averaged down, one
   * that missed it is kept: −14% on cornell when tried). Each receiver's relative sampling
   * variance and inherited variance are predicted from its neighbours' pilots (texels:
   * the up to 8 covered atlas neighbours; probes: the mean over the other probes), whose
   * samples are independent of its own, so every round, the pilot included, is averaged
   * in unbiased. Rounds n (pilot included): the sampling variance / n must fit the budget
   * left beside the inherited part (which rounds do not reduce), at least a tenth of the
   * allowance; at most maxr. */
  double t2 = d->target_error * d->target_error;
  for (int k = 0; k < 2; k++) {
    recv_set *rs = &c->sets[k];
    if (!rs->acc_var)
      continue;
    const double *cur = rs->acc_iz ? rs->acc_iz : rs->acc_sh;
    /* Per active receiver: relative sampling / inherited variance of its pilot. */
    double *rmc = calloc(rs->count + 1, sizeof(double)), *rpv = calloc(rs->count + 1, sizeof(double));
    double *epil = calloc(rs->count + 1, sizeof(double));
    uint8_t *act = calloc(rs->count + 1, 1);
    if (!rmc || !rpv || !epil || !act) {
      free(rmc);
      free(rpv);
      free(epil);
      free(act);
      atomic_store(&c->cancelled, 2);
      res = -1;
      goto done;
    }
    double smc = 0.0, spv = 0.0;
    for (uint32_t i = 0; i < save_active[k]; i++) {
      uint32_t r = save_index[k] ? save_index[k][i] : i;
      epil[r] = recv_lum(rs, cur, r);
      double e = recv_lum(rs, prev[k], r) + epil[r];
      double den = e > floor_e[k] ? e : floor_e[k];
      act[r] = 1;
      if (den > 0.0) {
        rmc[r] = rs->acc_var[r] / (den * den);
        rpv[r] = rs->acc_pvar[r] / (den * den);
      }
      smc += rmc[r];
      spv += rpv[r];
    }
    for (uint32_t i = 0; i < save_active[k]; i++) {
      uint32_t r = save_index[k] ? save_index[k][i] : i;
      double mc = 0.0, pv = 0.0, ep = 0.0;
      uint32_t nn = 0;
      if (rs->texels) {
        const ub_atlas *at = &c->lm->atlases[c->lm->texel_atlas[r]];
        int x = (int)c->lm->texel_xy[2 * (size_t)r], y = (int)c->lm->texel_xy[2 * (size_t)r + 1];
        for (int dy = -1; dy <= 1; dy++)
          for (int dx = -1; dx <= 1; dx++) {
            int xx = x + dx, yy = y + dy;
            if ((!dx && !dy) || xx < 0 || yy < 0 || xx >= (int)at->width || yy >= (int)at->height)
              continue;
            int32_t q = at->texel_of[(size_t)yy * at->width + (size_t)xx];
            if (q < 0 || !act[q])
              continue;
            mc += rmc[q];
            pv += rpv[q];
            ep += epil[q];
            nn++;
          }
      } else if (save_active[k] > 1) {
        mc = smc - rmc[r];
        pv = spv - rpv[r];
        nn = save_active[k] - 1;
        ep = NAN; /* no neighbourhood: the light so far from earlier bounces only */
      }
      if (!nn)
        continue; /* nothing independent to plan from: the pilot only */
      mc /= nn;
      pv /= nn;
      double e = recv_lum(rs, prev[k], r) + (isfinite(ep) ? ep / nn : 0.0);
      double den = e > floor_e[k] ? e : floor_e[k];
      double vp = den > 0.0 ? vprev[k][r] / (den * den) : 0.0;
      double budget = fmax(0.5 * (t2 - vp), 0.1 * t2);
      if (mc + pv <= budget)
        continue;
      double room = fmax(budget - pv, 0.1 * t2);
      double n = ceil(mc / room);
      nround[k][r] = (uint16_t)(n > maxr ? maxr : n); /* rounds in all, pilot included */
    }
    free(rmc);
    free(rpv);
    free(epil);
    free(act);
  }
  for (round = 1; round < maxr; round++) {
    uint32_t nsel[2] = {0, 0};
    for (int k = 0; k < 2; k++)
      for (uint32_t i = 0; i < save_active[k]; i++) {
        uint32_t r = save_index[k] ? save_index[k][i] : i;
        if (nround[k][r] > round)
          idx[k][nsel[k]++] = r;
      }
    if (nsel[0] + nsel[1] == 0)
      break;
    refined += nsel[0] + nsel[1];
    for (int k = 0; k < 3; k++) {
      recv_set *rs = &c->sets[k];
      rs->index = k < 2 ? idx[k] : NULL;
      rs->active = k < 2 ? nsel[k] : 0;
      if (k == 2)
        continue;
      for (int a = 0; a < NARR; a++) {
        if (!fresh[k][a])
          continue;
        for (uint32_t i = 0; i < nsel[k]; i++)
          memset(fresh[k][a] + stride[k][a] * idx[k][i], 0, stride[k][a] * sizeof(double));
        double *t = *acc[k][a];
        *acc[k][a] = fresh[k][a];
        fresh[k][a] = t;
      }
    }
    c->seed = ub_hash4(d->seed, 0xada9u, round, 0);
    run_blocks(c, direct, gather, stage, share, share);
    c->seed = d->seed;
    for (int k = 0; k < 3; k++) {
      recv_set *rs = &c->sets[k];
      rs->index = save_index[k];
      rs->active = save_active[k];
      if (k == 2)
        continue;
      for (int a = 0; a < NARR; a++) {
        if (!fresh[k][a])
          continue;
        double *t = *acc[k][a]; /* this round's */
        *acc[k][a] = fresh[k][a];
        fresh[k][a] = t;
        double *m = *acc[k][a];
        size_t st = stride[k][a];
        double n = (double)round; /* rounds averaged so far, the pilot included */
        for (uint32_t i = 0; i < nsel[k]; i++) {
          uint32_t r = idx[k][i];
          for (size_t q = 0; q < st; q++) {
            size_t o = st * r + q;
            m[o] = a == 4 ? (n * n * m[o] + t[o]) / ((n + 1.0) * (n + 1.0))
                          : (n * m[o] + t[o]) / (n + 1.0);
          }
        }
      }
    }
    out->adaptive_rounds++;
    if (atomic_load(&c->cancelled)) {
      res = -1;
      break;
    }
  }
  {
    uint64_t rays = atomic_load(&c->rays_gather) + atomic_load(&c->rays_shadow) - rays0;
    out->rays_adaptive += rays;
    out->adaptive_receivers += refined;
    if (refined)
      ub_log_printf(log, UB_LOG_INFO, "  %s: adaptive: %llu receiver-rounds, +%.2f M rays",
                    stage, (unsigned long long)refined, rays * 1e-6);
  }
done:
  for (int k = 0; k < 2; k++) {
    for (int a = 0; a < NARR; a++)
      free(fresh[k][a]);
    free(nround[k]);
    free(idx[k]);
  }
  return res;
}

ub_result ub_pass_run(const ub_pass_desc *d, const ub_log *log, ub_pass_result *out)
{
  const ub_scene *s = d->scene;
  const ub_lightmap *lm = d->lightmap;
  uint32_t T = lm->texel_count;
  memset(out, 0, sizeof *out);
  pass_ctx c;
  memset(&c, 0, sizeof c);
  c.d = d;
  c.s = s;
  c.lm = lm;
  c.seed = d->seed;
  atomic_init(&c.cancelled, 0);

  uint32_t P = d->probe_count;
  uint32_t N = d->gather_rays ? d->gather_rays : 1;
  /* texels outside the subset whose estimated bounce light is fed to the images */
  uint8_t *outside = d->outside_bounce_iz && d->outside_bounces && d->texel_subset
                         ? malloc((size_t)T + 1) : NULL;
  if (outside) {
    memset(outside, 1, (size_t)T);
    for (uint32_t i = 0; i < d->texel_subset_count; i++)
      outside[d->texel_subset[i]] = 0;
  }
  /* A subset pass (a set's influence or full pass) only ever holds light at its subset's
   * texels and at the outside texels with an estimate: the per-bounce sums, resets and
   * stores below run over those (act, ascending, so every sum adds the same terms in the
   * same order: the same bits) instead of the level's every texel, probe and LLG probe.
   * At ESTATE scale (1.6 M texels, 264 subset passes) those whole-level loops, and the
   * page faults of touching whole-level arrays, were most of the sets' bake time. */
  uint32_t *act = NULL, nact = T;
  if (d->texel_subset && outside && d->outside_candidates) {
    /* the subset and the candidates that hold outside light, merged (both ascending) */
    const uint32_t *sb = d->texel_subset, *oc = d->outside_candidates;
    const uint32_t ns = d->texel_subset_count, no = d->outside_candidate_count;
    act = malloc(((size_t)ns + no + 1) * sizeof *act);
    if (act) {
      nact = 0;
      for (uint32_t i = 0, j = 0; i < ns || j < no;) {
        if (j == no || (i < ns && sb[i] < oc[j])) {
          act[nact++] = sb[i++];
          continue;
        }
        uint32_t t = oc[j++];
        int lit = 0; /* a subset texel is not outside: taken from sb */
        for (uint32_t k = 0; outside[t] && !lit && k < d->outside_bounces; k++) {
          const float *v = d->outside_bounce_iz + (size_t)k * T * 3 + 3 * (size_t)t;
          lit = v[0] != 0.0f || v[1] != 0.0f || v[2] != 0.0f;
        }
        if (lit)
          act[nact++] = t;
      }
    }
  } else if (d->texel_subset) {
    uint8_t *mk = calloc((size_t)T + 1, 1);
    if (mk) {
      for (uint32_t i = 0; i < d->texel_subset_count; i++)
        mk[d->texel_subset[i]] = 1;
      if (outside)
        for (uint32_t k = 0; k < d->outside_bounces; k++) {
          const float *src = d->outside_bounce_iz + (size_t)k * T * 3;
          for (uint32_t t = 0; t < T; t++)
            mk[t] |= outside[t] && (src[3 * (size_t)t] != 0.0f || src[3 * (size_t)t + 1] != 0.0f ||
                                    src[3 * (size_t)t + 2] != 0.0f);
        }
      nact = 0;
      for (uint32_t t = 0; t < T; t++)
        nact += mk[t];
      act = malloc(((size_t)nact + 1) * sizeof *act);
      if (act) {
        nact = 0;
        for (uint32_t t = 0; t < T; t++)
          if (mk[t])
            act[nact++] = t;
      } else {
        nact = T;
      }
      free(mk);
    }
  }
  const uint32_t *pact = d->probe_subset;
  const uint32_t npact = pact ? d->probe_subset_count : P;
  /* A subset pass writes its level-sized arrays only at act texels / pact probes: it
   * borrows them from the bake's cache and gives them back zeroed there (not with
   * adaptive rounds, whose fresh arrays are swapped in and out). This relies on the
   * desc's rules: gather_subset within texel_subset, every gather_donor[t] of the subset
   * in it, probe_gather_subset within probe_subset (a row written outside would stay in
   * the cache for every later pass). */
  ub_pass_cache *scache = d->cache && act && pact && !(d->target_error > 0.0) ? d->cache : NULL;
  /* Its outputs likewise from the cache's pool (ub_pass_result_recycle gives them back). */
  out->texel_direct = pool_take(scache, ((size_t)T + 1) * sizeof(float));
  out->texel_indirect = pool_take(scache, ((size_t)T + 1) * sizeof(float));
  if (d->keep_bounce_iz)
    out->texel_bounce_iz =
        pool_take(scache, ((size_t)T * 3 * d->keep_bounce_iz + 1) * sizeof(float));
  const size_t B_SH = ((size_t)T * 12 + 1) * sizeof(double), B_IZ = ((size_t)T * 3 + 1) * sizeof(double),
               B_T = ((size_t)T + 1) * sizeof(double), B_PSH = ((size_t)P * 27 + 1) * sizeof(double),
               B_P = ((size_t)P + 1) * sizeof(double);
  /* The running totals (sh_total, iz_total, probe_total, llg_total) feed the store, the
   * adaptive rounds and the bounce auto-stop. A pass with none of them (a DLS influence
   * pass: no_store, a fixed bounce count) takes none of them (NULL), nor the texels' SH
   * (tx->acc_sh, which only sh_total sums): at ESTATE scale ~220 B a texel and 216 B a
   * probe were written, summed and zeroed per pass for nothing. The measures it keeps
   * come from the bounce accumulators (I_z, probe SH), so the same bits. */
  const int totals = !d->no_store || d->bounces < 0 || d->target_error > 0.0;
  double *sh_total = totals ? scr_take(scache, SCR_SH_TOTAL, B_SH) : NULL;
  double *iz_total = totals ? scr_take(scache, SCR_IZ_TOTAL, B_IZ) : NULL;
  double *probe_total = totals ? scr_take(scache, SCR_PROBE_TOTAL, B_PSH) : NULL;
#define ACT(i) (act ? act[i] : (i))
#define PACT(i) (pact ? pact[i] : (i))
#define LACT(i) (lact ? lact[i] : (i))
  out->probe_direct = pool_take(scache, ((size_t)P + 1) * sizeof(float));
  out->probe_indirect = pool_take(scache, ((size_t)P + 1) * sizeof(float));
  recv_set *tx = &c.sets[0], *pr = &c.sets[1], *lg = &c.sets[2];
  const ub_llg_set *llg = d->llg && d->llg->probe_count ? d->llg : NULL;
  uint32_t LP = llg ? llg->probe_count : 0;
  const uint32_t *lact = d->llg_subset;
  const uint32_t nlact = lact ? d->llg_subset_count : LP;
  c.llg = llg;
  tx->texels = 1;
  tx->count = T;
  tx->index = d->texel_subset;
  tx->active = d->texel_subset ? d->texel_subset_count : T;
  tx->normal = lm->texel_normal;
  tx->samples = lm->sample_pos;
  tx->spr = UB_TEXEL_SAMPLES;
  tx->nsh = 4;
  tx->rays = N;
  tx->ray_shift = d->texel_ray_shift;
  tx->id_base = 0;
  tx->rt = d->rt;
  tx->acc_sh = totals ? scr_take(scache, SCR_ACC_SH, B_SH) : NULL; /* NULL: not summed */
  tx->acc_iz = scr_take(scache, SCR_ACC_IZ, B_IZ);
  tx->acc_src = scr_take(scache, SCR_ACC_SRC, B_IZ);
  tx->acc_src_np = scr_take(scache, SCR_ACC_SRC_NP, B_IZ);
  /* Texel lights: an eighth of the gather rays (at least 4) toward bright texels. */
  c.tl_samples = N / 8 < 4 ? 4 : N / 8;
  c.act = act;
  c.nact = nact;
  int tl_ok;
  ub_pass_cache *cache = d->cache;
  if (cache && cache->ok && cache->lm == lm && cache->s == s && cache->T == T) {
    tl_ok = texel_clusters_from_cache(&c, cache);
  } else {
    c.tl_area = malloc(((size_t)T + 1) * sizeof(float));
    tl_ok = c.tl_area != NULL;
    if (c.tl_area) {
      for (uint32_t t = 0; t < T; t++) {
        float w = texel_world_size(&c, t);
        c.tl_area[t] = w * w;
      }
      tl_ok = texel_clusters_build(&c);
    }
    if (tl_ok && cache && !cache->ok) {
      texel_clusters_to_cache(&c, lm, s, cache); /* best effort: without it, built again */
      if (cache->ok) { /* filled from this pass's clusters: one copy, not two */
        c.tl_tex = cache->tl_tex;
        c.tl_tex_borrowed = 1;
      }
    }
  }
  if (tl_ok && !c.tl_tex) {
    c.tl_tex = tl_tex_new(lm, c.tl_area, c.tl_of);
    tl_ok = c.tl_tex != NULL;
  }
  c.light_on = malloc(((size_t)s->light_count + 1) * sizeof *c.light_on);
  for (uint32_t l = 0; c.light_on && l < s->light_count; l++)
    if (d->light_enabled[l])
      c.light_on[c.light_on_count++] = l;
  c.nee = c.light_on_count > 0;
  pr->count = P;
  pr->index = d->probe_subset;
  pr->active = d->probe_subset ? d->probe_subset_count : P;
  pr->normal = NULL;
  pr->samples = d->probe_pos;
  pr->spr = 1;
  pr->nsh = 9;
  pr->rays = d->probe_rays ? d->probe_rays : N;
  pr->ray_shift = d->probe_ray_shift;
  pr->id_base = UB_PROBE_ID_BASE;
  pr->rt = d->rt;
  lg->count = LP;
  lg->index = d->llg_subset;
  lg->active = d->llg_subset ? d->llg_subset_count : LP;
  lg->samples = llg ? llg->probe_pos : NULL;
  lg->spr = 1;
  lg->nsh = 9;
  lg->rays = pr->rays;
  lg->ray_shift = d->llg_ray_shift;
  lg->id_base = UB_LLG_ID_BASE;
  lg->rt = llg ? llg->rt_env : d->rt;
  /* The LLG probes' arrays too when the pass has an LLG subset (written at its rows only) */
  ub_pass_cache *lcache = lact ? scache : NULL;
  const size_t B_LSH = ((size_t)LP * 27 + 1) * sizeof(double);
  lg->acc_sh = scr_take(lcache, SCR_LLG_ACC_SH, B_LSH);
  lg->acc_sh_np = scr_take(lcache, SCR_LLG_ACC_NP, B_LSH);
  tx->pass_shift = tx->ray_shift;
  pr->pass_shift = pr->ray_shift;
  lg->pass_shift = lg->ray_shift;
  if (!d->bounce_full_rays && (d->bounces < 0 || d->bounces >= 3)) {
    /* without memory every bounce keeps the full rays (same estimator, more work) */
    recv_set *sets3[3] = {tx, pr, lg};
    for (int k = 0; k < 3; k++) {
      sets3[k]->bshift = calloc((size_t)sets3[k]->count + 1, 1);
      sets3[k]->peak = calloc((size_t)sets3[k]->count + 1, sizeof(float));
      if (!sets3[k]->bshift || !sets3[k]->peak) {
        free(sets3[k]->bshift);
        free(sets3[k]->peak);
        sets3[k]->bshift = NULL;
        sets3[k]->peak = NULL;
      }
    }
  }
  double *llg_total = totals ? scr_take(lcache, SCR_LLG_TOTAL, B_LSH) : NULL;
  out->llg_direct = pool_take(scache, ((size_t)LP + 1) * sizeof(float));
  out->llg_indirect = pool_take(scache, ((size_t)LP + 1) * sizeof(float));
  /* Error estimates: this bounce's variance per texel / GLG probe, and the sum over
   * bounces. Bounces are taken as independent (var_total = Σ_k var_k): each bounce's
   * samples are fresh, and the error a receiver's bounce k inherits comes from other
   * texels' bounce k−1 samples, not its own. Bounce k reads bounce k−1's noisy lightmap:
   * that inherited noise is counted per bounce (acc_pvar, prop_var: the relative variance
   * of each texel read, rel2, times the squared sum of what the samples reading it
   * added). It matters where a few bright, noisy texels light a room (cornell: the
   * ceiling next to the lamp makes bounce 1 noisy, and bounce 2 reads it); without it the
   * estimate of the later bounces was 2× low there. What is still missed: the bilinear
   * lookup is taken as its nearest texel, texels' errors as independent (dilation shares
   * values), and errors inherited from further back than one bounce add only through
   * rel2 (which holds a texel's whole bounce-k variance, inherited part included). Not
   * included at all: the fixed per-texel sample points of far punctual lights (a
   * quadrature, the same for every seed) and the bounces the auto-stop leaves out (a
   * bias, not noise). */
  /* Without them (no_error_estimate) these stay NULL and every use below is skipped. */
  const int est = !d->no_error_estimate || d->target_error > 0.0;
  /* The stop rule's per-texel counts: needed to stop (auto bounces) or to log them. */
  const int stop_counts = totals && (d->bounces < 0 || log != NULL);
  float *rel2 = NULL;
  double *var_tx = NULL, *var_pr = NULL;
  if (est) {
    tx->acc_var = scr_take(scache, SCR_ACC_VAR, B_T);
    pr->acc_var = scr_take(scache, SCR_PR_ACC_VAR, B_P);
    tx->acc_pvar = scr_take(scache, SCR_ACC_PVAR, B_T);
    pr->acc_pvar = scr_take(scache, SCR_PR_ACC_PVAR, B_P);
    rel2 = scr_take(scache, SCR_REL2, ((size_t)T + 1) * sizeof(float));
    var_tx = scr_take(scache, SCR_VAR_TX, B_T);
    var_pr = scr_take(scache, SCR_VAR_PR, B_P);
  }
  if (LP)
    c.llg_prev = scr_take(scache, SCR_LLG_PREV, (size_t)LP * 27 * sizeof(float));
  pr->acc_sh = scr_take(scache, SCR_PR_ACC_SH, B_PSH);
  c.img = calloc(lm->atlas_count ? lm->atlas_count : 1, sizeof *c.img);
  c.emitter_of = malloc((size_t)(s->triangle_count ? s->triangle_count : 1) * sizeof(int32_t));
  int oom = (totals && (!sh_total || !iz_total || !tx->acc_sh || !probe_total || !llg_total)) ||
            !tx->acc_iz || !tx->acc_src ||
            !tl_ok || !c.light_on ||
            !tx->acc_src_np || !c.img ||
            !c.emitter_of || !pr->acc_sh || !out->texel_direct ||
            !out->texel_indirect || (d->keep_bounce_iz && !out->texel_bounce_iz) ||
            (d->outside_bounce_iz && d->outside_bounces && d->texel_subset && !outside) ||
            !out->probe_direct || !out->probe_indirect || !lg->acc_sh ||
            !lg->acc_sh_np || (LP && !c.llg_prev) || !out->llg_direct ||
            !out->llg_indirect ||
            (est && (!tx->acc_var || !pr->acc_var || !var_tx || !var_pr || !tx->acc_pvar ||
                     !pr->acc_pvar || !rel2));
  int shared = 0;
  if (!oom && act && lm->atlas_count)
    shared = d->cache && d->cache->ok && d->cache->lm == lm && sparse_base_ready(d->cache, lm);
  /* per atlas: 1 when c.img[a] is the cache's image holding the zero-light fill */
  uint8_t *img_ready = calloc(lm->atlas_count + 1, 1);
  oom |= !img_ready;
  for (uint32_t a = 0; !oom && a < lm->atlas_count; a++) {
    if (shared && scache && scache->simg && scache->simg[a]) {
      c.img[a] = scache->simg[a];
      scache->simg[a] = NULL;
      img_ready[a] = 1;
      continue;
    }
    c.img[a] = malloc((size_t)lm->atlases[a].width * lm->atlases[a].height * 4 * sizeof(float));
    oom = !c.img[a];
  }
  if (!oom && act && lm->atlas_count) {
    /* A subset pass: the zero-light image once, then refills around act only (out of
     * memory: whole refills, as a full pass) */
    c.sparse = calloc(lm->atlas_count, sizeof *c.sparse);
    int ok = c.sparse != NULL;
    for (uint32_t a = 0; ok && a < lm->atlas_count; a++)
      ok = ub_lightmap_sparse_init(lm, a, act, nact,
                                   shared && !img_ready[a] ? d->cache->zimg[a] : NULL,
                                   shared ? d->cache->zlevel[a] : NULL, c.img[a],
                                   &c.sparse[a]);
    if (!ok && c.sparse) {
      for (uint32_t a = 0; a < lm->atlas_count; a++)
        ub_lightmap_sparse_free(&c.sparse[a]);
      free(c.sparse);
      c.sparse = NULL;
    }
  }
  ub_result res = UB_OK;
  if (oom) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto done;
  }
  for (uint32_t t = 0; t < s->triangle_count; t++)
    c.emitter_of[t] = -1;
  if (d->emitters)
    for (uint32_t i = 0; i < d->emitters->count; i++)
      c.emitter_of[d->emitters->tri[i]] = (int32_t)i;

  /* Bounce 0: direct light (+ sky and emitters through gather rays). */
  int gather0 = d->sky || (d->emissive && d->emitters && d->emitters->count);
  c.bounce = 0;
  run_blocks(&c, 1, gather0, "direct", 0.0, 0.25);
  if (!atomic_load(&c.cancelled))
    refine_bounce(&c, 1, gather0, "direct", 0.25, iz_total, probe_total, var_tx, var_pr, out,
                  log);
  if (atomic_load(&c.cancelled)) {
    res = atomic_load(&c.cancelled) == 2 ? UB_ERR_OUT_OF_MEMORY : UB_ERR_CANCELLED;
    goto done;
  }
  if (est) {
#pragma omp parallel for schedule(static)
    for (uint32_t i = 0; i < nact; i++) {
      uint32_t t = ACT(i);
      var_tx[t] += tx->acc_var[t] + tx->acc_pvar[t];
    }
#pragma omp parallel for schedule(static)
    for (uint32_t i = 0; i < npact; i++) {
      uint32_t q = PACT(i);
      var_pr[q] += pr->acc_var[q] + pr->acc_pvar[q];
    }
    /* What bounce 1 reads (src or its non-punctual part), and its relative variance. */
    relative_variance(&c, c.nee ? tx->acc_src_np : tx->acc_src, rel2, act, nact);
  }
  c.prev_rel2 = rel2;
  double total_energy = energy_of(tx->acc_iz, act, nact);
  double src_energy = outgoing_energy(&c, tx->acc_src, act, nact);
  out->bounce_energy[0] = total_energy;
  /* Per receiver, independent: on every thread (serial, these loops were a fifth of an
   * influence pass's time with the other thread idle). */
#pragma omp parallel for schedule(static)
  for (uint32_t i = 0; i < nact; i++) {
    size_t t = ACT(i);
    if (totals) {
      memcpy(sh_total + 12 * t, tx->acc_sh + 12 * t, 12 * sizeof(double));
      memcpy(iz_total + 3 * t, tx->acc_iz + 3 * t, 3 * sizeof(double));
    }
    out->texel_direct[t] = (float)lum3d(tx->acc_src + 3 * t);
  }
#pragma omp parallel for schedule(static)
  for (uint32_t i = 0; i < npact; i++) {
    size_t q = PACT(i);
    if (totals)
      memcpy(probe_total + 27 * q, pr->acc_sh + 27 * q, 27 * sizeof(double));
    out->probe_direct[q] = (float)(M_PI * UB_Y0 * lum3d(pr->acc_sh + 27 * q));
  }
  /* With next-event estimation, bounce 1 reads only the non-punctual part of bounce 0. */
  build_images(&c, c.nee ? tx->acc_src_np : tx->acc_src);
  /* Texel lights carry all of bounce 0, punctual light included: a small sunlit patch is
   * the brightest source of bounce 1 and only they find it; a gather hit read as a texel
   * light then takes no NEE of its own (tl_full), so nothing is counted twice. */
  texel_lights_build(&c, tx->acc_src);
  c.tl_full = c.nee;
  /* LLG probes likewise: bounce 1 reads their non-punctual bounce 0 when NEE is on. */
#pragma omp parallel for schedule(static)
  for (uint32_t i = 0; i < nlact; i++) {
    size_t q = LACT(i);
    out->llg_direct[q] = (float)(M_PI * UB_Y0 * lum3d(lg->acc_sh + 27 * q));
    for (size_t j = 27 * q; j < 27 * q + 27; j++) {
      if (totals)
        llg_total[j] = lg->acc_sh[j];
      c.llg_prev[j] = (float)(c.nee ? lg->acc_sh_np[j] : lg->acc_sh[j]);
    }
  }
  ub_llg_fill_invalid(llg, c.llg_prev);
  scr_give(lcache, SCR_LLG_ACC_NP, lg->acc_sh_np, B_LSH, lact, nlact, 27 * sizeof(double));
  lg->acc_sh_np = NULL;
  scr_give(scache, SCR_ACC_SRC, tx->acc_src, B_IZ, act, nact, 3 * sizeof(double));
  scr_give(scache, SCR_ACC_SRC_NP, tx->acc_src_np, B_IZ, act, nact, 3 * sizeof(double));
  tx->acc_src = NULL;
  tx->acc_src_np = NULL;

  if (d->gather_donor && d->gather_subset) {
    tx->index = d->gather_subset; /* bounces ≥ 1 gather here; the others copy (below) */
    tx->active = d->gather_subset_count;
  }
  if (d->probe_gather_subset) {
    pr->index = d->probe_gather_subset;
    pr->active = d->probe_gather_subset_count;
  }
  if (d->llg_gather_donor && d->llg_gather_subset) {
    lg->index = d->llg_gather_subset;
    lg->active = d->llg_gather_subset_count;
  }
  int max_b = d->bounces < 0 ? UB_BAKE_MAX_BOUNCES : d->bounces;
  if (max_b > UB_BAKE_MAX_BOUNCES)
    max_b = UB_BAKE_MAX_BOUNCES;
  uint32_t b;
  int converged = 0;
  for (b = 1; b <= (uint32_t)max_b; b++) {
    if (src_energy <= 0.0) {
      converged = 1;
      break; /* nothing to bounce */
    }
#pragma omp parallel for schedule(static)
    for (uint32_t i = 0; i < nact; i++) {
      size_t t = ACT(i);
      if (tx->acc_sh)
        memset(tx->acc_sh + 12 * t, 0, 12 * sizeof(double));
      memset(tx->acc_iz + 3 * t, 0, 3 * sizeof(double));
      if (est)
        tx->acc_var[t] = tx->acc_pvar[t] = 0.0;
    }
#pragma omp parallel for schedule(static)
    for (uint32_t i = 0; i < npact; i++) {
      size_t q = PACT(i);
      memset(pr->acc_sh + 27 * q, 0, 27 * sizeof(double));
      if (est)
        pr->acc_var[q] = pr->acc_pvar[q] = 0.0;
    }
#pragma omp parallel for schedule(static)
    for (uint32_t i = 0; i < nlact; i++)
      memset(lg->acc_sh + 27 * (size_t)LACT(i), 0, 27 * sizeof(double));
    c.bounce = b;
    char stage[32];
    snprintf(stage, sizeof stage, "bounce %u", b);
    double sh0 = 0.25 + 0.75 * (1.0 - pow(0.5, b - 1));
    double sh1 = 0.25 + 0.75 * (1.0 - pow(0.5, b));
    run_blocks(&c, 0, 1, stage, sh0, sh1);
    if (!atomic_load(&c.cancelled))
      refine_bounce(&c, 0, 1, stage, sh1, iz_total, probe_total, var_tx, var_pr, out, log);
    if (atomic_load(&c.cancelled)) {
      res = atomic_load(&c.cancelled) == 2 ? UB_ERR_OUT_OF_MEMORY : UB_ERR_CANCELLED;
      goto done;
    }
    if (d->gather_donor && d->gather_subset) {
      uint32_t na = d->texel_subset ? d->texel_subset_count : T;
      /* a donor is its own (never written here) */
#pragma omp parallel for schedule(static)
      for (uint32_t i = 0; i < na; i++) {
        uint32_t t = d->texel_subset ? d->texel_subset[i] : i, g = d->gather_donor[t];
        if (g == t || g >= T)
          continue;
        memcpy(tx->acc_iz + 3 * (size_t)t, tx->acc_iz + 3 * (size_t)g, 3 * sizeof(double));
        if (tx->acc_sh) /* the SH rows feed sh_total alone */
          memcpy(tx->acc_sh + 12 * (size_t)t, tx->acc_sh + 12 * (size_t)g, 12 * sizeof(double));
        if (est) {
          tx->acc_var[t] = tx->acc_var[g];
          tx->acc_pvar[t] = tx->acc_pvar[g];
        }
      }
    }
    if (d->llg_gather_donor && d->llg_gather_subset) {
      uint32_t na = d->llg_subset ? d->llg_subset_count : LP;
#pragma omp parallel for schedule(static)
      for (uint32_t i = 0; i < na; i++) {
        uint32_t q = d->llg_subset ? d->llg_subset[i] : i, g = d->llg_gather_donor[q];
        if (g != q && g < LP)
          memcpy(lg->acc_sh + 27 * (size_t)q, lg->acc_sh + 27 * (size_t)g, 27 * sizeof(double));
      }
    }
    double e = energy_of(tx->acc_iz, act, nact);
    out->bounce_energy[b] = e;
#pragma omp parallel for schedule(static)
    for (uint32_t i = 0; i < nact; i++) {
      size_t t = ACT(i);
      if (totals) {
        for (size_t j = 12 * t; j < 12 * t + 12; j++)
          sh_total[j] += tx->acc_sh[j];
        for (size_t j = 3 * t; j < 3 * t + 3; j++)
          iz_total[j] += tx->acc_iz[j];
      }
      if (est)
        var_tx[t] += tx->acc_var[t] + tx->acc_pvar[t];
      out->texel_indirect[t] += (float)lum3d(tx->acc_iz + 3 * t);
      if (b <= d->keep_bounce_iz)
        for (int j = 0; j < 3; j++)
          out->texel_bounce_iz[(size_t)(b - 1) * T * 3 + 3 * t + j] = (float)tx->acc_iz[3 * t + j];
    }
#pragma omp parallel for schedule(static)
    for (uint32_t i = 0; i < npact; i++) {
      size_t q = PACT(i);
      if (totals)
        for (size_t j = 27 * q; j < 27 * q + 27; j++)
          probe_total[j] += pr->acc_sh[j];
      if (est)
        var_pr[q] += pr->acc_var[q] + pr->acc_pvar[q];
      out->probe_indirect[q] += (float)(M_PI * UB_Y0 * lum3d(pr->acc_sh + 27 * q));
    }
#pragma omp parallel for schedule(static)
    for (uint32_t i = 0; i < nlact; i++) {
      size_t q = LACT(i);
      if (totals)
        for (size_t j = 27 * q; j < 27 * q + 27; j++)
          llg_total[j] += lg->acc_sh[j];
      out->llg_indirect[q] += (float)(M_PI * UB_Y0 * lum3d(lg->acc_sh + 27 * q));
    }
    bounce_shifts(tx, tx->acc_iz, 3);
    bounce_shifts(pr, pr->acc_sh, 27);
    bounce_shifts(lg, lg->acc_sh, 27);
    total_energy += e;
    src_energy = outgoing_energy(&c, tx->acc_iz, act, nact);
    /* Stop when the bounce adds < stop_fraction of the light so far, both over the level
     * and at (almost) every texel: a bright directly lit area (a sun patch) must not end
     * the bounces while a dark corner still gains a good part of its light per bounce. */
    /* Texels below 0.1% of the mean (a dark room next to a lit one: leak-level light)
     * have nothing to converge to. */
    double mean_sum = 0.0;
    for (uint32_t i = 0; stop_counts && i < nact; i++)
      mean_sum += lum3d(iz_total + 3 * (size_t)ACT(i));
    mean_sum /= T ? T : 1;
    uint64_t gaining = 0, lit = 0;
    for (uint32_t i = 0; stop_counts && i < nact; i++) {
      uint32_t t = ACT(i);
      double add = lum3d(tx->acc_iz + 3 * (size_t)t), sum = lum3d(iz_total + 3 * (size_t)t);
      if (sum > 1e-3 * mean_sum) {
        lit++;
        gaining += add > d->stop_fraction * sum;
      }
    }
    int local_done = gaining <= (uint64_t)(UB_STOP_TEXEL_SHARE * (double)lit);
    /* Both halves of the stop rule, so a log shows which one holds the bounces. */
    if (stop_counts) /* else they were not counted (and log is NULL in such passes) */
      ub_log_printf(log, UB_LOG_INFO,
                  "  bounce %u: +%.3f%% energy; %.2f%% of lit texels gained > %.2g%% of "
                  "their own light",
                  b, total_energy > 0 ? 100.0 * e / total_energy : 0.0,
                  lit ? 100.0 * (double)gaining / (double)lit : 0.0, 100.0 * d->stop_fraction);
    if (d->bounces < 0 && local_done &&
        e <= d->stop_fraction * (total_energy - out->bounce_energy[0])) {
      converged = 1;
      b++;
      break;
    }
    if (outside) {
      /* The unsimulated texels' bounce b, estimated: what the next bounce gathers. */
      uint32_t k = b < d->outside_bounces ? b : d->outside_bounces;
      double last = out->bounce_energy[k];
      double scale = b <= d->outside_bounces ? 1.0 : (last > 0.0 ? e / last : 0.0);
      const float *src = d->outside_bounce_iz + (size_t)(k - 1) * T * 3;
#pragma omp parallel for schedule(static)
      for (uint32_t i = 0; i < nact; i++) {
        uint32_t t = ACT(i);
        if (outside[t])
          for (int j = 0; j < 3; j++)
            tx->acc_iz[3 * (size_t)t + j] = scale * src[3 * (size_t)t + j];
      }
    }
    build_images(&c, tx->acc_iz);
    texel_lights_build(&c, tx->acc_iz);
    c.tl_full = 0;
    if (est)
      relative_variance(&c, tx->acc_iz, rel2, act, nact);
#pragma omp parallel for schedule(static)
    for (uint32_t i = 0; i < nlact; i++)
      for (size_t j = 27 * (size_t)LACT(i); j < 27 * (size_t)LACT(i) + 27; j++)
        c.llg_prev[j] = (float)lg->acc_sh[j];
    ub_llg_fill_invalid(llg, c.llg_prev);
  }
  out->bounces = b - 1;
  if (d->bounces < 0 && !converged && out->bounces >= 2) {
    /* The cap ended the series (albedo near 1: a furnace at 0.999 needs thousands of
     * bounces). Estimate what is missing as the geometric tail of the last two bounces. */
    double e1 = out->bounce_energy[out->bounces], e0 = out->bounce_energy[out->bounces - 1];
    double ratio = e0 > 0.0 ? e1 / e0 : 0.0;
    double tail = ratio < 1.0 ? e1 * ratio / (1.0 - ratio) : INFINITY;
    out->bounce_cap_tail = total_energy > 0.0 ? tail / total_energy : 0.0;
    ub_log_printf(log, UB_LOG_WARNING, "bounce cap %d reached before convergence: the last "
                  "bounce added %.3f%%; the remaining bounces would add about %.3g%% more "
                  "(geometric tail, ratio %.4f). Lower the albedo below ~0.99 or accept the "
                  "bias", max_b, total_energy > 0 ? 100.0 * e1 / total_energy : 0.0,
                  100.0 * out->bounce_cap_tail, ratio);
  }

  uint64_t clamped = 0;
  if (d->no_store) /* the caller reads only the influence measures */
    goto counters;
  /* Store: SH corrected so that its irradiance along the normal is the exact I_z. A
   * compact store writes the subset's rows only (srank: act index → subset row, or
   * UINT32_MAX for an outside texel, whose values are still checked and counted). */
  const int compact = d->compact_store && d->texel_subset && d->probe_subset && act;
  const uint32_t NS = d->texel_subset_count;
  uint32_t *srank = NULL;
  if (compact) {
    out->compact = 1;
    srank = malloc(((size_t)nact + 1) * sizeof *srank);
    out->sh = malloc(((size_t)NS * 12 + 1) * sizeof(float));
    out->iz = malloc(((size_t)NS * 3 + 1) * sizeof(float));
    for (uint32_t i = 0, j = 0; srank && i < nact; i++) {
      while (j < NS && d->texel_subset[j] < act[i])
        j++;
      srank[i] = j < NS && d->texel_subset[j] == act[i] ? j : UINT32_MAX;
    }
  } else {
    out->sh = pool_take(scache, ((size_t)T * 12 + 1) * sizeof(float)); /* zero outside act */
    out->iz = pool_take(scache, ((size_t)T * 3 + 1) * sizeof(float));
  }
  if (!out->sh || !out->iz || (compact && !srank)) {
    free(srank);
    res = UB_ERR_OUT_OF_MEMORY;
    goto done;
  }
  /* Cosine lobe about n normalised to unit irradiance along n: E_h(n) = 1. */
  const double K = M_PI * M_PI * (UB_Y0 * UB_Y0) + (2.0 * M_PI / 3.0) * (2.0 * M_PI / 3.0) *
                                                     (UB_Y1 * UB_Y1);
  const double h0 = UB_Y0 * M_PI / K, h1 = UB_Y1 * (2.0 * M_PI / 3.0) / K;
#pragma omp parallel for schedule(static) reduction(+ : clamped)
  for (uint32_t i = 0; i < nact; i++) {
    uint32_t t = ACT(i);
    const float *n = lm->texel_normal + 3 * (size_t)t;
    double *sh = sh_total + 12 * (size_t)t;
    const size_t row = srank ? srank[i] : t; /* the output row, when keep */
    const int keep = !srank || srank[i] != UINT32_MAX;
    for (int ch = 0; ch < 3; ch++) {
      double e_sh = M_PI * UB_Y0 * sh[ch] +
                    (2.0 * M_PI / 3.0) * UB_Y1 *
                        (sh[3 + ch] * n[1] + sh[6 + ch] * n[2] + sh[9 + ch] * n[0]);
      double iz = iz_total[3 * (size_t)t + ch];
      if (!(iz >= 0.0) || !isfinite(iz)) {
        iz = 0.0;
        clamped++;
      }
      double delta = iz - e_sh;
      sh[ch] += delta * h0;
      sh[3 + ch] += delta * h1 * n[1];
      sh[6 + ch] += delta * h1 * n[2];
      sh[9 + ch] += delta * h1 * n[0];
      if (keep)
        out->iz[3 * row + ch] = (float)iz;
    }
    for (int i = 0; i < 12; i++) {
      float v = (float)sh[i];
      if (!isfinite(v)) {
        v = 0.0f;
        clamped++;
      }
      if (keep)
        out->sh[12 * row + i] = v;
    }
  }
  free(srank);
  out->probe_sh = finite_rows(probe_total, P, 27, pact, npact, compact, scache, &clamped);
  out->llg_sh = finite_rows(llg_total, LP, 27, lact, nlact, 0, scache, &clamped);
  if (!out->probe_sh || !out->llg_sh) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto done;
  }
  ub_llg_fill_invalid(llg, out->llg_sh);
  out->texel_se = pool_take(scache, ((size_t)T + 1) * sizeof(float));
  out->probe_se = pool_take(scache, ((size_t)P + 1) * sizeof(float));
  if (!out->texel_se || !out->probe_se) {
    res = UB_ERR_OUT_OF_MEMORY;
    goto done;
  }
  for (uint32_t i = 0; est && i < nact; i++) {
    uint32_t t = ACT(i);
    float v = (float)sqrt(var_tx[t]);
    out->texel_se[t] = isfinite(v) ? v : 0.0f;
  }
  for (uint32_t i = 0; est && i < npact; i++) {
    uint32_t q = PACT(i);
    float v = (float)sqrt(var_pr[q]);
    out->probe_se[q] = isfinite(v) ? v : 0.0f;
  }
counters:
  out->rays_gather = atomic_load(&c.rays_gather);
  out->rays_shadow = atomic_load(&c.rays_shadow);
  out->clamped = atomic_load(&c.clamped) + clamped;
  out->backface_hits = atomic_load(&c.backface);
  out->unlit_hits = atomic_load(&c.unlit);
  out->misses = atomic_load(&c.misses);
  out->rays_emissive = atomic_load(&c.rays_emissive);
  out->sky_hits = atomic_load(&c.sky_hits);
  out->emitter_hits = atomic_load(&c.emitter_hits);

done:
  if (res != UB_OK)
    ub_pass_result_free(out);
#undef ACT
#undef PACT
#undef LACT
  /* Scratch back to the cache, zeroed at act / pact (freed after a failure: what was
   * written is not known). */
  ub_pass_cache *give = res == UB_OK ? scache : NULL;
  scr_give(give, SCR_SH_TOTAL, sh_total, B_SH, act, nact, 12 * sizeof(double));
  scr_give(give, SCR_IZ_TOTAL, iz_total, B_IZ, act, nact, 3 * sizeof(double));
  scr_give(give, SCR_ACC_SH, tx->acc_sh, B_SH, act, nact, 12 * sizeof(double));
  scr_give(give, SCR_ACC_IZ, tx->acc_iz, B_IZ, act, nact, 3 * sizeof(double));
  scr_give(give, SCR_ACC_SRC, tx->acc_src, B_IZ, act, nact, 3 * sizeof(double));
  scr_give(give, SCR_ACC_SRC_NP, tx->acc_src_np, B_IZ, act, nact, 3 * sizeof(double));
  scr_give(give, SCR_ACC_VAR, tx->acc_var, B_T, act, nact, sizeof(double));
  scr_give(give, SCR_ACC_PVAR, tx->acc_pvar, B_T, act, nact, sizeof(double));
  scr_give(give, SCR_REL2, rel2, ((size_t)T + 1) * sizeof(float), act, nact, sizeof(float));
  scr_give(give, SCR_VAR_TX, var_tx, B_T, act, nact, sizeof(double));
  scr_give(give, SCR_PROBE_TOTAL, probe_total, B_PSH, pact, npact, 27 * sizeof(double));
  scr_give(give, SCR_PR_ACC_SH, pr->acc_sh, B_PSH, pact, npact, 27 * sizeof(double));
  scr_give(give, SCR_PR_ACC_VAR, pr->acc_var, B_P, pact, npact, sizeof(double));
  scr_give(give, SCR_PR_ACC_PVAR, pr->acc_pvar, B_P, pact, npact, sizeof(double));
  scr_give(give, SCR_VAR_PR, var_pr, B_P, pact, npact, sizeof(double));
  if (give && shared && c.sparse && c.img && d->cache->zimg &&
      d->cache->zatlases == lm->atlas_count) {
    if (!give->simg)
      give->simg = calloc(lm->atlas_count + 1, sizeof *give->simg);
    for (uint32_t a = 0; give->simg && a < lm->atlas_count; a++)
      if (c.img[a] && !give->simg[a] && d->cache->zimg[a]) {
        ub_lightmap_sparse_restore(&c.sparse[a], d->cache->zimg[a], c.img[a]);
        give->simg[a] = c.img[a];
        c.img[a] = NULL;
      }
  }
  free(img_ready);
  if (c.tl_tex_borrowed) /* before act goes */
    tl_tex_reset(&c);
  else
    free(c.tl_tex);
  tl_ccdf_give(&c);
  if (res == UB_OK && scache && act) { /* the rows ub_pass_result_recycle zeroes */
    out->pool = scache;
    out->pool_texels = act;
    out->pool_ntexels = nact;
    out->pool_probes = malloc(((size_t)npact + 1) * sizeof *out->pool_probes);
    if (out->pool_probes)
      memcpy(out->pool_probes, pact, (size_t)npact * sizeof *pact);
    out->pool_nprobes = npact;
    out->pool_T = T;
    out->pool_P = P;
    out->pool_LP = LP;
    out->pool_keep = d->keep_bounce_iz;
    act = NULL;
  }
  free(act);
  free(outside);
  if (!c.tl_borrowed) {
    free(c.tl_area);
    free(c.tl_of);
    free(c.tl_start);
    free(c.tl_list);
  }
  free(c.tl_cl);
  free(c.tl_hot);
  ub_pass_cache *lgive = lact ? give : NULL;
  scr_give(lgive, SCR_LLG_ACC_SH, lg->acc_sh, B_LSH, lact, nlact, 27 * sizeof(double));
  scr_give(lgive, SCR_LLG_ACC_NP, lg->acc_sh_np, B_LSH, lact, nlact, 27 * sizeof(double));
  for (int k = 0; k < 3; k++) {
    free(c.sets[k].bshift);
    free(c.sets[k].peak);
  }
  scr_give(lgive, SCR_LLG_TOTAL, llg_total, B_LSH, lact, nlact, 27 * sizeof(double));
  if (give && c.llg_prev) /* written at lact and the invalid probes: zeroed whole */
    memset(c.llg_prev, 0, (size_t)LP * 27 * sizeof(float));
  scr_give(give, SCR_LLG_PREV, c.llg_prev, (size_t)LP * 27 * sizeof(float), NULL, 0, 0);
  if (c.sparse)
    for (uint32_t a = 0; a < lm->atlas_count; a++)
      ub_lightmap_sparse_free(&c.sparse[a]);
  free(c.sparse);
  if (c.img)
    for (uint32_t a = 0; a < lm->atlas_count; a++)
      free(c.img[a]);
  free(c.img);
  free(c.emitter_of);
  free(c.light_on);
  return res;
}

void ub_pass_result_free(ub_pass_result *r)
{
  if (!r)
    return;
  free(r->sh);
  free(r->iz);
  free(r->probe_sh);
  free(r->llg_sh);
  r->llg_sh = NULL;
  free(r->texel_direct);
  free(r->texel_indirect);
  free(r->texel_bounce_iz);
  r->texel_bounce_iz = NULL;
  free(r->probe_direct);
  free(r->probe_indirect);
  free(r->llg_direct);
  free(r->llg_indirect);
  r->texel_direct = r->texel_indirect = r->probe_direct = r->probe_indirect = NULL;
  r->llg_direct = r->llg_indirect = NULL;
  free(r->texel_se);
  free(r->probe_se);
  r->texel_se = r->probe_se = NULL;
  r->sh = NULL;
  r->iz = NULL;
  r->probe_sh = NULL;
  free(r->pool_texels);
  free(r->pool_probes);
  r->pool_texels = r->pool_probes = NULL;
  r->pool = NULL;
}

/* a (bytes long) zeroed at the n rows of width floats, then back to the pool */
static void pool_give_rows(ub_pass_cache *pool, float *a, size_t bytes, const uint32_t *rows,
                           uint32_t n, size_t width)
{
  if (!a)
    return;
  zero_rows(a, rows, n, width * sizeof *a);
  pool_give(pool, a, bytes);
}

void ub_pass_result_recycle(ub_pass_result *r)
{
  ub_pass_cache *pc = r ? r->pool : NULL;
  if (!pc || !r->pool_texels || !r->pool_probes) {
    ub_pass_result_free(r);
    return;
  }
  const size_t T = r->pool_T, P = r->pool_P, LP = r->pool_LP;
  const uint32_t *tr = r->pool_texels, *pr = r->pool_probes;
  const uint32_t nt = r->pool_ntexels, np = r->pool_nprobes;
  pool_give_rows(pc, r->texel_direct, (T + 1) * sizeof(float), tr, nt, 1);
  pool_give_rows(pc, r->texel_indirect, (T + 1) * sizeof(float), tr, nt, 1);
  pool_give_rows(pc, r->texel_se, (T + 1) * sizeof(float), tr, nt, 1);
  if (!r->compact) { /* else the subsets' rows only: freed below */
    pool_give_rows(pc, r->sh, (T * 12 + 1) * sizeof(float), tr, nt, 12);
    pool_give_rows(pc, r->iz, (T * 3 + 1) * sizeof(float), tr, nt, 3);
    pool_give_rows(pc, r->probe_sh, (P * 27 + 1) * sizeof(float), pr, np, 27);
    r->sh = r->iz = r->probe_sh = NULL;
  }
  if (r->texel_bounce_iz) { /* keep planes of T × 3, each written at the act rows */
    for (uint32_t k = 0; k < r->pool_keep; k++)
      zero_rows(r->texel_bounce_iz + k * T * 3, tr, nt, 3 * sizeof(float));
    pool_give(pc, r->texel_bounce_iz, (T * 3 * r->pool_keep + 1) * sizeof(float));
  }
  pool_give_rows(pc, r->probe_direct, (P + 1) * sizeof(float), pr, np, 1);
  pool_give_rows(pc, r->probe_indirect, (P + 1) * sizeof(float), pr, np, 1);
  pool_give_rows(pc, r->probe_se, (P + 1) * sizeof(float), pr, np, 1);
  /* LLG arrays: written at the LLG subset and (llg_sh) its invalid probes: zeroed whole */
  float *la[3] = {r->llg_direct, r->llg_indirect, r->llg_sh};
  const size_t lb[3] = {(LP + 1) * sizeof(float), (LP + 1) * sizeof(float),
                        (LP * 27 + 1) * sizeof(float)};
  for (int k = 0; k < 3; k++)
    if (la[k]) {
      memset(la[k], 0, lb[k]);
      pool_give(pc, la[k], lb[k]);
    }
  r->texel_direct = r->texel_indirect = r->texel_se = NULL;
  r->texel_bounce_iz = NULL;
  r->probe_direct = r->probe_indirect = r->probe_se = NULL;
  r->llg_direct = r->llg_indirect = r->llg_sh = NULL;
  ub_pass_result_free(r);
}
