/* runtime/runtime.c — run-time state and lightmap queries (include/ubake/runtime.h). */
#include "ubake/runtime.h"
#include "ubake/glg.h"

#include <assert.h>
#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "runtime/bigalloc.h"
#include "runtime/blend.h"
#include "runtime/fpmode.h"
#include "runtime/half.h"
#include "runtime/texel_links.h"
#include "runtime/texel_sh.h"
#include "ubake/ahd.h"
#include "ubake/sh.h"

/* Texels searched around a query whose four bilinear neighbours are all empty. */
#define UB_RT_EMPTY_SEARCH_RADIUS 4

typedef struct ub_rt_fallback {
  uint32_t count;
  uint32_t *pixel; /* count, ascending */
  float *normal;   /* count × 3, unit or zero */
} ub_rt_fallback;

struct ub_runtime {
  ub_bakefile *bf;
  unsigned load_flags; /* ub_runtime_load_ex's: UB_RUNTIME_RECORDS_8BIT, _PLAIN_SUMS,
                          _KEEP_STATE, _GLG_SMALL_WALK, _NO_BASE_AHD */
  /* AHD encode normals: a covered texel's own stored normal (ub_texel_normal, made when
   * needed), else the normal of the nearest texel that has one, kept here for those few
   * texels only (per atlas, pixels ascending; a zero normal: none in the atlas, the SH's
   * own direction is used). */
  ub_rt_fallback *fallback; /* atlas_count */
  /* Every covered texel's stored normal as the file's halves (3 per slot, global slot
   * order; made at the end of load, when the bake file's float copies go: the same values,
   * half the bytes; padding and empty pixels keep none: a padding pixel shows its source). */
  uint16_t *nrm;
  uint64_t *pixel_first; /* atlas_count + 1: first global pixel of each atlas */
  /* Per-texel run-time arrays hold covered texels only (coverage 1; ESTATE-like levels
   * cover ~60% of their atlas pixels): a texel's slot is its rank among the covered
   * pixels of its atlas (slot_of), global slots number atlas after atlas. */
  uint64_t *slot_first;  /* atlas_count + 1: first global slot of each atlas */
  uint64_t **cov_bits;   /* atlas_count arrays of ⌈pixels / 64⌉ words: coverage 1 */
  uint32_t **cov_rank;   /* atlas_count arrays: covered pixels before each 64-pixel word */
  uint32_t *slot_pixel;  /* global slot → pixel within its atlas */
  /* Dilated padding pixels (coverage 2) are no texels of their own: each shows the covered
   * texel it copies (dil_src; build_dilation), so records, base rows and AHD hold covered
   * texels only. Per atlas: the padding pixels some texel reaches, their rank per word,
   * and per such pixel (ascending) the covered pixel it copies. */
  uint64_t **dil_bits;
  uint32_t **dil_rank;
  uint32_t **dil_src;
  /* Dynamic light sets (when the file has any): blended SH, re-encoded where touched. */
  /* The texels' SH in the file's I_z form (below): the texels some record touches have
   * their current state computed by the lightmap blend (streamed into the AHD re-encode
   * at an update, ub_blend_row for a query: no blended array is kept); the others never
   * change and keep the file's halves (lm_static × lm_static_scale, a power of two). A
   * slot's index in either: slot_touched (a rank, or its rank among the untouched). */
  float *lm_base;          /* during setup: Σ slots × 12 */
  float *lm_tbase;         /* during setup: touched slots × 12, the blend's base rows */
  float *lm_un;            /* touched slots × 3: the unit normal the AHD re-encode uses
                              (ub_texel_normal of the stored one, made once at load: it
                              was an eighth of a toggle), NaN first when the texel has
                              none (the fallback's) */
  int lm_un_all;           /* every touched texel has a normal of its own (no NaN in lm_un) */
  uint16_t *lm_static;     /* untouched slots × 12 */
  float lm_static_scale;
  double lm_row_max;       /* the largest |value| of the lightmap's rows, base (every
                              texel's) and records: what the AHD scale is chosen from */
  uint64_t *tch_bits;      /* ⌈slots / 64⌉ words: the slot is touched */
  uint32_t *tch_rank;      /* touched slots before each word */
  /* A touched slot's index (its "rank": in lm_un, tch_slot, the lightmap blend's
   * receivers and, once ahd_ranked, the AHD array) is not its bitmap rank but its place
   * in group-major order: texels with the same combination of records are consecutive
   * (in slot order within it), so each blend group is one run and an update streams
   * through every per-texel array instead of hopping between a list group's texels
   * (those random reads were a third of an all-sets update at ESTATE full scale). */
  uint32_t *tch_grp;       /* touched slots in bitmap-rank order → their rank */
  uint64_t touched;        /* touched slots */
  uint32_t *tch_slot;      /* touched slots × 1: the global slot of each (the lightmap blend
                              works in touched ranks) */
  uint32_t *lm_idx;        /* during setup: the texel records' receivers as global slots */
  /* Merged groups (unless UB_RUNTIME_SEPARATE_GROUPS): the merged texels (given zero
   * rows), so that an update whose changed elements are only their added ones leaves them
   * as they are (neither re-encoded nor listed as changed: an update touches the texels it
   * would with separate groups). pad_bits: ⌈touched / 64⌉ words over the ranks; pad_rank:
   * merged texels before each word; per merged texel (rank order) pad_tid, the
   * combination it joined (its records: pad_el[pad_off[t] .. pad_off[t + 1]), at most 64),
   * and pad_mask, which of those records it has zero rows in. NULL: nothing merged. */
  uint64_t *pad_bits, *pad_mask;
  uint32_t *pad_rank, *pad_tid, *pad_off, *pad_el;
  struct merge_pad *pad_tmp; /* during setup: the merged texels (merge_small_groups) */
  uint32_t pad_count;      /* merged texels */
  uint32_t pad_targets;    /* the combinations they joined */
  uint8_t *pad_stay;       /* per merged texel: 1 when the last update that computed it
                              left it as it was (read only within that update's runs, and
                              only when that update could leave texels: chg_stay) */
  uint8_t *lm_chg;         /* elem_total: the lightmap weight changed in the update begun */
  int pad_skip;            /* the update begun may leave merged texels (not every group,
                              not every element) */
  /* Record values in half precision inside the blends, as the file stores them (per
   * representation divided by a power-of-two scale, which the weights given to the blend
   * are multiplied by: (w·s)·h and w·(s·h) round to the same float). Texel
   * values and base rows are in the I_z form of runtime/texel_sh.h (L00 replaced by the
   * irradiance along the texel's stored normal), where half rounding keeps I_z to half
   * precision even under grazing light; readers unpack a texel before use (texel_sh_at). */
  float lm_scale, glg_scale, llg_scale;
  ub_blend *lm_blend, *glg_blend, *llg_blend;
  ub_blend_record *lm_rec, *glg_rec, *llg_rec;
  /* Elements: the sets, then the file's doors/objects/combinations (ELEM). value is what
   * the caller set (RGB), applied what the blends use (see runtime.h). */
  uint32_t elem_total;
  float *value, *applied;  /* elem_total × 3 */
  float *updated;          /* elem_total: value[3e] as of the last update (begun), which
                              ub_runtime_triangle_shown reads: the geometry a door or object
                              shows changes with its lighting, at the update */
  /* LLG probes of all models in order (when records touch them): blended here, and the
   * touched probes copied back into each model's grid, which queries read. */
  float *llg_base, *llg_cur;
  uint64_t *llg_first;     /* llg_count + 1 */
  atomic_uchar *llg_chg;   /* llg_count: the last update wrote some of the model's probes
                              (set by any job: atomic) */
  ub_glg glg;            /* valid when has_glg */
  int has_glg;
  /* The AHD of every covered texel (slots entries), packed (ubake/ahd.h, 16 B: halves of
   * value / ahd_scale and an octahedral direction; what a game uploads): always the pack of
   * the float AHD encoded from the texel's current row (texel_row), as
   * ub_runtime_texel_irradiance encodes it. Made by init_ahd (the untouched texels) and
   * the set-up's update of every group (the touched ones). With records (ahd_ranked) the
   * touched texels come first by rank, so an update writes it sequentially, then the
   * untouched ones in slot order (ahd_index). */
  ub_ahd_packed *ahd;
  /* ub_runtime_keep_state: the touched texels' AHD (by rank) at the kept state, which the
   * lightmap blend's reference weights are; an update copies them back for the groups
   * whose weights are those again (UB_BLEND_AT_REFERENCE). NULL: none kept. */
  ub_ahd_packed *ahd_kept;
  /* The touched texels' AHD (by rank) with every element at 0, encoded at load: an update
   * copies them for the groups whose weights are all 0 (UB_BLEND_AT_BASE), so turning a
   * set off re-encodes only the texels another set still lights. NULL:
   * UB_RUNTIME_NO_BASE_AHD. */
  ub_ahd_packed *ahd_base;
  float ahd_scale, ahd_inv_scale; /* a power of two ≥ 1, and its inverse */
  int ahd_ranked;
  /* Jobs of the update in progress (ub_runtime_update_begin … end). */
  struct rt_job *jobs;
  uint32_t job_cap, job_count;
  /* The texels each job re-encoded, as runs of ranks (first, count) merged where they
   * continue each other: a group's ranks are one run, so job j needs at most as many as
   * the lightmap blend's part j has groups (ub_blend_part_first), and one more: its runs
   * start at pair chg_at[j] = first(j) + j of chg_pairs(job_cap) pairs. A run may hold
   * merged texels the update left as they were (pad_stay): not changed. The last
   * update's jobs (chg_jobs) stay there for ub_runtime_changed_texels; chg_all when a job
   * ran out of room (not expected): every touched texel then counts as changed. */
  uint32_t *chg_runs;
  uint32_t *chg_at;   /* job_cap: each job's first pair */
  uint32_t chg_groups, chg_jobs;
  uint64_t chg_texels;
  int chg_all;
  int chg_stay;       /* the last update may have left merged texels in its runs (pad_skip) */
  uint32_t lit_count;    /* triangles with tri_atlas >= 0 */
  uint32_t *lit_tris;
};

/* One job's results (ub_runtime_update_job), added up by ub_runtime_update_end. */
typedef struct rt_job {
  ub_blend_stats lm, glg, llg;
  uint64_t texels;    /* re-encoded (or copied back from the kept state) */
  uint64_t kept;      /* of them, copied back */
  uint64_t based;     /* of them, the base's copied (every element at 0) */
  uint64_t left;      /* merged texels computed and left as they were (lm_touched) */
  uint32_t runs;      /* runs of them in chg_runs */
  int runs_full;      /* some did not fit */
  int done;           /* run (ub_runtime_update_end runs the ones that were not) */
  double seconds[3];  /* lightmap, GLG, LLG */
} rt_job;

static const float ub_rt_luma[3] = {0.2126f, 0.7152f, 0.0722f};

/* A log that puts the file's name before each message (path NULL: passes them as they
 * are), counting the errors. */
typedef struct named_log {
  const ub_log *to;
  const char *path;
  int errors;
} named_log;

static void named_log_fn(void *user, ub_log_level level, const char *message)
{
  named_log *nl = user;
  nl->errors += level == UB_LOG_ERROR;
  if (nl->path)
    ub_log_printf(nl->to, level, "%s: %s", nl->path, message);
  else
    ub_log_printf(nl->to, level, "%s", message);
}

/* Slot (within its atlas) of covered pixel i of atlas a. */
static inline uint64_t slot_of(const ub_runtime *rt, uint32_t a, size_t i)
{
  uint64_t w = rt->cov_bits[a][i >> 6], below = w & ((UINT64_C(1) << (i & 63)) - 1);
  return rt->cov_rank[a][i >> 6] + (uint64_t)__builtin_popcountll(below);
}

/* Touched slots before global slot s (s's bitmap rank when it is touched). */
static inline uint64_t touched_before(const ub_runtime *rt, uint64_t s)
{
  uint64_t below = rt->tch_bits[s >> 6] & ((UINT64_C(1) << (s & 63)) - 1);
  return rt->tch_rank[s >> 6] + (uint64_t)__builtin_popcountll(below);
}

/* Whether global slot s is touched by a record, and its index among the touched (its
 * rank) or untouched slots. */
static inline int slot_touched(const ub_runtime *rt, uint64_t s, uint64_t *out_index)
{
  uint64_t t = touched_before(rt, s);
  int on = (int)((rt->tch_bits[s >> 6] >> (s & 63)) & 1u);
  *out_index = on ? rt->tch_grp[t] : s - t;
  return on;
}

/* Where the AHD of slot sa of atlas a is in rt->ahd. */
static inline uint64_t ahd_index(const ub_runtime *rt, uint32_t a, uint64_t sa)
{
  uint64_t s = rt->slot_first[a] + sa, ix;
  if (!rt->ahd_ranked)
    return s;
  return slot_touched(rt, s, &ix) ? ix : rt->touched + ix;
}

/* The atlas of global slot s (atlases are few: a scan). */
static inline uint32_t slot_atlas(const ub_runtime *rt, uint64_t s)
{
  uint32_t a = 0;
  while (s >= rt->slot_first[a + 1])
    a++;
  return a;
}

/* The packed AHD and the stored normal's halves of covered pixel i of atlas a. */
static inline ub_ahd_packed *texel_ahd_of(const ub_runtime *rt, uint32_t a, size_t i)
{
  return &rt->ahd[ahd_index(rt, a, slot_of(rt, a, i))];
}

static inline const uint16_t *texel_nrm_of(const ub_runtime *rt, uint32_t a, size_t i)
{
  return rt->nrm + (rt->slot_first[a] + slot_of(rt, a, i)) * 3;
}

/* No LLG model changed (before an update; after the set-up's, which wrote them all). */
static void llg_chg_clear(ub_runtime *rt)
{
  for (uint32_t m = 0; rt->llg_chg && m < rt->bf->llg_count; m++)
    atomic_store_explicit(&rt->llg_chg[m], 0, memory_order_relaxed);
}

/* The covered texel (a pixel of coverage 1) that pixel i of atlas a shows: itself, or for
 * a dilated padding pixel the texel it copies; -1 for an empty pixel (or padding no texel
 * reaches). */
static inline int64_t texel_pixel(const ub_runtime *rt, uint32_t a, size_t i)
{
  const uint8_t c = rt->bf->atlases[a].coverage[i];
  if (c == 1)
    return (int64_t)i;
  if (c != 2)
    return -1;
  const uint64_t w = rt->dil_bits[a][i >> 6], bit = UINT64_C(1) << (i & 63);
  if (!(w & bit))
    return -1;
  return rt->dil_src[a][rt->dil_rank[a][i >> 6] + (uint64_t)__builtin_popcountll(w & (bit - 1))];
}

/* Which covered texel each dilated padding pixel of atlas a copies, ring by ring as the
 * baker grows its padding (ub_lightmap_dilate): a pixel of ring r (r 8-neighbour steps
 * through padding from the nearest covered texel) copies the texel of its first
 * 8-neighbour (rows top to bottom, left to right) of ring r − 1: a texel at the smallest
 * Chebyshev distance. One breadth-first search from the covered texels, linear in the
 * pixels (a file's padding may be any shape). The padding then shows that texel's state
 * exactly (the baker's ring averages are not kept: one texel's AHD per padding pixel is
 * what a game's copy-dilation gives too); padding no texel reaches shows nothing. */
static ub_result build_dilation(ub_runtime *rt, uint32_t a)
{
  const ub_bakefile_atlas *at = &rt->bf->atlases[a];
  const size_t w = at->width, h = at->height, px = w * h, words = (px + 63) / 64;
  int32_t *src = ub_big_alloc((px ? px : 1) * sizeof *src);
  uint32_t *ring = ub_big_alloc((px ? px : 1) * sizeof *ring);
  uint32_t *queue = ub_big_alloc((px ? px : 1) * sizeof *queue);
  rt->dil_bits[a] = ub_big_calloc(words ? words : 1, sizeof **rt->dil_bits);
  rt->dil_rank[a] = ub_big_alloc((words ? words : 1) * sizeof **rt->dil_rank);
  ub_result r = UB_ERR_OUT_OF_MEMORY;
  if (!src || !ring || !queue || !rt->dil_bits[a] || !rt->dil_rank[a])
    goto done;
  size_t head = 0, tail = 0, nd = 0;
  for (size_t i = 0; i < px; i++) {
    src[i] = -1;
    ring[i] = UINT32_MAX;
    if (at->coverage[i] == 1) {
      src[i] = (int32_t)i;
      ring[i] = 0;
      queue[tail++] = (uint32_t)i;
    }
  }
  /* Dequeued in ring order: a padding pixel's ring r − 1 neighbours have their texel. */
  while (head < tail) {
    const size_t i = queue[head++], x = i % w, y = i / w;
    const uint32_t ri = ring[i];
    for (int dy = -1; dy <= 1; dy++)
      for (int dx = -1; dx <= 1; dx++) {
        if ((dx == 0 && dy == 0) || (dy < 0 && y == 0) || (dy > 0 && y + 1 >= h) ||
            (dx < 0 && x == 0) || (dx > 0 && x + 1 >= w))
          continue;
        const size_t j = (size_t)((int64_t)i + dy * (int64_t)w + dx);
        if (ri > 0 && src[i] < 0 && ring[j] == ri - 1)
          src[i] = src[j]; /* the first ring r − 1 neighbour in scan order */
        if (at->coverage[j] == 2 && ring[j] == UINT32_MAX) {
          ring[j] = ri + 1;
          queue[tail++] = (uint32_t)j;
        }
      }
  }
  for (size_t i = 0; i < px; i++)
    if (at->coverage[i] == 2 && src[i] >= 0) {
      rt->dil_bits[a][i >> 6] |= UINT64_C(1) << (i & 63);
      nd++;
    }
  rt->dil_src[a] = ub_big_alloc((nd ? nd : 1) * sizeof **rt->dil_src);
  if (!rt->dil_src[a])
    goto done;
  nd = 0;
  for (size_t wd = 0; wd < words; wd++) {
    rt->dil_rank[a][wd] = (uint32_t)nd;
    for (size_t i = wd * 64; i < px && i < wd * 64 + 64; i++)
      if (rt->dil_bits[a][wd] >> (i & 63) & 1)
        rt->dil_src[a][nd++] = (uint32_t)src[i];
  }
  r = UB_OK;
done:
  free(src);
  free(ring);
  free(queue);
  return r;
}

/* Builds the coverage bits, ranks and slot → pixel map (covered texels: coverage 1) and
 * the dilated padding's sources; sets slot_first. */
static ub_result build_slots(ub_runtime *rt)
{
  const ub_bakefile *bf = rt->bf;
  uint32_t na = bf->atlas_count;
  rt->slot_first = ub_big_calloc((size_t)na + 1, sizeof *rt->slot_first);
  rt->cov_bits = ub_big_calloc(na ? na : 1, sizeof *rt->cov_bits);
  rt->cov_rank = ub_big_calloc(na ? na : 1, sizeof *rt->cov_rank);
  rt->dil_bits = ub_big_calloc(na ? na : 1, sizeof *rt->dil_bits);
  rt->dil_rank = ub_big_calloc(na ? na : 1, sizeof *rt->dil_rank);
  rt->dil_src = ub_big_calloc(na ? na : 1, sizeof *rt->dil_src);
  if (!rt->slot_first || !rt->cov_bits || !rt->cov_rank || !rt->dil_bits || !rt->dil_rank ||
      !rt->dil_src)
    return UB_ERR_OUT_OF_MEMORY;
  for (uint32_t a = 0; a < na; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    size_t px = (size_t)at->width * at->height, words = (px + 63) / 64;
    rt->cov_bits[a] = ub_big_calloc(words ? words : 1, sizeof **rt->cov_bits);
    rt->cov_rank[a] = ub_big_alloc((words ? words : 1) * sizeof **rt->cov_rank);
    if (!rt->cov_bits[a] || !rt->cov_rank[a])
      return UB_ERR_OUT_OF_MEMORY;
    uint64_t n = 0;
    for (size_t w = 0; w < words; w++) {
      rt->cov_rank[a][w] = (uint32_t)n;
      for (size_t i = w * 64; i < px && i < w * 64 + 64; i++)
        if (at->coverage[i] == 1) {
          rt->cov_bits[a][w] |= UINT64_C(1) << (i & 63);
          n++;
        }
    }
    rt->slot_first[a + 1] = rt->slot_first[a] + n;
    if (build_dilation(rt, a) != UB_OK)
      return UB_ERR_OUT_OF_MEMORY;
  }
  uint64_t slots = rt->slot_first[na];
  rt->slot_pixel = ub_big_alloc((size_t)(slots ? slots : 1) * sizeof *rt->slot_pixel);
  if (!rt->slot_pixel)
    return UB_ERR_OUT_OF_MEMORY;
  for (uint32_t a = 0; a < na; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    uint32_t *sp = rt->slot_pixel + rt->slot_first[a];
    for (size_t i = 0; i < (size_t)at->width * at->height; i++)
      if (at->coverage[i] == 1)
        *sp++ = (uint32_t)i;
  }
  return UB_OK;
}

static int normalise3(const float v[3], float out[3])
{
  if (!isfinite(v[0]) || !isfinite(v[1]) || !isfinite(v[2]))
    return 0;
  double l = sqrt((double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2]);
  if (!(l > 0.0))
    return 0;
  for (int i = 0; i < 3; i++)
    out[i] = (float)(v[i] / l);
  return 1;
}

/* Normal for a texel that has none: the luminance-weighted direction of the SH L1 band
 * (where most light comes from), else +Y. L1 order is (y, z, x). */
static void sh_dominant_direction(const float sh[UB_SH1_FLOATS], float out_n[3])
{
  float d[3] = {0, 0, 0};
  for (int c = 0; c < 3; c++) {
    d[0] += ub_rt_luma[c] * sh[3 * 3 + c];
    d[1] += ub_rt_luma[c] * sh[1 * 3 + c];
    d[2] += ub_rt_luma[c] * sh[2 * 3 + c];
  }
  if (!normalise3(d, out_n)) {
    out_n[0] = 0;
    out_n[1] = 1;
    out_n[2] = 0;
  }
}

/* Encode normals of one atlas's covered texels without a usable normal of their own: the
 * normal of the nearest texel (8-connected multi-source BFS) that has one; zero where no
 * texel of the atlas has a normal (the SH's own direction is used). */
static ub_result encode_fallbacks(const ub_bakefile_atlas *at, ub_rt_fallback *out)
{
  size_t texels = (size_t)at->width * at->height, need = 0;
  float un[3];
  for (size_t i = 0; i < texels; i++)
    need += at->coverage[i] != 0 && !ub_texel_normal(&at->normal[i * 3], un);
  memset(out, 0, sizeof *out);
  if (!need)
    return UB_OK;
  int32_t *src = ub_big_alloc(texels * sizeof *src);   /* texel whose normal is used, -1 none */
  uint32_t *queue = ub_big_alloc(texels * sizeof *queue);
  out->pixel = ub_big_alloc(need * sizeof *out->pixel);
  out->normal = ub_big_calloc(need * 3, sizeof *out->normal);
  if (!src || !queue || !out->pixel || !out->normal) {
    free(src);
    free(queue);
    free(out->pixel);
    free(out->normal);
    memset(out, 0, sizeof *out);
    return UB_ERR_OUT_OF_MEMORY;
  }
  size_t head = 0, tail = 0;
  for (size_t i = 0; i < texels; i++) {
    src[i] = -1;
    if (at->coverage[i] != 0 && ub_texel_normal(&at->normal[i * 3], un)) {
      src[i] = (int32_t)i;
      queue[tail++] = (uint32_t)i;
    }
  }
  while (head < tail) {
    uint32_t i = queue[head++];
    int64_t x = i % at->width, y = i / at->width;
    for (int dy = -1; dy <= 1; dy++)
      for (int dx = -1; dx <= 1; dx++) {
        int64_t nx = x + dx, ny = y + dy;
        if (nx < 0 || ny < 0 || nx >= at->width || ny >= at->height)
          continue;
        size_t j = (size_t)ny * at->width + (size_t)nx;
        if (src[j] >= 0)
          continue;
        src[j] = src[i];
        queue[tail++] = (uint32_t)j;
      }
  }
  for (size_t i = 0; i < texels; i++)
    if (at->coverage[i] != 0 && !ub_texel_normal(&at->normal[i * 3], un)) {
      out->pixel[out->count] = (uint32_t)i;
      if (src[i] >= 0)
        ub_texel_normal(&at->normal[(size_t)src[i] * 3], &out->normal[out->count * 3]);
      out->count++;
    }
  free(src);
  free(queue);
  return UB_OK;
}

/* ub_texel_normal of covered pixel i's stored normal in atlas a (the bake file's floats
 * during load, the same values from rt->nrm after it). */
static int stored_normal(const ub_runtime *rt, uint32_t a, size_t i, float out_n[3])
{
  const float *f = rt->bf->atlases[a].normal;
  if (f)
    return ub_texel_normal(&f[i * 3], out_n);
  assert(rt->bf->atlases[a].coverage[i] == 1);
  const uint16_t *h = texel_nrm_of(rt, a, i);
  const float n[3] = {ub_half_to_float(h[0]), ub_half_to_float(h[1]), ub_half_to_float(h[2])};
  return ub_texel_normal(n, out_n);
}

/* The encode normal of covered texel i of atlas a (unit, or zero: use the SH's direction);
 * returns whether it is the texel's own normal (then the I_z form unpacks with it). */
static int encode_normal(const ub_runtime *rt, uint32_t a, size_t i, float out_n[3])
{
  const ub_rt_fallback *fb = &rt->fallback[a];
  if (stored_normal(rt, a, i, out_n))
    return 1;
  size_t lo = 0, hi = fb->count;
  while (lo < hi) {
    size_t mid = (lo + hi) / 2;
    if (fb->pixel[mid] < i)
      lo = mid + 1;
    else
      hi = mid;
  }
  if (lo < fb->count && fb->pixel[lo] == i)
    memcpy(out_n, &fb->normal[lo * 3], 3 * sizeof(float));
  else
    out_n[0] = out_n[1] = out_n[2] = 0.0f;
  return 0;
}

/* Covered pixel i's SH L1 from its row (I_z form when packed, else plain) into out_sh, and
 * its encode normal into out_n (see encode_normal). */
static void texel_sh_at(const ub_runtime *rt, uint32_t a, const float *row, int packed,
                        size_t i, float out_sh[UB_SH1_FLOATS], float out_n[3])
{
  memcpy(out_sh, row, UB_SH1_FLOATS * sizeof(float));
  if (encode_normal(rt, a, i, out_n) && packed)
    ub_texel_sh_unpack(out_sh, out_n);
}

/* The AHD of one covered pixel i from its SH row. A packed row of a texel with its own
 * normal (the I_z form along that normal) is encoded as it is (ub_ahd_encode_iz). */
static void encode_texel(const ub_runtime *rt, uint32_t a, const float *row, int packed,
                         size_t i, ub_ahd *out)
{
  float v[UB_SH1_FLOATS], n[3];
  if (packed && stored_normal(rt, a, i, n)) {
    ub_ahd_encode_iz(row, n, out);
    return;
  }
  texel_sh_at(rt, a, row, packed, i, v, n);
  if (n[0] == 0.0f && n[1] == 0.0f && n[2] == 0.0f)
    sh_dominant_direction(v, n);
  ub_ahd_encode(v, n, out);
}

/* encode_texel, packed at the run-time's AHD scale. */
static void encode_texel_packed(const ub_runtime *rt, uint32_t a, const float *row, int packed,
                                size_t i, ub_ahd_packed *out)
{
  ub_ahd f;
  encode_texel(rt, a, row, packed, i, &f);
  ub_ahd_pack(&f, rt->ahd_inv_scale, out);
}

/* ub_blend_create_ex's values_done: element e's halves (user: its ub_blend_record array)
 * are copied into the blend, which reads them no more. */
static void rec_values_done(void *user, uint32_t e)
{
  ub_blend_record *recs = user;
  free((void *)(uintptr_t)recs[e].values);
  recs[e].values = NULL;
}

/* Frees the records' halves records_prepare handed to n elements (the blend made from them
 * keeps its own copy). */
static void free_rec_values(ub_blend_record *recs, uint32_t n)
{
  for (uint32_t e = 0; recs && e < n; e++) {
    free((void *)(uintptr_t)recs[e].values);
    recs[e].values = NULL;
  }
}

void ub_runtime_free(ub_runtime *rt)
{
  if (!rt)
    return;
  free(rt->ahd);
  free(rt->ahd_kept);
  free(rt->ahd_base);
  free(rt->jobs);
  free(rt->chg_runs);
  free(rt->chg_at);
  free(rt->llg_chg);
  if (rt->fallback)
    for (uint32_t a = 0; a < rt->bf->atlas_count; a++) {
      free(rt->fallback[a].pixel);
      free(rt->fallback[a].normal);
    }
  free(rt->fallback);
  free(rt->nrm);
  free(rt->pixel_first);
  if (rt->cov_bits)
    for (uint32_t a = 0; a < rt->bf->atlas_count; a++)
      free(rt->cov_bits[a]);
  if (rt->cov_rank)
    for (uint32_t a = 0; a < rt->bf->atlas_count; a++)
      free(rt->cov_rank[a]);
  free(rt->cov_bits);
  free(rt->cov_rank);
  for (uint32_t a = 0; a < rt->bf->atlas_count; a++) {
    if (rt->dil_bits)
      free(rt->dil_bits[a]);
    if (rt->dil_rank)
      free(rt->dil_rank[a]);
    if (rt->dil_src)
      free(rt->dil_src[a]);
  }
  free(rt->dil_bits);
  free(rt->dil_rank);
  free(rt->dil_src);
  free(rt->slot_first);
  free(rt->slot_pixel);
  free(rt->lm_idx);
  free(rt->pad_bits);
  free(rt->pad_mask);
  free(rt->pad_rank);
  free(rt->pad_tid);
  free(rt->pad_tmp);
  free(rt->pad_off);
  free(rt->pad_el);
  free(rt->lm_chg);
  free(rt->pad_stay);
  ub_blend_free(rt->lm_blend);
  ub_blend_free(rt->glg_blend);
  ub_blend_free(rt->llg_blend);
  free_rec_values(rt->lm_rec, rt->elem_total);
  free_rec_values(rt->glg_rec, rt->elem_total);
  free_rec_values(rt->llg_rec, rt->elem_total);
  free(rt->lm_rec);
  free(rt->glg_rec);
  free(rt->llg_rec);
  free(rt->value);
  free(rt->applied);
  free(rt->updated);
  free(rt->llg_base);
  free(rt->lm_base);
  free(rt->lm_tbase);
  free(rt->lm_un);
  free(rt->lm_static);
  free(rt->tch_bits);
  free(rt->tch_rank);
  free(rt->tch_slot);
  free(rt->tch_grp);
  free(rt->lit_tris);
  if (rt->has_glg)
    ub_glg_release(&rt->glg);
  /* Detach the bake file's arrays that point into the current state (setup_elements). */
  for (uint32_t m = 0; rt->llg_cur && m < rt->bf->llg_count; m++)
    if (rt->bf->llgs[m].probe_sh == rt->llg_cur + rt->llg_first[m] * 27)
      rt->bf->llgs[m].probe_sh = NULL;
  free(rt->llg_cur);
  free(rt->llg_first);
  ub_bakefile_free(rt->bf);
  free(rt);
}

static ub_bakefile_record *element_record_rw(ub_bakefile *bf, uint32_t e)
{
  return e < bf->dls_count ? &bf->dls[e] : &bf->elems[e - bf->dls_count];
}

static const ub_bakefile_record *element_record(const ub_bakefile *bf, uint32_t e)
{
  return element_record_rw((ub_bakefile *)(uintptr_t)bf, e);
}

/* A record's values of one representation (0 texels, 1 GLG probes, 2 LLG probes) as read
 * with UB_BAKEFILE_RECORD_HALVES: where the array is held. */
static uint16_t **record_halves(ub_bakefile_record *rc, int rep)
{
  return rep == 0 ? &rc->texel_sh_half : rep == 1 ? &rc->probe_sh_half : &rc->llg_probe_sh_half;
}

/* The weight an element's record is applied with (see runtime.h). */
static void element_applied(const ub_runtime *rt, uint32_t e, float out[3])
{
  const ub_bakefile_record *r = element_record(rt->bf, e);
  if (r->kind == UB_ELEMENT_COMBO) {
    float a[3], b[3];
    element_applied(rt, (uint32_t)r->parent[0], a); /* parents are never combinations */
    element_applied(rt, (uint32_t)r->parent[1], b);
    for (int c = 0; c < 3; c++)
      out[c] = a[c] * b[c];
    return;
  }
  float baked = r->kind == UB_ELEMENT_OBJECT ? 1.0f : 0.0f;
  for (int c = 0; c < 3; c++)
    out[c] = rt->value[3 * (size_t)e + c] - baked;
}

static ub_result push_applied(ub_runtime *rt, uint32_t e)
{
  float w[3];
  element_applied(rt, e, w);
  memcpy(rt->applied + 3 * (size_t)e, w, sizeof w);
  /* Each blend's records are stored ÷ its pool scale (a power of two): w × scale is exact
   * and gives the same products. */
  float wl[3], wg[3], wh[3];
  for (int c = 0; c < 3; c++) {
    wl[c] = w[c] * rt->lm_scale;
    wg[c] = w[c] * rt->glg_scale;
    wh[c] = w[c] * rt->llg_scale;
  }
  ub_result r = ub_blend_set_weight(rt->lm_blend, e, wl);
  if (r == UB_OK && rt->glg_blend)
    r = ub_blend_set_weight(rt->glg_blend, e, wg);
  if (r == UB_OK && rt->llg_blend)
    r = ub_blend_set_weight(rt->llg_blend, e, wh);
  return r;
}

/* Sets element e's value and re-applies it and every combination it is a parent of. */
static ub_result set_value(ub_runtime *rt, uint32_t e, const float rgb[3])
{
  memcpy(rt->value + 3 * (size_t)e, rgb, 3 * sizeof(float));
  ub_result r = push_applied(rt, e);
  const ub_bakefile *bf = rt->bf;
  for (uint32_t k = 0; r == UB_OK && k < bf->elem_count; k++)
    if (bf->elems[k].kind == UB_ELEMENT_COMBO &&
        (bf->elems[k].parent[0] == (int32_t)e || bf->elems[k].parent[1] == (int32_t)e))
      r = push_applied(rt, bf->dls_count + k);
  return r;
}

/* The power of two ≥ 1 that brings mx within the half range with margin (as the writer). */
static float half_pool_scale(double mx)
{
  float s = 1.0f;
  while (mx / s > 32768.0 && s < 1e30f)
    s *= 2.0f;
  return s;
}

/* Global pixel p: its atlas (*inout_atlas, a cursor: receivers are sorted, start at 0)
 * and pixel within it (*out_local); 0 if p is past the atlases. */
static int pixel_locate(const ub_runtime *rt, uint64_t p, uint32_t *inout_atlas,
                        size_t *out_local)
{
  const ub_bakefile *bf = rt->bf;
  uint32_t a = *inout_atlas;
  while (a + 1 < bf->atlas_count && p >= rt->pixel_first[a + 1])
    a++;
  *inout_atlas = a;
  if (a >= bf->atlas_count || p < rt->pixel_first[a] || p >= rt->pixel_first[a + 1])
    return 0;
  *out_local = (size_t)(p - rt->pixel_first[a]);
  return 1;
}

/* One representation's records readied for its blend from the file's halves (read with
 * UB_BAKEFILE_RECORD_HALVES; texel rows in the file's I_z form, as the blend wants them):
 * every value brought from the file's scale to one power-of-two scale for the whole
 * representation that keeps it in the half range (recs[e].values, the run-time's now;
 * the blend keeps the halves, the weights are multiplied by the scale: (w·s)·h and
 * w·(s·h) round to the same float). Texel records: receivers become global slots
 * (rt->lm_idx) and entries on empty or padding pixels (never read) are dropped. */
static ub_result records_prepare(ub_runtime *rt, int rep, ub_blend_record *recs, float *out_scale)
{
  ub_bakefile *bf = rt->bf;
  uint32_t n = rt->elem_total;
  uint32_t stride = rep == 0 ? UB_SH1_FLOATS : 27;
  size_t entries = 0;
  for (uint32_t e = 0; e < n; e++) {
    const ub_bakefile_record *rc = element_record(bf, e);
    entries += rep == 0 ? rc->texel_count : 0;
  }
  if (rep == 0) {
    free(rt->lm_idx);
    rt->lm_idx = ub_big_alloc((entries ? entries : 1) * sizeof *rt->lm_idx);
    if (!rt->lm_idx)
      return UB_ERR_OUT_OF_MEMORY;
  }
  double mx = 0.0;
  size_t ei = 0;
  for (uint32_t e = 0; e < n; e++) {
    ub_bakefile_record *rc = element_record_rw(bf, e);
    uint32_t count = rep == 0 ? rc->texel_count : rep == 1 ? rc->probe_count : rc->llg_probe_count;
    uint16_t *v = *record_halves(rc, rep);
    const double fs = rc->sh_half_scale;
    uint32_t cursor = 0, kept = 0;
    uint16_t hmax = 0; /* the largest |value|'s bits: a finite half's magnitude orders as
                          its bits without the sign */
    if (rep == 0)
      recs[e].receivers = rt->lm_idx + ei;
    for (uint32_t i = 0; i < count; i++) {
      const uint16_t *row = v + (size_t)i * stride;
      if (rep == 0) {
        size_t px = 0;
        if (!pixel_locate(rt, rc->texel_index[i], &cursor, &px) ||
            bf->atlases[cursor].coverage[px] != 1)
          continue; /* an empty or padding pixel: never read (padding shows a texel) */
        rt->lm_idx[ei++] = (uint32_t)(rt->slot_first[cursor] + slot_of(rt, cursor, px));
        if (kept != i) /* compact in place */
          memmove(v + (size_t)kept * stride, row, stride * sizeof *v);
        row = v + (size_t)kept * stride;
      }
      kept++;
      for (uint32_t k = 0; k < stride; k++) {
        const uint16_t m = row[k] & 0x7fffu;
        hmax = m > hmax ? m : hmax;
      }
    }
    const double rmx = (double)ub_half_to_float(hmax) * fs;
    mx = rmx > mx ? rmx : mx;
    recs[e].count = kept;
  }
  /* The file's halves (texel rows in its I_z form already) become the blend's, in place:
   * rescaled from the file's scale to the pool's (both powers of two: exact but for half
   * subnormals and rounding when the pool's is larger), the arrays handed over to recs. */
  float s = half_pool_scale(mx);
  if (rep == 0)
    rt->lm_row_max = mx > rt->lm_row_max ? mx : rt->lm_row_max;
  for (uint32_t e = 0; e < n; e++) {
    ub_bakefile_record *rc = element_record_rw(bf, e);
    uint16_t **own = record_halves(rc, rep);
    uint16_t *v = *own;
    const float fs = rc->sh_half_scale;
    const size_t nv = (size_t)recs[e].count * stride;
    for (size_t i = 0; fs != s && i < nv; i++)
      v[i] = ub_half_from_float(ub_half_to_float(v[i]) * fs / s);
    *own = NULL;
    recs[e].values = v; /* the run-time's now (free_rec_values) */
  }
  *out_scale = s;
  return UB_OK;
}

/* Merged groups (unless UB_RUNTIME_SEPARATE_GROUPS): texels whose combination of texel
 * records is rare (held by at most MERGE_MAX_RECEIVERS texels: a group of that few in the
 * lightmap blend) join a more common combination that holds theirs and at most
 * MERGE_MAX_ADDED records more, fewest added first, then the most texels: each added
 * record gets a row of zeros for them. Their values stay the same (base + Σ ω·row gains
 * terms ω·0 = ±0, up to float rounding: which sum a group takes depends on its members'
 * weights), their texels sit in that combination's group, and the blend visits a few
 * thousand groups instead of tens of thousands of one or two texels, each of which cost
 * ~250-500 cycles besides its rows (tables, kernel call, one read per member stream; full
 * ESTATE: 32,700 of its 37,578 groups hold at most 4 texels). The price: the zero rows'
 * bytes, and an update that changes only an added record computes those texels too (and
 * leaves them: lm_touched).
 * Needs the records' receivers as global slots (records_prepare), before tch_bits;
 * *out_padded: the zero rows added; the merged slots in rt->pad_tmp (pad_count; NULL
 * when none), the combinations they join in rt->pad_off, pad_el (pad_targets). */
#define MERGE_MAX_RECEIVERS 4u
#define MERGE_MAX_ADDED 6u

typedef struct merge_combo {
  uint32_t rep;   /* a slot holding it: its records are lst[off[rep]..off[rep + 1]) */
  uint32_t count; /* slots holding it */
  uint32_t into;  /* the combination it joins, or UINT32_MAX */
  uint32_t id;    /* when some combination joins it: 1 + its number among those, else 0 */
} merge_combo;

/* A merged slot (then rank, pad_index), the combination it joins and its zero rows there
 * (rt->pad_tid, pad_mask). */
typedef struct merge_pad {
  uint64_t mask;
  uint32_t at, tid;
} merge_pad;

/* The most records a combination others join may hold (the bits of merge_pad.mask). */
#define MERGE_MAX_TARGET 64u

/* Whether the ascending list a[0..na) is inside the ascending list b[0..nb). */
static int list_within(const uint32_t *a, uint32_t na, const uint32_t *b, uint32_t nb)
{
  uint32_t j = 0;
  for (uint32_t i = 0; i < na; i++) {
    while (j < nb && b[j] < a[i])
      j++;
    if (j == nb || b[j] != a[i])
      return 0;
    j++;
  }
  return 1;
}

/* A combination's hash h with record e added (records in id order): merge_small_groups'
 * list hash and rank_touched's per-texel key. */
static inline uint64_t combo_step(uint64_t h, uint32_t e)
{
  h = (h ^ (e + UINT64_C(0x9e3779b97f4a7c15))) * UINT64_C(0xff51afd7ed558ccd);
  return h ^ (h >> 32);
}

static uint64_t list_hash(const uint32_t *l, uint32_t k)
{
  uint64_t h = UINT64_C(0x243f6a8885a308d3) ^ k;
  for (uint32_t i = 0; i < k; i++)
    h = combo_step(h, l[i]);
  return h;
}

/* The records slot s (of combination c) gains: those of the combination it joins that
 * are not in its own. Each such record e gets cur[e]++, and with rec, slot s at its
 * receivers[cur[e]] first; with mask, bit i for the joined combination's record i (it
 * holds at most MERGE_MAX_TARGET). Returns their count. */
static uint32_t merge_added(const uint32_t *lst, const uint32_t *off, const merge_combo *cb,
                            uint32_t c, uint32_t s, uint32_t *cur, ub_blend_record *rec,
                            uint64_t *mask)
{
  if (c == UINT32_MAX || cb[c].into == UINT32_MAX)
    return 0;
  const uint32_t q = cb[cb[c].into].rep, *l = lst + off[s], k = off[s + 1] - off[s];
  uint32_t n = 0;
  if (mask)
    *mask = 0;
  for (uint32_t i = off[q], j = 0; i < off[q + 1]; i++) {
    while (j < k && l[j] < lst[i])
      j++;
    if (j == k || l[j] != lst[i]) {
      const uint32_t e = lst[i];
      if (rec)
        ((uint32_t *)(uintptr_t)rec[e].receivers)[cur[e]] = s;
      if (mask)
        *mask |= UINT64_C(1) << (i - off[q]);
      cur[e]++;
      n++;
    }
  }
  return n;
}

static ub_result merge_small_groups(ub_runtime *rt, uint64_t *out_padded)
{
  const uint32_t n = rt->elem_total;
  const uint64_t slots = rt->slot_first[rt->bf->atlas_count];
  ub_blend_record *rec = rt->lm_rec;
  *out_padded = 0;
  uint64_t entries = 0;
  for (uint32_t e = 0; e < n; e++)
    entries += rec[e].count;
  if (!entries || slots >= UINT32_MAX / 2 || entries >= UINT32_MAX / 2)
    return UB_OK; /* nothing to merge, or beyond the 32-bit tables below: as without */
  size_t cap = 16;
  while (cap < 2 * (size_t)slots)
    cap *= 2;
  uint32_t *off = ub_big_calloc((size_t)slots + 1, sizeof *off);
  uint32_t *fill = ub_big_calloc((size_t)slots + 1, sizeof *fill);
  uint32_t *lst = ub_big_alloc((size_t)entries * sizeof *lst);
  uint32_t *tab = ub_big_alloc(cap * sizeof *tab);
  merge_combo *cb = ub_big_alloc((size_t)slots * sizeof *cb);
  uint32_t *eoff = ub_big_calloc((size_t)n + 1, sizeof *eoff);
  uint32_t *extra = ub_big_calloc((size_t)n + 1, sizeof *extra);
  uint32_t *ecb = NULL, *nidx = NULL;
  ub_result r = UB_ERR_OUT_OF_MEMORY;
  if (!off || !fill || !lst || !tab || !cb || !eoff || !extra)
    goto done;
  /* each slot's records, ascending (filled in id order) */
  for (uint32_t e = 0; e < n; e++)
    for (uint32_t i = 0; i < rec[e].count; i++)
      off[rec[e].receivers[i] + 1]++;
  for (uint64_t s = 0; s < slots; s++)
    off[s + 1] += off[s];
  for (uint32_t e = 0; e < n; e++)
    for (uint32_t i = 0; i < rec[e].count; i++) {
      const uint32_t s = rec[e].receivers[i];
      lst[off[s] + fill[s]++] = e;
    }
  /* the combinations (exact: equal lists), fill[s] becomes slot s's */
  memset(tab, 0xff, cap * sizeof *tab);
  uint32_t ncb = 0;
  for (uint32_t s = 0; s < slots; s++) {
    const uint32_t k = off[s + 1] - off[s];
    fill[s] = UINT32_MAX;
    if (!k)
      continue;
    for (size_t i = list_hash(lst + off[s], k) & (cap - 1);; i = (i + 1) & (cap - 1)) {
      const uint32_t c = tab[i];
      if (c == UINT32_MAX) {
        tab[i] = ncb;
        cb[ncb] = (merge_combo){s, 1, UINT32_MAX, 0};
        fill[s] = ncb++;
        break;
      }
      const uint32_t q = cb[c].rep;
      if (off[q + 1] - off[q] == k && !memcmp(lst + off[q], lst + off[s], k * sizeof *lst)) {
        cb[c].count++;
        fill[s] = c;
        break;
      }
    }
  }
  /* per record, the common combinations holding it */
  for (uint32_t c = 0; c < ncb; c++)
    if (cb[c].count > MERGE_MAX_RECEIVERS)
      for (uint32_t i = off[cb[c].rep]; i < off[cb[c].rep + 1]; i++)
        eoff[lst[i] + 1]++;
  for (uint32_t e = 0; e < n; e++)
    eoff[e + 1] += eoff[e];
  ecb = ub_big_alloc(((size_t)eoff[n] + 1) * sizeof *ecb);
  if (!ecb)
    goto done;
  for (uint32_t c = 0; c < ncb; c++)
    if (cb[c].count > MERGE_MAX_RECEIVERS)
      for (uint32_t i = off[cb[c].rep]; i < off[cb[c].rep + 1]; i++)
        ecb[eoff[lst[i]] + extra[lst[i]]++] = c;
  memset(extra, 0, ((size_t)n + 1) * sizeof *extra);
  /* each rare combination's target: among the common ones holding its least common record */
  for (uint32_t c = 0; c < ncb; c++) {
    if (cb[c].count > MERGE_MAX_RECEIVERS)
      continue;
    const uint32_t *l = lst + off[cb[c].rep], k = off[cb[c].rep + 1] - off[cb[c].rep];
    uint32_t e0 = l[0];
    for (uint32_t i = 1; i < k; i++)
      if (eoff[l[i] + 1] - eoff[l[i]] < eoff[e0 + 1] - eoff[e0])
        e0 = l[i];
    uint32_t best = UINT32_MAX, bd = MERGE_MAX_ADDED, bn = 0; /* d = bd: more texels than bn */
    for (uint32_t j = eoff[e0]; j < eoff[e0 + 1]; j++) {
      const uint32_t h = ecb[j], q = cb[h].rep, kh = off[q + 1] - off[q];
      if (kh <= k || kh - k > bd || (kh - k == bd && cb[h].count <= bn) ||
          kh > MERGE_MAX_TARGET)
        continue;
      if (list_within(l, k, lst + off[q], kh)) {
        best = h;
        bd = kh - k;
        bn = cb[h].count;
      }
    }
    cb[c].into = best;
  }
  /* the zero rows: per record, its added slots; the slots that gain some (merged) */
  uint64_t added = 0;
  uint32_t np = 0;
  for (uint32_t s = 0; s < slots; s++) {
    const uint32_t a = merge_added(lst, off, cb, fill[s], s, extra, NULL, NULL);
    added += a;
    np += a != 0;
  }
  r = UB_OK;
  if (!added)
    goto done;
  /* the combinations merged slots join, numbered in combination order, and their records */
  r = UB_ERR_OUT_OF_MEMORY;
  uint32_t nt = 0, nel = 0;
  for (uint32_t c = 0; c < ncb; c++)
    if (cb[c].into != UINT32_MAX)
      cb[cb[c].into].id = 1;
  for (uint32_t c = 0; c < ncb; c++)
    if (cb[c].id) {
      cb[c].id = ++nt;
      nel += off[cb[c].rep + 1] - off[cb[c].rep];
    }
  rt->pad_off = ub_big_alloc(((size_t)nt + 1) * sizeof *rt->pad_off);
  rt->pad_el = ub_big_alloc(((size_t)nel + 1) * sizeof *rt->pad_el);
  rt->pad_tmp = ub_big_alloc(((size_t)np + 1) * sizeof *rt->pad_tmp);
  nidx = ub_big_alloc((size_t)(entries + added) * sizeof *nidx);
  if (!rt->pad_off || !rt->pad_el || !rt->pad_tmp || !nidx)
    goto done;
  rt->pad_off[0] = 0;
  for (uint32_t c = 0; c < ncb; c++)
    if (cb[c].id) {
      const uint32_t q = cb[c].rep, k = off[q + 1] - off[q], t = cb[c].id - 1;
      memcpy(rt->pad_el + rt->pad_off[t], lst + off[q], (size_t)k * sizeof *lst);
      rt->pad_off[t + 1] = rt->pad_off[t] + k;
    }
  for (uint32_t e = 0; e < n; e++) { /* rows first: a failure leaves every count as it was */
    if (!extra[e])
      continue;
    const size_t nv = (size_t)(rec[e].count + extra[e]) * UB_SH1_FLOATS;
    uint16_t *v = realloc((void *)(uintptr_t)rec[e].values, nv * sizeof *v);
    if (!v)
      goto done;
    memset(v + (size_t)rec[e].count * UB_SH1_FLOATS, 0,
           (size_t)extra[e] * UB_SH1_FLOATS * sizeof *v); /* +0.0 halves */
    rec[e].values = v;
  }
  uint64_t at = 0;
  for (uint32_t e = 0; e < n; e++) {
    memcpy(nidx + at, rec[e].receivers, (size_t)rec[e].count * sizeof *nidx);
    rec[e].receivers = nidx + at;
    at += (uint64_t)rec[e].count + extra[e];
    extra[e] = rec[e].count; /* the write cursor */
  }
  /* the zero rows' receivers, and each merged slot's joined combination and zero rows */
  for (uint32_t s = 0, j = 0; s < slots; s++) {
    uint64_t mask;
    if (merge_added(lst, off, cb, fill[s], s, extra, rec, &mask))
      rt->pad_tmp[j++] = (merge_pad){mask, s, cb[cb[fill[s]].into].id - 1};
  }
  for (uint32_t e = 0; e < n; e++)
    rec[e].count = extra[e];
  free(rt->lm_idx);
  rt->lm_idx = nidx;
  nidx = NULL;
  *out_padded = added;
  rt->pad_count = np;
  rt->pad_targets = nt;
  r = UB_OK;
done:
  free(off);
  free(fill);
  free(lst);
  free(tab);
  free(cb);
  free(eoff);
  free(extra);
  free(ecb);
  free(nidx);
  return r;
}

/* Pairs of chg_runs for `jobs` jobs: job j's runs are the groups of its part of the
 * lightmap blend and one more (a group cut at the part's start). */
static size_t chg_pairs(const ub_runtime *rt, uint32_t jobs)
{
  return (size_t)rt->chg_groups + jobs;
}

static int merge_pad_cmp(const void *pa, const void *pb)
{
  const merge_pad *a = pa, *b = pb;
  return (a->at > b->at) - (a->at < b->at);
}

/* The merged texels (rt->pad_tmp, by slot) by rank: pad_bits, pad_rank, pad_tid,
 * pad_mask; and lm_chg. Needs the ranks (tch_grp). The combinations joined are numbered
 * again in rank order (their lists then lie in the order an update visits their groups:
 * a hall set's toggle reads them as one stretch, not ~3.5k scattered lists, which cost it
 * 0.7 ms on full ESTATE). */
static ub_result pad_index(ub_runtime *rt)
{
  const size_t words = (size_t)(rt->touched + 63) / 64, np = rt->pad_count;
  rt->pad_bits = ub_big_calloc(words ? words : 1, sizeof *rt->pad_bits);
  rt->pad_rank = ub_big_alloc((words ? words : 1) * sizeof *rt->pad_rank);
  rt->pad_tid = ub_big_alloc((np ? np : 1) * sizeof *rt->pad_tid);
  rt->pad_mask = ub_big_alloc((np ? np : 1) * sizeof *rt->pad_mask);
  rt->lm_chg = ub_big_calloc(rt->elem_total ? rt->elem_total : 1, 1);
  rt->pad_stay = ub_big_calloc(np ? np : 1, 1);
  if (!rt->pad_bits || !rt->pad_rank || !rt->pad_tid || !rt->pad_mask || !rt->lm_chg ||
      !rt->pad_stay)
    return UB_ERR_OUT_OF_MEMORY;
  for (size_t i = 0; i < np; i++) {
    uint64_t ix = 0;
    slot_touched(rt, rt->pad_tmp[i].at, &ix); /* (a merged slot has records) */
    rt->pad_tmp[i].at = (uint32_t)ix;
    rt->pad_bits[ix >> 6] |= UINT64_C(1) << (ix & 63);
  }
  qsort(rt->pad_tmp, np, sizeof *rt->pad_tmp, merge_pad_cmp);
  const uint32_t nt = rt->pad_targets;
  uint32_t *renum = ub_big_alloc(((size_t)nt + 1) * sizeof *renum);
  uint32_t *off = ub_big_alloc(((size_t)nt + 1) * sizeof *off);
  uint32_t *el = ub_big_alloc(((size_t)rt->pad_off[nt] + 1) * sizeof *el);
  if (!renum || !off || !el) {
    free(renum);
    free(off);
    free(el);
    return UB_ERR_OUT_OF_MEMORY;
  }
  memset(renum, 0xff, ((size_t)nt + 1) * sizeof *renum);
  uint32_t nn = 0;
  off[0] = 0;
  for (size_t i = 0; i < np; i++) {
    const uint32_t t = rt->pad_tmp[i].tid;
    if (renum[t] == UINT32_MAX) { /* first met: its list next */
      const uint32_t k = rt->pad_off[t + 1] - rt->pad_off[t];
      memcpy(el + off[nn], rt->pad_el + rt->pad_off[t], (size_t)k * sizeof *el);
      off[nn + 1] = off[nn] + k;
      renum[t] = nn++;
    }
    rt->pad_tid[i] = renum[t];
    rt->pad_mask[i] = rt->pad_tmp[i].mask;
  }
  assert(nn == nt); /* (every combination joined by some texel) */
  free(renum);
  free(rt->pad_off);
  free(rt->pad_el);
  rt->pad_off = off;
  rt->pad_el = el;
  uint32_t k = 0;
  for (size_t w = 0; w < words; w++) {
    rt->pad_rank[w] = k;
    k += (uint32_t)__builtin_popcountll(rt->pad_bits[w]);
  }
  free(rt->pad_tmp);
  rt->pad_tmp = NULL;
  return UB_OK;
}

/* A combination of texel records, as rank_touched orders them. */
typedef struct rank_key {
  uint64_t mask[2]; /* the combination's 128 highest-priority records, bit 63 - p of word 0
                     * for priority p < 64, of word 1 for p - 64 */
  uint64_t key;     /* hash of the combination's records */
  uint32_t count;   /* its touched slots */
  uint32_t id;      /* its number in rank_touched's table */
} rank_key;

static int rank_key_cmp(const void *pa, const void *pb)
{
  const rank_key *a = pa, *b = pb;
  for (int w = 0; w < 2; w++) /* descending: a combination holding the bigger record first */
    if (a->mask[w] != b->mask[w])
      return a->mask[w] > b->mask[w] ? -1 : 1;
  if (a->key != b->key)
    return a->key < b->key ? -1 : 1;
  return (a->id > b->id) - (a->id < b->id);
}

/* Records in mask order: by texel count, most first (ties: lower id). */
typedef struct rank_prio {
  uint32_t count, e;
} rank_prio;

static int rank_prio_cmp(const void *pa, const void *pb)
{
  const rank_prio *a = pa, *b = pb;
  if (a->count != b->count)
    return a->count > b->count ? -1 : 1;
  return (a->e > b->e) - (a->e < b->e);
}

/* A combination hash's first place in a table of cap (a power of two) entries. */
static inline size_t rank_slot(uint64_t h, size_t cap)
{
  return (size_t)(h ^ (h >> 29)) & (cap - 1);
}

/* tch_grp: the touched slots ordered by the combination of texel records holding them,
 * in slot order within a combination. Combinations are ordered as bit vectors over the
 * records sorted by texel count (most first; the 128 biggest, then a 64-bit hash of the
 * record ids: a collision only interleaves two groups, the blend still finds each), so
 * the groups holding a big set are neighbours in rank order: the blend keeps its group
 * tables, base rows, sums and records in that order, and the AHD texels and normals are
 * stored by rank, so toggling a hall set streams one stretch instead of ~22k groups
 * scattered over the level (a hash order did that). Needs tch_bits, tch_rank, touched and
 * the records' receivers as global slots. The slots' distinct combinations (a hash table
 * of their hashes) are sorted, then each slot takes its combination's next rank: the
 * order a sort of all slots by (combination, slot) gave, which took 0.25 s of full
 * ESTATE's load. */
static ub_result rank_touched(ub_runtime *rt)
{
  const uint64_t touched = rt->touched, nt = touched ? touched : 1;
  uint64_t *hash = ub_big_alloc((size_t)nt * sizeof *hash);
  uint32_t *cid = ub_big_alloc((size_t)nt * sizeof *cid);
  rank_prio *ord = ub_big_alloc((size_t)(rt->elem_total ? rt->elem_total : 1) * sizeof *ord);
  uint32_t *prio = ub_big_alloc((size_t)(rt->elem_total ? rt->elem_total : 1) * sizeof *prio);
  rt->tch_grp = ub_big_alloc((size_t)nt * sizeof *rt->tch_grp);
  size_t cap = (size_t)1 << 12; /* grows to keep it at most half full */
  uint32_t *table = malloc(cap * sizeof *table);
  rank_key *cb = NULL;
  uint32_t *start = NULL;
  ub_result r = UB_ERR_OUT_OF_MEMORY;
  if (!hash || !cid || !ord || !prio || !rt->tch_grp || !table)
    goto done;
  for (uint32_t e = 0; e < rt->elem_total; e++)
    ord[e] = (rank_prio){rt->lm_rec[e].count, e};
  qsort(ord, rt->elem_total, sizeof *ord, rank_prio_cmp);
  for (uint32_t p = 0; p < rt->elem_total; p++)
    prio[ord[p].e] = p;
  /* each slot's combination hash */
  for (uint64_t t = 0; t < touched; t++)
    hash[t] = UINT64_C(0x243f6a8885a308d3);
  for (uint32_t e = 0; e < rt->elem_total; e++)
    for (uint32_t i = 0; i < rt->lm_rec[e].count; i++) {
      uint64_t t = touched_before(rt, rt->lm_rec[e].receivers[i]);
      hash[t] = combo_step(hash[t], e);
    }
  /* the distinct combinations: a slot's records decide its hash (and its mask), the hash
   * its combination */
  memset(table, 0xff, cap * sizeof *table);
  uint32_t ncb = 0;
  for (uint64_t t = 0; t < touched; t++) {
    size_t h = rank_slot(hash[t], cap);
    while (table[h] != UINT32_MAX && hash[table[h]] != hash[t])
      h = (h + 1) & (cap - 1);
    if (table[h] != UINT32_MAX) {
      cid[t] = cid[table[h]];
      continue;
    }
    table[h] = (uint32_t)t; /* the combination's first slot stands for it */
    cid[t] = ncb++;
    if (2 * (size_t)ncb > cap) {
      uint32_t *grown = malloc(2 * cap * sizeof *grown);
      if (!grown)
        goto done;
      memset(grown, 0xff, 2 * cap * sizeof *grown);
      for (size_t j = 0; j < cap; j++)
        if (table[j] != UINT32_MAX) {
          size_t g = rank_slot(hash[table[j]], 2 * cap);
          while (grown[g] != UINT32_MAX)
            g = (g + 1) & (2 * cap - 1);
          grown[g] = table[j];
        }
      free(table);
      table = grown;
      cap *= 2;
    }
  }
  free(table);
  table = NULL;
  cb = calloc(ncb ? ncb : 1, sizeof *cb);
  start = malloc((ncb ? ncb : 1) * sizeof *start);
  if (!cb || !start)
    goto done;
  for (uint64_t t = 0; t < touched; t++) {
    cb[cid[t]].key = hash[t];
    cb[cid[t]].count++;
  }
  /* the masks (every slot of a combination sets the same bits) */
  for (uint32_t e = 0; e < rt->elem_total; e++) {
    const uint32_t p = prio[e];
    if (p >= 128)
      continue;
    for (uint32_t i = 0; i < rt->lm_rec[e].count; i++) {
      rank_key *c = &cb[cid[touched_before(rt, rt->lm_rec[e].receivers[i])]];
      c->mask[p >> 6] |= UINT64_C(1) << (63 - (p & 63));
    }
  }
  for (uint32_t c = 0; c < ncb; c++)
    cb[c].id = c;
  qsort(cb, ncb, sizeof *cb, rank_key_cmp);
  uint32_t at = 0;
  for (uint32_t i = 0; i < ncb; i++) {
    start[cb[i].id] = at;
    at += cb[i].count;
  }
  for (uint64_t t = 0; t < touched; t++)
    rt->tch_grp[t] = start[cid[t]]++;
  r = UB_OK;
done:
  free(hash);
  free(cid);
  free(ord);
  free(prio);
  free(table);
  free(cb);
  free(start);
  return r;
}

typedef struct recv_at {
  uint32_t recv, at;
} recv_at;

/* Sorts o[0..n) by recv (unique keys, so any sort gives this order): least significant
 * digit first, 11 bits a pass, as many passes as the largest key needs (ranks at full
 * ESTATE scale: 21 bits, two passes); tmp: n entries of scratch. The result may end in
 * tmp: returned. */
static recv_at *radix_recv(recv_at *o, recv_at *tmp, uint32_t n)
{
  uint32_t mx = 0;
  for (uint32_t i = 0; i < n; i++)
    mx = o[i].recv > mx ? o[i].recv : mx;
  for (unsigned shift = 0; shift < 32 && (shift == 0 || (mx >> shift)); shift += 11) {
    uint32_t cnt[2048] = {0};
    for (uint32_t i = 0; i < n; i++)
      cnt[(o[i].recv >> shift) & 2047u]++;
    uint32_t sum = 0;
    for (uint32_t d = 0; d < 2048; d++) {
      const uint32_t c = cnt[d];
      cnt[d] = sum;
      sum += c;
    }
    for (uint32_t i = 0; i < n; i++)
      tmp[cnt[(o[i].recv >> shift) & 2047u]++] = o[i];
    recv_at *t = o;
    o = tmp;
    tmp = t;
  }
  return o;
}

/* Sorts a record's receivers ascending, its rows (stride floats each) along. */
static ub_result sort_record(uint32_t *recv, uint16_t *rows, uint32_t count, uint32_t stride)
{
  uint32_t i = 1;
  while (i < count && recv[i - 1] < recv[i])
    i++;
  if (i >= count)
    return UB_OK;
  recv_at *o0 = ub_big_alloc((size_t)count * 2 * sizeof *o0);
  uint16_t *tmp = ub_big_alloc((size_t)count * stride * sizeof *tmp);
  if (!o0 || !tmp) {
    free(o0);
    free(tmp);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (i = 0; i < count; i++) {
    o0[i].recv = recv[i];
    o0[i].at = i;
  }
  const recv_at *o = radix_recv(o0, o0 + count, count);
  for (i = 0; i < count; i++) {
    recv[i] = o[i].recv;
    memcpy(tmp + (size_t)i * stride, rows + (size_t)o[i].at * stride, stride * sizeof *tmp);
  }
  memcpy(rows, tmp, (size_t)count * stride * sizeof *tmp);
  free(o0);
  free(tmp);
  return UB_OK;
}

static const float *texel_row(const ub_runtime *rt, uint32_t a, size_t i,
                              float srow[UB_SH1_FLOATS]);
static ub_result update_begin_ex(ub_runtime *rt, uint32_t max_jobs, int all, uint32_t *out_jobs);
static ub_result take_base_ahd(ub_runtime *rt);

/* rt->ahd in ahd_index order (ranked: the touched texels by rank first): the untouched
 * texels encoded from their rows (lm_static), the touched ones left zero for the set-up's
 * update of every group (it encodes them from the blend's rows). The scale: the smallest
 * power of two ≥ 1 that brings 64 × the largest row value (base or record) within the
 * half range: an AHD colour can exceed its row's values (C_d up to ~10× them for light
 * at d·n ≈ 0.25), and sets add up; 1 unless a row value exceeds 1023. */
static ub_result init_ahd(ub_runtime *rt, int ranked)
{
  const ub_bakefile *bf = rt->bf;
  uint64_t slots = rt->slot_first[bf->atlas_count];
  ub_ahd_packed *o = ub_big_calloc((size_t)(slots ? slots : 1), sizeof *o);
  if (!o)
    return UB_ERR_OUT_OF_MEMORY;
  const float s = ub_ahd_pack_scale(rt->lm_row_max);
  rt->ahd_scale = s;
  rt->ahd_inv_scale = 1.0f / s;
  rt->ahd_ranked = ranked;
  rt->ahd = o;
  for (uint32_t a = 0; a < bf->atlas_count; a++)
    for (uint64_t sa = 0; sa < rt->slot_first[a + 1] - rt->slot_first[a]; sa++) {
      const uint64_t sl = rt->slot_first[a] + sa;
      uint64_t ix;
      if (slot_touched(rt, sl, &ix))
        continue;
      float srow[UB_SH1_FLOATS];
      const uint32_t px = rt->slot_pixel[sl];
      encode_texel_packed(rt, a, texel_row(rt, a, px, srow), 1, px, &o[ahd_index(rt, a, sa)]);
    }
  return UB_OK;
}

/* rt->lm_base: every covered texel's SH in the I_z form (slot order), from the atlases'
 * float SH, which are freed (the AHD texels are encoded already; freeing each atlas's
 * first keeps the peak at two copies). 0 when out of memory. */
static int base_rows_packed(ub_runtime *rt)
{
  ub_bakefile *bf = rt->bf;
  uint64_t slots = rt->slot_first[bf->atlas_count];
  rt->lm_base = ub_big_alloc((size_t)(slots ? slots : 1) * UB_SH1_FLOATS * sizeof(float));
  if (!rt->lm_base)
    return 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    ub_bakefile_atlas *at = &bf->atlases[a];
    uint64_t ns = rt->slot_first[a + 1] - rt->slot_first[a];
    float *dst = rt->lm_base + rt->slot_first[a] * UB_SH1_FLOATS;
    const uint32_t *sp = rt->slot_pixel + rt->slot_first[a];
    for (uint64_t k = 0; k < ns; k++) {
      float un[3], *row = dst + k * UB_SH1_FLOATS;
      memcpy(row, at->sh + (size_t)sp[k] * UB_SH1_FLOATS, UB_SH1_FLOATS * sizeof(float));
      if (ub_texel_normal(&at->normal[3 * (size_t)sp[k]], un))
        ub_texel_sh_pack(row, un);
    }
    free(at->sh);
    at->sh = NULL;
  }
  return 1;
}

/* rt->lm_static: the untouched slots' rows of lm_base (tch_bits set) in half times a power
 * of two (the file's halves again: the bake file stores these rows in half, in this
 * form). 0 when out of memory. */
static int static_rows(ub_runtime *rt)
{
  uint64_t slots = rt->slot_first[rt->bf->atlas_count], touched = rt->touched;
  rt->lm_static = ub_big_alloc((size_t)(slots - touched ? slots - touched : 1) * UB_SH1_FLOATS *
                         sizeof(uint16_t));
  if (!rt->lm_static)
    return 0;
  double smx = 0.0, amx = 0.0; /* untouched rows', every row's */
  for (uint64_t sl = 0; sl < slots; sl++) {
    uint64_t ix;
    const int un = !slot_touched(rt, sl, &ix);
    for (int k = 0; k < UB_SH1_FLOATS; k++) {
      const double v = fabs((double)rt->lm_base[sl * UB_SH1_FLOATS + k]);
      amx = v > amx ? v : amx;
      smx = un && v > smx ? v : smx;
    }
  }
  rt->lm_static_scale = half_pool_scale(smx);
  rt->lm_row_max = amx > rt->lm_row_max ? amx : rt->lm_row_max;
  for (uint64_t sl = 0; sl < slots; sl++) {
    uint64_t ix;
    const float *row = rt->lm_base + sl * UB_SH1_FLOATS;
    if (!slot_touched(rt, sl, &ix))
      for (int k = 0; k < UB_SH1_FLOATS; k++)
        rt->lm_static[ix * UB_SH1_FLOATS + k] = ub_half_from_float(row[k] / rt->lm_static_scale);
  }
  return 1;
}

/* A file without dynamic elements: every covered texel's SH as the file's halves in the I_z
 * form (lm_static; no texel touched) instead of the reader's float SH of every atlas
 * pixel (kaos: 41.5 → 17.2 MiB); queries unpack a row exactly as the reader did, so they
 * answer the same. 0 when out of memory. */
static int setup_static(ub_runtime *rt)
{
  uint64_t slots = rt->slot_first[rt->bf->atlas_count];
  size_t words = (size_t)(slots + 63) / 64;
  rt->tch_bits = ub_big_calloc(words ? words : 1, sizeof *rt->tch_bits);
  rt->tch_rank = ub_big_calloc(words ? words : 1, sizeof *rt->tch_rank);
  rt->touched = 0;
  int ok = rt->tch_bits && rt->tch_rank && base_rows_packed(rt) && static_rows(rt);
  free(rt->lm_base);
  rt->lm_base = NULL;
  return ok;
}

/* The covered texels' stored normals as halves (rt->nrm, per slot), the bake file's floats
 * freed: the file stores them in half, so the floats convert back exactly and every
 * reader (stored_normal) gets the same values. 0 when out of memory (nothing freed). */
static int normals_to_half(ub_runtime *rt)
{
  ub_bakefile *bf = rt->bf;
  const uint64_t slots = rt->slot_first[bf->atlas_count];
  rt->nrm = ub_big_alloc((size_t)(slots ? slots : 1) * 3 * sizeof *rt->nrm);
  if (!rt->nrm)
    return 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++)
    for (uint64_t sl = rt->slot_first[a]; sl < rt->slot_first[a + 1]; sl++)
      for (int k = 0; k < 3; k++)
        rt->nrm[sl * 3 + k] =
            ub_half_from_float(bf->atlases[a].normal[(size_t)rt->slot_pixel[sl] * 3 + k]);
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    free(bf->atlases[a].normal);
    bf->atlases[a].normal = NULL;
  }
  return 1;
}

/* A GLG probe's current raw SH for the compact store (ub_glg_row_fn): read only, so
 * queries on several threads may ask at once. */
static int glg_row_source(void *user, uint32_t probe, float out[27])
{
  const ub_runtime *rt = user;
  return ub_blend_row(rt->glg_blend, probe, out);
}

/* Blend engines for the elements' lightmap, GLG and LLG records; sets start at weight 1,
 * doors closed, objects shown. Afterwards the run-time keeps a float copy of the LLG
 * probes' current state (llg_cur; the GLG's is its compact store, whose probes a query blends
 * through glg_row_source when an update marked them; the texels' is computed on demand by the lightmap blend, whose rows
 * the AHD re-encode streams), the
 * base rows of the touched receivers inside the blends (UB_BLEND_OWN_BASE) and the
 * records in half (8-bit rows with UB_RUNTIME_RECORDS_8BIT: UB_BLEND_STORE_Q8) and, unless
 * UB_RUNTIME_PLAIN_SUMS, the all-ones sums (UB_BLEND_ONES_SUM); the bake file's float
 * copies are freed or point into the current state (runtime.h, ub_runtime_bakefile). */
static ub_result setup_elements(ub_runtime *rt, const char *path, const ub_log *log)
{
  ub_bakefile *bf = rt->bf;
  uint32_t n = bf->dls_count + bf->elem_count;
  rt->elem_total = n;
  uint64_t slots = rt->slot_first[bf->atlas_count];
  rt->lm_rec = ub_big_calloc(n, sizeof *rt->lm_rec);
  rt->glg_rec = ub_big_calloc(n, sizeof *rt->glg_rec);
  rt->llg_rec = ub_big_calloc(n, sizeof *rt->llg_rec);
  rt->value = ub_big_calloc((size_t)n * 3, sizeof *rt->value);
  rt->applied = ub_big_calloc((size_t)n * 3, sizeof *rt->applied);
  rt->updated = ub_big_calloc(n ? n : 1, sizeof *rt->updated);
  rt->llg_first = ub_big_calloc((size_t)bf->llg_count + 1, sizeof *rt->llg_first);
  if (!rt->lm_rec || !rt->glg_rec || !rt->llg_rec || !rt->value || !rt->applied ||
      !rt->updated ||
      !rt->llg_first || !base_rows_packed(rt)) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory preparing dynamic elements", path);
    return UB_ERR_OUT_OF_MEMORY;
  }
  int any_llg = 0;
  for (uint32_t e = 0; e < n; e++) {
    const ub_bakefile_record *rc = element_record(bf, e);
    rt->lm_rec[e].receivers = NULL; /* slots, set by records_prepare */
    rt->lm_rec[e].count = 0;
    rt->glg_rec[e].receivers = rc->probe_index;
    rt->glg_rec[e].count = rc->probe_count;
    rt->llg_rec[e].receivers = rc->llg_probe_index;
    rt->llg_rec[e].count = rc->llg_probe_count;
    any_llg |= rc->llg_probe_count > 0;
  }
  ub_result r = records_prepare(rt, 0, rt->lm_rec, &rt->lm_scale);
  if (r == UB_OK)
    r = records_prepare(rt, 1, rt->glg_rec, &rt->glg_scale);
  if (r == UB_OK)
    r = records_prepare(rt, 2, rt->llg_rec, &rt->llg_scale);
  uint64_t padded = 0;
  if (r == UB_OK && !(rt->load_flags & UB_RUNTIME_SEPARATE_GROUPS)) {
    r = merge_small_groups(rt, &padded);
    if (r == UB_OK && padded)
      ub_log_printf(log, UB_LOG_INFO, "%s: %llu zero rows merge rare texel groups", path,
                    (unsigned long long)padded);
  }
  if (r != UB_OK) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory preparing dynamic elements", path);
    return r;
  }
  /* Touched slots (in some texel record): their base rows go to the lightmap blend, which
   * computes their current state; the others stay in half (lm_static). */
  size_t words = (size_t)(slots + 63) / 64;
  rt->tch_bits = ub_big_calloc(words ? words : 1, sizeof *rt->tch_bits);
  rt->tch_rank = ub_big_alloc((words ? words : 1) * sizeof *rt->tch_rank);
  if (!rt->tch_bits || !rt->tch_rank) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory preparing dynamic elements", path);
    return UB_ERR_OUT_OF_MEMORY;
  }
  for (uint32_t e = 0; e < n; e++)
    for (uint32_t i = 0; i < rt->lm_rec[e].count; i++) {
      uint32_t sl = rt->lm_rec[e].receivers[i];
      rt->tch_bits[sl >> 6] |= UINT64_C(1) << (sl & 63);
    }
  uint64_t touched = 0;
  for (size_t w = 0; w < words; w++) {
    rt->tch_rank[w] = (uint32_t)touched;
    touched += (uint64_t)__builtin_popcountll(rt->tch_bits[w]);
  }
  if (touched > UINT32_MAX) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: %llu touched texels is too many", path,
                  (unsigned long long)touched);
    return UB_ERR_INVALID_DATA;
  }
  rt->touched = touched;
  r = rank_touched(rt);
  if (r != UB_OK) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory preparing dynamic elements", path);
    return r;
  }
  rt->tch_slot = ub_big_alloc((size_t)(touched ? touched : 1) * sizeof *rt->tch_slot);
  rt->lm_tbase = ub_big_alloc((size_t)(touched ? touched : 1) * UB_SH1_FLOATS * sizeof(float));
  rt->lm_un = ub_big_alloc((size_t)(touched ? touched : 1) * 3 * sizeof(float));
  if (!rt->tch_slot || !rt->lm_tbase || !rt->lm_un || !static_rows(rt)) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory preparing dynamic elements", path);
    return UB_ERR_OUT_OF_MEMORY;
  }
  rt->lm_un_all = 1;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    for (uint64_t sl = rt->slot_first[a]; sl < rt->slot_first[a + 1]; sl++) {
      uint64_t ix;
      if (!slot_touched(rt, sl, &ix))
        continue;
      float *un = rt->lm_un + 3 * ix;
      if (!ub_texel_normal(&at->normal[(size_t)rt->slot_pixel[sl] * 3], un)) {
        un[0] = un[1] = un[2] = NAN;
        rt->lm_un_all = 0;
      }
    }
  }
  for (uint64_t sl = 0; sl < slots; sl++) {
    uint64_t ix;
    if (slot_touched(rt, sl, &ix)) {
      memcpy(rt->lm_tbase + ix * UB_SH1_FLOATS, rt->lm_base + sl * UB_SH1_FLOATS,
             UB_SH1_FLOATS * sizeof(float));
      rt->tch_slot[ix] = (uint32_t)sl;
    }
  }
  if (rt->pad_tmp && pad_index(rt) != UB_OK) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory preparing dynamic elements", path);
    return UB_ERR_OUT_OF_MEMORY;
  }
  /* every row is in lm_tbase or lm_static now: gone before the blend's copies are made */
  free(rt->lm_base);
  rt->lm_base = NULL;
  /* The blend's receivers are the touched ranks. Ranks are group-major, not monotonic
   * in the slots: each record is sorted again, its rows with it. */
  for (uint32_t e = 0; e < n; e++) {
    uint32_t *rv = rt->lm_idx + (rt->lm_rec[e].receivers - rt->lm_idx);
    for (uint32_t i = 0; i < rt->lm_rec[e].count; i++) {
      uint64_t ix;
      slot_touched(rt, rv[i], &ix);
      rv[i] = (uint32_t)ix;
    }
    r = sort_record(rv, (uint16_t *)(uintptr_t)rt->lm_rec[e].values, rt->lm_rec[e].count,
                    UB_SH1_FLOATS);
    if (r != UB_OK) {
      ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory preparing dynamic elements", path);
      return r;
    }
  }
  ub_blend_desc bd;
  memset(&bd, 0, sizeof bd);
  bd.name = "lightmap texels";
  bd.receiver_count = (uint32_t)touched;
  bd.stride = UB_SH1_FLOATS;
  bd.base = rt->lm_tbase;
  bd.storage = UB_BLEND_FLOAT16; /* the file's halves (records_prepare) */
  bd.element_count = n;
  bd.elements = rt->lm_rec;
  /* Keeps only the touched receivers' base rows (in half, as lm_static) and the records
   * as half; streams its rows to the re-encode, queries ask it for a texel's row
   * (ub_blend_row). */
  /* the records' form and (unless UB_RUNTIME_PLAIN_SUMS) the all-ones sums */
  const uint32_t rec_flags =
      ((rt->load_flags & UB_RUNTIME_RECORDS_8BIT) ? UB_BLEND_STORE_Q8 : 0) |
      ((rt->load_flags & UB_RUNTIME_PLAIN_SUMS) ? 0 : UB_BLEND_ONES_SUM);
  bd.flags = UB_BLEND_OWN_BASE | UB_BLEND_ROW_QUERY | UB_BLEND_BASE_HALF | rec_flags;
  bd.ones_weight = rt->lm_scale; /* a set on has blend weight 1 × its pool's scale */
  /* each element's halves go once copied (rec_values_done) */
  r = ub_blend_create_ex(&bd, log, NULL, rec_values_done, rt->lm_rec, &rt->lm_blend);
  if (r != UB_OK)
    return r;
  free_rec_values(rt->lm_rec, n);
  {
    ub_blend_info in;
    ub_blend_get_info(rt->lm_blend, &in);
    rt->chg_groups = in.group_count;
    rt->chg_runs = ub_big_alloc(chg_pairs(rt, rt->job_cap) * 2 * sizeof *rt->chg_runs);
    rt->chg_at = ub_big_calloc(rt->job_cap, sizeof *rt->chg_at);
    if (!rt->chg_runs || !rt->chg_at)
      return UB_ERR_OUT_OF_MEMORY;
  }
  /* Base rows in half too (UB_BLEND_BASE_HALF): the touched texels' as the untouched ones'
   * (lm_static); the probes' are the file's halves, kept exactly. */
  bd.flags = UB_BLEND_OWN_BASE | UB_BLEND_BASE_HALF | rec_flags;
  /* each texel an update hands over is encoded to AHD (lm_touched): about 12 of the
   * blend's cost units, 6 record rows (full ESTATE's per-group times: 14 cycles a texel
   * besides 2 a row read), counted when an update is split into jobs */
  ub_blend_set_receiver_cost(rt->lm_blend, 12);
  free(rt->lm_tbase);
  rt->lm_tbase = NULL;
  if (rt->has_glg) {
    bd.name = "GLG probes";
    bd.receiver_count = bf->glg_probe_count;
    bd.stride = 27;
    bd.base = bf->glg_sh;
    bd.elements = rt->glg_rec;
    /* Lazy: an update only marks the probes of the groups it would recompute
     * (glg_marked); the first query that reads one asks the blend for its row
     * (glg_row_source, ub_blend_row: the bits an eager update streams). */
    bd.flags |= UB_BLEND_ROW_QUERY;
    bd.ones_weight = rt->glg_scale;
    r = ub_blend_create_ex(&bd, log, NULL, rec_values_done, rt->glg_rec, &rt->glg_blend);
    bd.flags &= ~UB_BLEND_ROW_QUERY;
    if (r != UB_OK)
      return r;
    ub_glg_set_row_source(&rt->glg, glg_row_source, rt);
    free_rec_values(rt->glg_rec, n);
    free(bf->glg_sh);
    bf->glg_sh = NULL;
  }
  for (uint32_t m = 0; m < bf->llg_count; m++)
    rt->llg_first[m + 1] = rt->llg_first[m] + (uint64_t)bf->llgs[m].dims[0] *
                                                  bf->llgs[m].dims[1] * bf->llgs[m].dims[2];
  uint64_t lp = rt->llg_first[bf->llg_count];
  if (any_llg && lp) {
    rt->llg_base = ub_big_alloc((size_t)lp * 27 * sizeof(float));
    rt->llg_cur = ub_big_alloc((size_t)lp * 27 * sizeof(float));
    if (!rt->llg_base || !rt->llg_cur) {
      ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory preparing LLG records", path);
      return UB_ERR_OUT_OF_MEMORY;
    }
    for (uint32_t m = 0; m < bf->llg_count; m++)
      memcpy(rt->llg_base + rt->llg_first[m] * 27, bf->llgs[m].probe_sh,
             (size_t)(rt->llg_first[m + 1] - rt->llg_first[m]) * 27 * sizeof(float));
    bd.name = "LLG probes";
    bd.receiver_count = (uint32_t)lp;
    bd.stride = 27;
    bd.base = rt->llg_base;
    bd.elements = rt->llg_rec;
    bd.ones_weight = rt->llg_scale;
    r = ub_blend_create_ex(&bd, log, rt->llg_cur, rec_values_done, rt->llg_rec,
                           &rt->llg_blend);
    if (r != UB_OK)
      return r;
    rt->llg_chg = ub_big_calloc(bf->llg_count, sizeof *rt->llg_chg);
    if (!rt->llg_chg)
      return UB_ERR_OUT_OF_MEMORY;
    free_rec_values(rt->llg_rec, n);
    free(rt->llg_base);
    rt->llg_base = NULL;
    /* Each model's grid (what queries read) becomes its slice of the blend's output. */
    for (uint32_t m = 0; m < bf->llg_count; m++) {
      free(bf->llgs[m].probe_sh);
      bf->llgs[m].probe_sh = rt->llg_cur + rt->llg_first[m] * 27;
    }
  }
  /* The blends keep their own half copies of the records' values, in group order, and
   * the receiver indices they need: the records' index arrays go (records_prepare handed
   * their values over already). */
  free(rt->lm_idx);
  rt->lm_idx = NULL;
  for (uint32_t e = 0; e < n; e++) {
    ub_bakefile_record *rc = element_record_rw(bf, e);
    free(rc->texel_index);
    free(rc->probe_index);
    free(rc->llg_probe_index);
    rc->texel_index = NULL;
    rc->probe_index = NULL;
    rc->llg_probe_index = NULL;
    rt->lm_rec[e].receivers = rt->glg_rec[e].receivers = rt->llg_rec[e].receivers = NULL;
  }
  free_rec_values(rt->lm_rec, n);
  free_rec_values(rt->glg_rec, n);
  free_rec_values(rt->llg_rec, n);
  for (uint32_t e = 0; e < n && r == UB_OK; e++) {
    uint32_t kind = element_record(bf, e)->kind;
    float v = kind == UB_ELEMENT_DOOR ? 0.0f : 1.0f;
    float rgb[3] = {v, v, v};
    memcpy(rt->value + 3 * (size_t)e, rgb, sizeof rgb);
    rt->updated[e] = v;
  }
  for (uint32_t e = 0; e < n && r == UB_OK; e++)
    r = push_applied(rt, e);
  if (r != UB_OK) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: cannot apply the elements' default values", path);
    return r;
  }
  r = init_ahd(rt, 1);
  if (r != UB_OK) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory preparing dynamic elements", path);
    return r;
  }
  if (!(rt->load_flags & UB_RUNTIME_NO_BASE_AHD) && rt->lm_blend && rt->touched) {
    r = take_base_ahd(rt);
    if (r != UB_OK) {
      ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory keeping the base state", path);
      return r;
    }
  }
  /* every group, dirty or not (a group of closed doors only has weights 0): every touched
   * texel's AHD encoded from the blend's row */
  uint32_t jobs;
  r = update_begin_ex(rt, 1, 1, &jobs);
  if (r != UB_OK)
    return r;
  ub_runtime_update_job(rt, 0);
  ub_runtime_update_end(rt, NULL);
  if (rt->load_flags & UB_RUNTIME_KEEP_STATE) {
    r = ub_runtime_keep_state(rt);
    if (r != UB_OK)
      ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory keeping the load state", path);
  }
  return r;
}

/* rt->ahd_base: an update of every group with the lightmap blend's weights all 0 (the
 * other blends' as they are: the load's update after this one rewrites everything), its
 * texels' AHD kept, the weights put back; from then on the blend reports such groups
 * (ub_blend_set_base_report). The same code encodes them as any update would: the bits a
 * re-encode of the base rows gives. */
static ub_result take_base_ahd(ub_runtime *rt)
{
  ub_blend_info in;
  ub_blend_get_info(rt->lm_blend, &in);
  const uint32_t E = in.element_count;
  float *w = ub_big_alloc(((size_t)E * 3 + 1) * sizeof *w);
  rt->ahd_base = ub_big_alloc((size_t)rt->touched * sizeof *rt->ahd_base);
  if (!w || !rt->ahd_base) {
    free(w);
    free(rt->ahd_base);
    rt->ahd_base = NULL;
    return UB_ERR_OUT_OF_MEMORY;
  }
  static const float zero[3] = {0.0f, 0.0f, 0.0f};
  ub_result r = UB_OK;
  for (uint32_t e = 0; e < E && r == UB_OK; e++) {
    ub_blend_weight(rt->lm_blend, e, w + 3 * (size_t)e);
    r = ub_blend_set_weight(rt->lm_blend, e, zero);
  }
  uint32_t jobs = 0;
  if (r == UB_OK)
    r = update_begin_ex(rt, 1, 1, &jobs);
  if (r == UB_OK) {
    ub_runtime_update_job(rt, 0);
    ub_runtime_update_end(rt, NULL);
    memcpy(rt->ahd_base, rt->ahd, (size_t)rt->touched * sizeof *rt->ahd_base);
  }
  for (uint32_t e = 0; e < E; e++) /* the same finite weights back: cannot fail */
    ub_blend_set_weight(rt->lm_blend, e, w + 3 * (size_t)e);
  free(w);
  if (r != UB_OK) {
    free(rt->ahd_base);
    rt->ahd_base = NULL;
    return r;
  }
  ub_blend_set_base_report(rt->lm_blend, 1);
  return UB_OK;
}

ub_result ub_runtime_keep_state(ub_runtime *rt)
{
  assert(rt);
  if (rt->job_count || (rt->lm_blend && ub_blend_pending(rt->lm_blend)) ||
      (rt->llg_blend && ub_blend_pending(rt->llg_blend)))
    return UB_ERR_INVALID_ARGUMENT; /* a change waits for its update */
  /* LLG probes: the blend keeps their rows (llg_cur, what it writes) */
  if (rt->llg_blend) {
    ub_result r = ub_blend_set_reference_rows(rt->llg_blend, rt->llg_cur);
    if (r != UB_OK)
      return r;
  }
  if (!rt->lm_blend || !rt->touched)
    return UB_OK; /* no texel an update re-encodes */
  ub_ahd_packed *kept = rt->ahd_kept;
  if (!kept) {
    kept = ub_big_alloc((size_t)rt->touched * sizeof *kept);
    if (!kept)
      return UB_ERR_OUT_OF_MEMORY; /* (the LLG probes' state is kept) */
  }
  ub_result r = ub_blend_set_reference(rt->lm_blend); /* cannot refuse: nothing pending */
  if (r != UB_OK) {
    if (kept != rt->ahd_kept)
      free(kept);
    return r;
  }
  rt->ahd_kept = kept;
  memcpy(rt->ahd_kept, rt->ahd, (size_t)rt->touched * sizeof *rt->ahd_kept);
  return UB_OK;
}

ub_result ub_runtime_load(const char *path, const ub_log *log, ub_runtime **out)
{
  return ub_runtime_load_ex(path, log, 0, out);
}

ub_result ub_runtime_load_ex(const char *path, const ub_log *log, unsigned flags,
                             ub_runtime **out)
{
  assert(path && out);
  if (flags & ~(unsigned)(UB_RUNTIME_RECORDS_8BIT | UB_RUNTIME_PLAIN_SUMS |
                          UB_RUNTIME_KEEP_STATE | UB_RUNTIME_GLG_SMALL_WALK |
                          UB_RUNTIME_NO_BASE_AHD | UB_RUNTIME_MERGE_GROUPS |
                          UB_RUNTIME_SEPARATE_GROUPS)) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: unknown load flags 0x%x", path, flags);
    return UB_ERR_INVALID_ARGUMENT;
  }
  ub_bakefile *bf = NULL;
  /* records as the file's halves: the blends keep halves, no float copy on the way */
  ub_result r = ub_bakefile_read_ex(path, log, UB_BAKEFILE_RECORD_HALVES, &bf);
  if (r != UB_OK)
    return r;
  ub_runtime *rt = ub_big_calloc(1, sizeof *rt);
  if (!rt) {
    ub_bakefile_free(bf);
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory", path);
    return UB_ERR_OUT_OF_MEMORY;
  }
  rt->bf = bf;
  rt->load_flags = flags;
  rt->pixel_first = ub_big_calloc((size_t)bf->atlas_count + 1, sizeof *rt->pixel_first);
  rt->jobs = ub_big_calloc(1, sizeof *rt->jobs); /* a plain update's: it cannot run out of memory */
  if (!rt->pixel_first || !rt->jobs)
    goto oom;
  rt->job_cap = 1;
  for (uint32_t a = 0; a < bf->atlas_count; a++)
    rt->pixel_first[a + 1] =
        rt->pixel_first[a] + (uint64_t)bf->atlases[a].width * bf->atlases[a].height;
  if (build_slots(rt) != UB_OK)
    goto oom;
  if (bf->atlas_count) {
    rt->fallback = ub_big_calloc(bf->atlas_count, sizeof *rt->fallback);
    if (!rt->fallback)
      goto oom;
    for (uint32_t a = 0; a < bf->atlas_count; a++)
      if (encode_fallbacks(&bf->atlases[a], &rt->fallback[a]) != UB_OK)
        goto oom;
  }
  for (uint32_t t = 0; t < bf->triangle_count; t++)
    rt->lit_count += bf->tri_atlas[t] >= 0;
  if (rt->lit_count) {
    rt->lit_tris = ub_big_alloc((size_t)rt->lit_count * sizeof *rt->lit_tris);
    if (!rt->lit_tris)
      goto oom;
    uint32_t k = 0;
    for (uint32_t t = 0; t < bf->triangle_count; t++)
      if (bf->tri_atlas[t] >= 0)
        rt->lit_tris[k++] = t;
  }
  if (bf->glg_probe_count) {
    ub_glg_desc gd;
    memset(&gd, 0, sizeof gd);
    gd.probe_count = bf->glg_probe_count;
    gd.positions = bf->glg_positions;
    gd.sh = bf->glg_sh;
    gd.tet_count = bf->glg_tet_count;
    gd.tets = bf->glg_tets;
    gd.neigh = bf->glg_neigh;
    gd.leak_plane_count = bf->glg_plane_count;
    gd.leak_planes = bf->glg_planes;
    gd.leak_plane_of = bf->glg_plane_of;
    /* The GLG's compact store (ubake/glg.h): raw SH in half with a per-probe exponent and
     * window, 58 B per probe. Every probe starts stale: the first query that reads one
     * finds its window, so loading windows nothing and probes nobody looks at never are
     * (windowing all of kaos's 35,822 probes took ~0.1 s at load). */
    gd.compact = 1;
    gd.small_walk = (rt->load_flags & UB_RUNTIME_GLG_SMALL_WALK) != 0;
    /* the GLG's messages name the file; what it finds wrong with the file's tetrahedra is
     * invalid data (its INVALID_ARGUMENT is a caller's desc), and it says so */
    named_log nl = {log, path, 0};
    const ub_log glog = {named_log_fn, &nl};
    r = ub_glg_init(&rt->glg, &gd, &glog);
    rt->has_glg = r == UB_OK;
    if (r != UB_OK) {
      if (r == UB_ERR_INVALID_ARGUMENT)
        r = UB_ERR_INVALID_DATA;
      if (!nl.errors)
        ub_log_printf(log, UB_LOG_ERROR, "%s: section GLGP: %s", path,
                      r == UB_ERR_OUT_OF_MEMORY ? "out of memory for the probe grid"
                                                : "the probe grid cannot be used "
                                                  "(its probes span no volume)");
      ub_runtime_free(rt);
      return r;
    }
    /* The walk records (or the small walk's links) hold the neighbours (16 B per tet), the
     * GLG the positions it needs (hull faces, badly shaped tets; every probe's with the
     * small walk) and its own SH: the file's copies go. The elements'
     * blend reads the base SH first (setup_elements frees it then). */
    free(bf->glg_neigh);
    bf->glg_neigh = NULL;
    free(bf->glg_positions);
    bf->glg_positions = NULL;
    if (!bf->dls_count && !bf->elem_count) {
      free(bf->glg_sh);
      bf->glg_sh = NULL;
    }
  }
  if (bf->dls_count || bf->elem_count) {
    named_log cl = {log, NULL, 0}; /* its messages name the file; some failures had none */
    const ub_log clog = {named_log_fn, &cl};
    r = setup_elements(rt, path, &clog);
    if (r != UB_OK) {
      if (!cl.errors)
        ub_log_printf(log, UB_LOG_ERROR, "%s: %s preparing dynamic elements", path,
                      ub_result_string(r));
      ub_runtime_free(rt);
      return r;
    }
  } else if (bf->atlas_count && (!setup_static(rt) || init_ahd(rt, 0) != UB_OK)) {
    goto oom;
  }
  if (bf->atlas_count && !normals_to_half(rt))
    goto oom;
  llg_chg_clear(rt);
  rt->chg_texels = 0; /* the set-up's update: the whole atlas is new */
  rt->chg_jobs = 0;
  rt->chg_all = 0;
  *out = rt;
  return UB_OK;
oom:
  ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory preparing the lightmaps", path);
  ub_runtime_free(rt);
  return UB_ERR_OUT_OF_MEMORY;
}

uint32_t ub_runtime_dls_count(const ub_runtime *rt)
{
  assert(rt);
  return rt->bf->dls_count;
}

int32_t ub_runtime_dls_find(const ub_runtime *rt, const char *name)
{
  assert(rt && name);
  for (uint32_t d = 0; d < rt->bf->dls_count; d++)
    if (strcmp(rt->bf->dls[d].name, name) == 0)
      return (int32_t)d;
  return -1;
}

const char *ub_runtime_dls_name(const ub_runtime *rt, uint32_t set)
{
  assert(rt);
  return set < rt->bf->dls_count ? rt->bf->dls[set].name : NULL;
}

ub_result ub_runtime_set_dls(ub_runtime *rt, uint32_t set, const float rgb[3])
{
  assert(rt && rgb);
  if (set >= rt->bf->dls_count || rt->job_count) /* (job_count: an update begun) */
    return UB_ERR_INVALID_ARGUMENT;
  for (int c = 0; c < 3; c++) /* (NaN fails the comparison) */
    if (!(fabsf(rgb[c]) <= UB_RUNTIME_MAX_WEIGHT))
      return UB_ERR_INVALID_ARGUMENT;
  return set_value(rt, set, rgb);
}

uint32_t ub_runtime_element_count(const ub_runtime *rt)
{
  assert(rt);
  return rt->bf->elem_count;
}

int32_t ub_runtime_element_find(const ub_runtime *rt, ub_element_kind kind, const char *name)
{
  assert(rt && name);
  for (uint32_t e = 0; e < rt->bf->elem_count; e++)
    if (rt->bf->elems[e].kind == (uint32_t)kind && strcmp(rt->bf->elems[e].name, name) == 0)
      return (int32_t)e;
  return -1;
}

const char *ub_runtime_element_name(const ub_runtime *rt, uint32_t element)
{
  assert(rt);
  return element < rt->bf->elem_count ? rt->bf->elems[element].name : NULL;
}

ub_element_kind ub_runtime_element_kind(const ub_runtime *rt, uint32_t element)
{
  assert(rt);
  return element < rt->bf->elem_count ? (ub_element_kind)rt->bf->elems[element].kind
                                      : UB_ELEMENT_DLS;
}

ub_result ub_runtime_set_element(ub_runtime *rt, uint32_t element, float value)
{
  assert(rt);
  if (element >= rt->bf->elem_count || rt->bf->elems[element].kind == UB_ELEMENT_COMBO ||
      !isfinite(value) || value < 0.0f || value > 1.0f || rt->job_count)
    return UB_ERR_INVALID_ARGUMENT;
  const float rgb[3] = {value, value, value};
  return set_value(rt, rt->bf->dls_count + element, rgb);
}

ub_result ub_runtime_element_value(const ub_runtime *rt, uint32_t element, float *out_value)
{
  assert(rt && out_value);
  if (element >= rt->bf->elem_count || rt->bf->elems[element].kind == UB_ELEMENT_COMBO ||
      !rt->value)
    return UB_ERR_INVALID_ARGUMENT;
  *out_value = rt->value[3 * ((size_t)rt->bf->dls_count + element)];
  return UB_OK;
}

int ub_runtime_triangle_shown(const ub_runtime *rt, uint32_t t)
{
  assert(rt);
  const ub_bakefile *bf = rt->bf;
  if (!bf->tri_role || t >= bf->triangle_count || !bf->tri_role[t])
    return 1;
  uint32_t role = bf->tri_role[t] >> 24, el = bf->tri_role[t] & 0xFFFFFFu;
  if (el >= bf->elem_count || bf->elems[el].kind == UB_ELEMENT_COMBO || !rt->updated)
    return role != UB_TRI_ROLE_DOOR_OPEN; /* as baked */
  const float v = rt->updated[bf->dls_count + el]; /* as of the last update */
  if (role == UB_TRI_ROLE_DOOR_CLOSED)
    return v < 0.5f;
  return v >= 0.5f;
}

float ub_runtime_door_fraction(float a)
{
  if (!isfinite(a))
    return 0.0f;
  a = fabsf(a);
  if (a >= (float)M_PI_2)
    return 1.0f;
  return 1.0f - cosf(a);
}

float ub_runtime_dls_weight_from_lights(const float *strengths, uint32_t count)
{
  if (!strengths || count == 0)
    return 0.0f;
  double s = 0.0;
  for (uint32_t i = 0; i < count; i++)
    s += isfinite(strengths[i]) ? strengths[i] : 0.0;
  return (float)(s / count);
}

typedef struct touched_ctx {
  ub_runtime *rt;
  uint64_t texels;
  uint64_t kept;   /* of texels: copied back from the kept state */
  uint64_t based;  /* of texels: the base's copied (UB_BLEND_AT_BASE) */
  uint64_t left;   /* merged texels left as they were (lm_touched) */
  /* texels with their own normal waiting to be encoded sixteen at a time (the blend hands
   * over pieces of one group's run, which end in fewer than sixteen; their rows live only
   * during the call: copied, so the sixteen are contiguous for the AVX-512 encode) */
  uint32_t np;
  ub_ahd_packed *pout[16];
  float pn[48];
  float qrow[16][UB_SH1_FLOATS];
  /* the job's runs of re-encoded ranks (rt->chg_runs) */
  uint32_t *runs, nruns, cap;
  int full;
  ub_ahd_packed sink; /* where a waiting texel lm_touched leaves is encoded to */
  uint32_t pad_t;   /* pad_left's combination (UINT32_MAX: none yet) */
  uint64_t pad_chg; /* its changed records */
} touched_ctx;

/* Encodes the waiting texels (padded to sixteen with copies of the first). */
static void touched_flush(touched_ctx *tc)
{
  if (!tc->np)
    return;
  ub_ahd_packed got[16];
  for (uint32_t j = tc->np; j < 16; j++) {
    memcpy(tc->qrow[j], tc->qrow[0], sizeof tc->qrow[0]);
    memcpy(tc->pn + 3 * j, tc->pn, 3 * sizeof(float));
  }
  ub_ahd_encode_iz_packed_n(tc->qrow[0], tc->pn, tc->rt->ahd_inv_scale, got, 16);
  for (uint32_t j = 0; j < tc->np; j++)
    *tc->pout[j] = got[j];
  tc->np = 0;
}

/* Ranks [first, first + count) changed (the job's runs: one per group, consecutive pieces
 * joined). */
static void lm_run(touched_ctx *tc, uint32_t first, uint32_t count)
{
  if (!count)
    return;
  uint32_t *last = tc->nruns ? tc->runs + 2 * (tc->nruns - 1) : NULL;
  if (last && last[0] + last[1] == first)
    last[1] += count;
  else if (tc->nruns < tc->cap) {
    tc->runs[2 * tc->nruns] = first;
    tc->runs[2 * tc->nruns + 1] = count;
    tc->nruns++;
  } else
    tc->full = 1;
}

/* Re-encodes to AHD the touched texels of ranks [first, first + count), whose current SH
 * rows (I_z form) the blend streams (valid during the call only).
 * Their normals (lm_un) and AHD (rt->ahd, ahd_ranked) are at the same ranks: three
 * sequential streams. Only a texel without a normal of its own needs its slot. */
static void lm_encode(touched_ctx *tc, uint32_t first, uint32_t count, const float *rows)
{
  const ub_runtime *rt = tc->rt;
  const float *un = rt->lm_un + (size_t)first * 3;
  ub_ahd_packed *out = rt->ahd + first;
  if (rows == UB_BLEND_AT_REFERENCE) { /* the kept state's texels: their bits back */
    memcpy(out, rt->ahd_kept + first, (size_t)count * sizeof *out);
    tc->texels += count;
    tc->kept += count;
    return;
  }
  if (rows == UB_BLEND_AT_BASE) { /* every element at 0: the base's bits */
    memcpy(out, rt->ahd_base + first, (size_t)count * sizeof *out);
    tc->texels += count;
    tc->based += count;
    return;
  }
  /* The next piece's normals (a chunk, 32 texels, 6 lines) asked for now, while this
   * piece is encoded: the all-sets update on the full ESTATE 2.5-3% faster (one process
   * alternating per update, 2026-12-04; the AHD lines written next asked as well: no
   * gain) */
  for (size_t o = 0; o < 32 * 3 * sizeof(float); o += 64)
    __builtin_prefetch((const char *)(un + 3 * (size_t)count) + o, 0, 3);
  const float inv_scale = rt->ahd_inv_scale;
  for (uint32_t i = 0; i < count; i++, rows += UB_SH1_FLOATS, un += 3, out++) {
    if (!tc->np) { /* a run of texels with their own normals: encoded where they are,
                    * sixteen at a time (AVX-512: 16 lanes; AVX: two groups of eight) */
      uint32_t r = count - i;
      if (!rt->lm_un_all)
        for (r = 0; r < count - i && !isnan(un[3 * r]); r++) {
        }
      const uint32_t m = r & ~15u;
      if (m) {
        ub_ahd_encode_iz_packed_n(rows, un, inv_scale, out, m);
        i += m - 1;
        rows += (size_t)(m - 1) * UB_SH1_FLOATS;
        un += (size_t)(m - 1) * 3;
        out += m - 1;
        continue;
      }
    }
    if (isnan(un[0])) {
      uint64_t s = rt->tch_slot[first + i];
      encode_texel_packed(rt, slot_atlas(rt, s), rows, 1, rt->slot_pixel[s], out);
      continue;
    }
    memcpy(tc->pn + 3 * tc->np, un, 3 * sizeof(float));
    memcpy(tc->qrow[tc->np], rows, UB_SH1_FLOATS * sizeof(float));
    tc->pout[tc->np] = out;
    if (++tc->np == 16)
      touched_flush(tc);
  }
  tc->texels += count;
}

/* The index in pad_tid of the first merged texel at or after rank r. */
static inline uint32_t pad_index_at(const ub_runtime *rt, uint64_t r)
{
  const uint64_t w = r >> 6;
  return rt->pad_rank[w] +
         (uint32_t)__builtin_popcountll(rt->pad_bits[w] & ((UINT64_C(1) << (r & 63)) - 1));
}

/* The rank of the first merged texel in [r, end), or end. */
static inline uint64_t pad_next(const ub_runtime *rt, uint64_t r, uint64_t end)
{
  while (r < end) {
    const uint64_t w = rt->pad_bits[r >> 6] >> (r & 63);
    if (w) {
      r += (uint64_t)__builtin_ctzll(w);
      return r < end ? r : end;
    }
    r = (r | 63) + 1;
  }
  return end;
}

/* Whether merged texel k (its index in pad_tid) keeps its value in the update begun: its
 * changed elements are all ones it has zero rows in. tc caches the changed records of the
 * last combination asked (the texels of a group share it). */
static int pad_left(touched_ctx *tc, uint32_t k)
{
  const ub_runtime *rt = tc->rt;
  const uint32_t t = rt->pad_tid[k];
  if (t != tc->pad_t) {
    uint64_t m = 0;
    for (uint32_t i = rt->pad_off[t]; i < rt->pad_off[t + 1]; i++)
      m |= (uint64_t)rt->lm_chg[rt->pad_el[i]] << (i - rt->pad_off[t]);
    tc->pad_t = t;
    tc->pad_chg = m;
  }
  return !(tc->pad_chg & ~rt->pad_mask[k]);
}

/* lm_encode of ranks [first, end) (rows from rank `first`, or a sentinel) but for the
 * ns ranks sk (ascending), whose AHD sv[] had before: put back, or, still waiting in
 * tc's sixteen, sent to tc->sink. */
static void lm_encode_but(touched_ctx *tc, uint64_t first, uint64_t end, const float *rows,
                          const uint64_t *sk, const ub_ahd_packed *sv, uint32_t ns)
{
  ub_runtime *rt = tc->rt;
  lm_encode(tc, (uint32_t)first, (uint32_t)(end - first), rows);
  for (uint32_t j = 0; j < ns; j++) {
    ub_ahd_packed *o = rt->ahd + sk[j];
    int waiting = 0;
    for (uint32_t q = 0; q < tc->np; q++)
      if (tc->pout[q] == o) {
        tc->pout[q] = &tc->sink;
        waiting = 1;
      }
    if (!waiting)
      *o = sv[j];
  }
  tc->texels -= ns;
  tc->left += ns;
  if (rows == UB_BLEND_AT_REFERENCE)
    tc->kept -= ns;
  else if (rows == UB_BLEND_AT_BASE)
    tc->based -= ns;
}

/* The blend's touched callback: lm_encode, except for merged texels the update leaves
 * (pad_skip, pad_left): the texels an update re-encodes and lists are those whose own
 * elements changed, as with UB_RUNTIME_SEPARATE_GROUPS. Those are encoded with the rest
 * (the sixteen-wide encode stays whole: cutting the pieces at them cost a third of a hall
 * set's toggle on full ESTATE) and their AHD put back. */
static void lm_touched(void *user, uint32_t first, uint32_t count, const float *rows)
{
  touched_ctx *tc = user;
  const ub_runtime *rt = tc->rt;
  if (!rt->pad_skip || !count) {
    lm_run(tc, first, count);
    lm_encode(tc, first, count, rows);
    return;
  }
  lm_run(tc, first, count); /* (ub_runtime_changed_texels leaves out the pad_stay ones) */
  const int sentinel = rows == UB_BLEND_AT_REFERENCE || rows == UB_BLEND_AT_BASE;
  const uint64_t end = (uint64_t)first + count;
  uint64_t i = first, r = first, sk[64];
  ub_ahd_packed sv[64];
  uint32_t ns = 0;
  uint32_t k = pad_index_at(rt, first);
  for (r = pad_next(rt, r, end); r < end; r = pad_next(rt, r + 1, end), k++) {
    const int stay = pad_left(tc, k);
    tc->rt->pad_stay[k] = (uint8_t)stay; /* (each job its own texels: no two write one) */
    if (stay) {
      if (ns == 64) { /* (a long piece: in parts) */
        lm_encode_but(tc, i, r, sentinel ? rows : rows + (i - first) * UB_SH1_FLOATS, sk, sv,
                      ns);
        i = r;
        ns = 0;
      }
      sk[ns] = r;
      sv[ns++] = rt->ahd[r];
    }
  }
  lm_encode_but(tc, i, end, sentinel ? rows : rows + (i - first) * UB_SH1_FLOATS, sk, sv, ns);
}

/* The probes an update would recompute are only marked in the GLG's compact store: the
 * first query that reads one blends it (glg_row_source) and windows it (ubake/glg.h).
 * Windowing at update time was three quarters of a room set's toggle on the ESTATE-scale
 * level (1.96 -> 0.51 ms without it); blending them was a quarter of what was left. */
static void glg_marked(void *user, uint32_t first, uint32_t count, const float *rows)
{
  (void)rows;
  ub_runtime *rt = user;
  ub_glg_mark_unblended(&rt->glg, first, count);
}

/* glg_marked for a list group's probes (most GLG groups: a set's probes are scattered). */
static void glg_listed(void *user, const uint32_t *probes, uint32_t count)
{
  ub_runtime *rt = user;
  ub_glg_mark_unblended_list(&rt->glg, probes, count);
}

/* The LLG probes [first, first + count) the blend just wrote: their models changed. */
static void llg_touched(void *user, uint32_t first, uint32_t count, const float *rows)
{
  (void)rows;
  const ub_runtime *rt = user;
  uint32_t lo = 0, hi = rt->bf->llg_count; /* the model holding `first` */
  while (hi - lo > 1) {
    const uint32_t mid = (lo + hi) / 2;
    if (rt->llg_first[mid] <= first)
      lo = mid;
    else
      hi = mid;
  }
  for (uint32_t m = lo; m < rt->bf->llg_count && rt->llg_first[m] < (uint64_t)first + count; m++)
    if (rt->llg_first[m + 1] > rt->llg_first[m]) /* (a model without probes never changes) */
      atomic_store_explicit(&rt->llg_chg[m], 1, memory_order_relaxed);
}

static double rt_now(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

ub_result ub_runtime_update_begin(ub_runtime *rt, uint32_t max_jobs, uint32_t *out_jobs)
{
  return update_begin_ex(rt, max_jobs, 0, out_jobs);
}

/* ub_runtime_update_begin; all: every group of every blend, dirty or not. */
static ub_result update_begin_ex(ub_runtime *rt, uint32_t max_jobs, int all, uint32_t *out_jobs)
{
  assert(rt && out_jobs);
  if (max_jobs == 0 || max_jobs > UB_RUNTIME_MAX_JOBS || rt->job_count)
    return UB_ERR_INVALID_ARGUMENT; /* (job_count: an update begun and not ended) */
  if (max_jobs > rt->job_cap) {
    if (rt->chg_runs) {
      uint32_t *c = realloc(rt->chg_runs, chg_pairs(rt, max_jobs) * 2 * sizeof *c);
      if (!c)
        return UB_ERR_OUT_OF_MEMORY;
      rt->chg_runs = c;
      uint32_t *at = realloc(rt->chg_at, (size_t)max_jobs * sizeof *at);
      if (!at)
        return UB_ERR_OUT_OF_MEMORY;
      rt->chg_at = at;
    }
    rt_job *j = realloc(rt->jobs, (size_t)max_jobs * sizeof *j);
    if (!j)
      return UB_ERR_OUT_OF_MEMORY;
    rt->jobs = j;
    rt->job_cap = max_jobs;
  }
  ub_blend *bl[3] = {rt->lm_blend, rt->glg_blend, rt->llg_blend};
  for (int i = 0; i < 3; i++)
    if (bl[i]) {
      ub_result r = ub_blend_reserve_parts(bl[i], max_jobs);
      if (r != UB_OK)
        return r;
    }
  /* merged texels may stay as they are unless every group is recomputed or every element
   * with texel records changed (each merged texel then has one of its own among them) */
  rt->pad_skip = 0;
  if (rt->pad_bits && !all)
    for (uint32_t e = 0; e < rt->elem_total; e++) {
      rt->lm_chg[e] = (uint8_t)ub_blend_element_dirty(rt->lm_blend, e);
      rt->pad_skip |= !rt->lm_chg[e] && rt->lm_rec[e].count;
    }
  for (int i = 0; i < 3; i++)
    if (bl[i])
      ub_blend_update_begin(bl[i], all);
  for (uint32_t j = 0; rt->chg_runs && j < max_jobs; j++) /* each job's runs (chg_at) */
    rt->chg_at[j] = ub_blend_part_first(rt->lm_blend, j, max_jobs) + j;
  memset(rt->jobs, 0, (size_t)max_jobs * sizeof *rt->jobs);
  llg_chg_clear(rt);
  for (uint32_t e = 0; rt->updated && e < rt->elem_total; e++)
    rt->updated[e] = rt->value[3 * (size_t)e];
  rt->job_count = max_jobs;
  *out_jobs = max_jobs;
  return UB_OK;
}

void ub_runtime_update_job(ub_runtime *rt, uint32_t job)
{
  assert(rt);
  if (job >= rt->job_count) /* no update begun, or not one of its jobs: nothing to do */
    return;
  rt_job *jb = &rt->jobs[job];
  jb->done = 1;
  const uint32_t parts = rt->job_count;
  /* the whole job, the last texels' encode (touched_flush) included, in the blend's mode:
   * which texels end a job depends on the split, their bits must not */
  const unsigned csr = ub_fp_mode_enter();
  double t0 = rt_now(), t1 = t0, t2 = t0;
  if (rt->lm_blend) {
    touched_ctx tc;
    memset(&tc, 0, sizeof tc);
    tc.rt = rt;
    tc.pad_t = UINT32_MAX;
    tc.runs = rt->chg_runs + (size_t)rt->chg_at[job] * 2;
    tc.cap = ub_blend_part_first(rt->lm_blend, job + 1, parts) + job + 1 - rt->chg_at[job];
    ub_blend_update_part(rt->lm_blend, job, parts, lm_touched, &tc, NULL, &jb->lm);
    touched_flush(&tc);
    jb->texels = tc.texels;
    jb->kept = tc.kept;
    jb->based = tc.based;
    jb->left = tc.left;
    jb->runs = tc.nruns;
    jb->runs_full = tc.full;
    t1 = rt_now();
  }
  if (rt->glg_blend) {
    ub_blend_mark_part_ex(rt->glg_blend, job, parts, glg_marked, glg_listed, rt, &jb->glg);
    t2 = rt_now();
  } else
    t2 = t1;
  if (rt->llg_blend) /* models read llg_cur */
    ub_blend_update_part(rt->llg_blend, job, parts, llg_touched, rt, rt->llg_cur, &jb->llg);
  jb->seconds[0] = t1 - t0;
  jb->seconds[1] = t2 - t1;
  jb->seconds[2] = rt_now() - t2;
  ub_fp_mode_leave(csr);
}

void ub_runtime_update_end(ub_runtime *rt, ub_runtime_update_stats *out_stats)
{
  assert(rt);
  ub_runtime_update_stats st;
  memset(&st, 0, sizeof st);
  if (!rt->job_count) { /* no update begun: the last one's changes stay listed */
    if (out_stats)
      *out_stats = st;
    return;
  }
  /* a job the caller did not run: run here, or its receivers would keep the old state
   * (and, their weights now applied, never be blended again) */
  for (uint32_t j = 0; j < rt->job_count; j++)
    if (!rt->jobs[j].done)
      ub_runtime_update_job(rt, j);
  rt->chg_all = 0;
  for (uint32_t j = 0; j < rt->job_count; j++) {
    const rt_job *jb = &rt->jobs[j];
    st.texels_written += jb->lm.receivers - jb->left;
    st.texels_reencoded += jb->texels;
    st.texels_kept += jb->kept;
    st.texels_base += jb->based;
    /* the lightmap blend streams its rows; the re-encode reads the normals, writes the
     * AHD; a texel copied back reads its kept or base AHD */
    const uint64_t copied = jb->kept + jb->based;
    st.bytes_read += jb->lm.bytes_read + (jb->texels - copied) * 3 * sizeof(float) +
                     copied * sizeof(ub_ahd_packed) + jb->glg.bytes_read +
                     jb->llg.bytes_read;
    st.bytes_written += jb->texels * sizeof(ub_ahd_packed) + jb->glg.bytes_written +
                        jb->llg.bytes_written;
    st.probes_written += jb->glg.receivers;
    st.llg_probes_written += jb->llg.receivers;
    st.llg_probes_kept += jb->llg.receivers_reference;
    st.groups += jb->lm.groups + jb->glg.groups + jb->llg.groups;
    st.seconds_lightmap = fmax(st.seconds_lightmap, jb->seconds[0]);
    st.seconds_glg = fmax(st.seconds_glg, jb->seconds[1]);
    st.seconds_llg = fmax(st.seconds_llg, jb->seconds[2]);
    rt->chg_all |= jb->runs_full;
  }
  rt->chg_jobs = rt->job_count;
  rt->chg_stay = rt->pad_skip;
  rt->chg_texels = rt->chg_all ? rt->touched : st.texels_reencoded;
  rt->job_count = 0;
  if (out_stats)
    *out_stats = st;
}

ub_result ub_runtime_update(ub_runtime *rt, ub_runtime_update_stats *out_stats)
{
  assert(rt);
  uint32_t jobs;
  ub_result r = ub_runtime_update_begin(rt, 1, &jobs);
  if (r != UB_OK)
    return r;
  ub_runtime_update_job(rt, 0);
  ub_runtime_update_end(rt, out_stats);
  return UB_OK;
}

ub_result ub_runtime_query_glg(const ub_runtime *rt, const float p[3], const float n[3],
                               uint32_t *inout_tet_cache, float out_rgb[3])
{
  assert(rt && p && n && out_rgb);
  if (!rt->has_glg)
    return UB_ERR_NOT_BAKED;
  if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]))
    return UB_ERR_INVALID_ARGUMENT;
  uint32_t local = UB_GLG_NO_CACHE;
  ub_glg_query(&rt->glg, p, n, inout_tet_cache ? inout_tet_cache : &local, out_rgb);
  return UB_OK;
}

ub_result ub_runtime_query_glg_cursor(const ub_runtime *rt, const float p[3], const float n[3],
                                      ub_glg_cursor *cursor, float out_rgb[3])
{
  assert(rt && p && n && cursor && out_rgb);
  if (!rt->has_glg)
    return UB_ERR_NOT_BAKED;
  if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]))
    return UB_ERR_INVALID_ARGUMENT;
  ub_glg_query_cursor(&rt->glg, p, n, cursor, out_rgb);
  return UB_OK;
}

ub_result ub_runtime_glg_probe_sh(const ub_runtime *rt, int windowed, float *out)
{
  assert(rt && out);
  if (!rt->has_glg)
    return UB_ERR_NOT_BAKED;
  for (uint32_t q = 0; q < rt->glg.probe_count; q++)
    ub_glg_probe_sh(&rt->glg, q, windowed, out + 27 * (size_t)q);
  return UB_OK;
}

const ub_glg *ub_runtime_glg(const ub_runtime *rt)
{
  assert(rt);
  return rt->has_glg ? &rt->glg : NULL;
}

const ub_bakefile *ub_runtime_bakefile(const ub_runtime *rt)
{
  assert(rt);
  return rt->bf;
}

void ub_runtime_memory_usage(const ub_runtime *rt, ub_runtime_memory *out)
{
  assert(rt && out);
  const ub_bakefile *bf = rt->bf;
  ub_runtime_memory m;
  memset(&m, 0, sizeof m);
  const size_t F = sizeof(float), U = sizeof(uint32_t);
  m.geometry = (size_t)bf->vertex_count * 3 * F +
               (size_t)bf->triangle_count * (3 * U + sizeof(int32_t) + 9 * F) +
               (bf->tri_role ? (size_t)bf->triangle_count * U : 0) +
               (size_t)bf->light_count * sizeof(ub_bakefile_light) +
               (bf->glg_positions ? (size_t)bf->glg_probe_count * 3 * F : 0) +
               (size_t)bf->glg_tet_count * (4 * U + (bf->glg_neigh ? 4 * sizeof(int32_t) : 0) + U) +
               (size_t)bf->glg_plane_count * 4 * F + (size_t)rt->lit_count * U;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    size_t t = (size_t)bf->atlases[a].width * bf->atlases[a].height;
    size_t ns = rt->slot_first ? (size_t)(rt->slot_first[a + 1] - rt->slot_first[a]) : 0;
    m.geometry += ns * 3 * sizeof(uint16_t) + t; /* covered texels' normals (halves), coverage */
    size_t nd = 0; /* padding pixels and their sources */
    if (rt->dil_src && rt->dil_src[a] && t)
      nd = rt->dil_rank[a][(t - 1) / 64] +
           (size_t)__builtin_popcountll(rt->dil_bits[a][(t - 1) / 64]);
    m.lightmap += ns * (sizeof(ub_ahd_packed) + U) + (t + 63) / 64 * 2 * (8 + U) + nd * U +
                  (bf->atlases[a].sh ? t * UB_SH1_FLOATS * F : 0) +
                  (rt->fallback ? (size_t)rt->fallback[a].count * (U + 3 * F) : 0);
  }
  if (rt->ahd_kept) /* the kept state's AHD (ub_runtime_keep_state) */
    m.lightmap += (size_t)rt->touched * sizeof(ub_ahd_packed);
  if (rt->ahd_base) /* the base state's AHD */
    m.lightmap += (size_t)rt->touched * sizeof(ub_ahd_packed);
  if (rt->chg_runs) /* changed-texel runs */
    m.lightmap += chg_pairs(rt, rt->job_cap) * 2 * U + (size_t)rt->job_cap * U;
  if (rt->pad_bits) /* the merged texels' index, the combinations they joined, lm_chg */
    m.lightmap += (size_t)(rt->touched + 63) / 64 * (8 + U) + (size_t)rt->pad_count * (8 + U) +
                  ((size_t)rt->pad_targets + 1 + rt->pad_off[rt->pad_targets]) * U +
                  rt->elem_total + rt->pad_count;
  if (rt->llg_chg)
    m.llg += bf->llg_count * sizeof *rt->llg_chg;
  if (rt->tch_bits) {
    size_t slots = (size_t)rt->slot_first[bf->atlas_count], words = (slots + 63) / 64, t = 0;
    for (size_t w = 0; w < words; w++)
      t += (size_t)__builtin_popcountll(rt->tch_bits[w]);
    m.lightmap += t * (3 * F + 2 * U) + (slots - t) * UB_SH1_FLOATS * 2 +
                  words * (8 + U);
  }
  for (uint32_t i = 0; i < bf->llg_count; i++) {
    const ub_bakefile_llg *g = &bf->llgs[i];
    size_t np = (size_t)g->dims[0] * g->dims[1] * g->dims[2];
    m.geometry += (size_t)g->vertex_count * (3 + 3 + 9 + 3) * F + (size_t)g->triangle_count * 3 * U;
    if (!rt->llg_cur)
      m.llg += np * 27 * F;
  }
  if (rt->llg_cur)
    m.llg += (size_t)rt->llg_first[bf->llg_count] * 27 * F;
  if (rt->has_glg)
    m.glg = ub_glg_owned_bytes(&rt->glg) + /* compact store, walk data */
            (bf->glg_sh ? (size_t)bf->glg_probe_count * 27 * F : 0);
  /* Records: the blends' copies of the values (half, group order; the receiver indices
   * are in their tables); anything the bake file still holds (a failed setup). */
  ub_blend *bl[3] = {rt->lm_blend, rt->glg_blend, rt->llg_blend};
  for (int i = 0; i < 3; i++)
    if (bl[i]) {
      ub_blend_info in;
      ub_blend_get_info(bl[i], &in);
      m.records += in.record_bytes;
      m.blend += in.engine_bytes;
    }
  uint32_t n = bf->dls_count + bf->elem_count;
  for (uint32_t e = 0; e < n; e++) {
    const ub_bakefile_record *r = element_record(bf, e);
    m.records += (r->texel_index ? (size_t)r->texel_count * U : 0) +
                 (r->texel_sh_half ? (size_t)r->texel_count * UB_SH1_FLOATS * 2 : 0) +
                 (r->probe_sh_half ? (size_t)r->probe_count * 27 * 2 : 0) +
                 (r->llg_probe_sh_half ? (size_t)r->llg_probe_count * 27 * 2 : 0) +
                 (r->texel_sh ? (size_t)r->texel_count * UB_SH1_FLOATS * F : 0) +
                 (r->probe_index ? (size_t)r->probe_count * U : 0) +
                 (r->probe_sh ? (size_t)r->probe_count * 27 * F : 0) +
                 (r->llg_probe_index ? (size_t)r->llg_probe_count * U : 0) +
                 (r->llg_probe_sh ? (size_t)r->llg_probe_count * 27 * F : 0);
  }
  m.total = m.geometry + m.lightmap + m.glg + m.llg + m.records + m.blend;
  *out = m;
}

/* Texel (x, y) of atlas `atlas` exists (the texel accessors' range check). */
static int texel_in_range(const ub_runtime *rt, uint32_t atlas, uint32_t x, uint32_t y)
{
  const ub_bakefile *bf = rt->bf;
  return atlas < bf->atlas_count && x < bf->atlases[atlas].width &&
         y < bf->atlases[atlas].height;
}

ub_result ub_runtime_texel_normal(const ub_runtime *rt, uint32_t atlas, uint32_t x, uint32_t y,
                                  float out_n[3])
{
  assert(rt && out_n);
  const ub_bakefile *bf = rt->bf;
  if (!texel_in_range(rt, atlas, x, y))
    return UB_ERR_INVALID_ARGUMENT;
  const int64_t t = texel_pixel(rt, atlas, (size_t)y * bf->atlases[atlas].width + x);
  if (t < 0) { /* empty (or padding no texel reaches) */
    out_n[0] = out_n[1] = out_n[2] = 0.0f;
    return UB_OK;
  }
  const uint16_t *h = texel_nrm_of(rt, atlas, (size_t)t);
  for (int k = 0; k < 3; k++)
    out_n[k] = ub_half_to_float(h[k]);
  return UB_OK;
}

ub_result ub_runtime_texel_source(const ub_runtime *rt, uint32_t atlas, uint32_t x, uint32_t y,
                                  uint32_t *out_x, uint32_t *out_y)
{
  assert(rt && out_x && out_y);
  if (!texel_in_range(rt, atlas, x, y))
    return UB_ERR_INVALID_ARGUMENT;
  const uint32_t w = rt->bf->atlases[atlas].width;
  const int64_t t = texel_pixel(rt, atlas, (size_t)y * w + x);
  if (t < 0)
    return UB_ERR_NOT_BAKED;
  *out_x = (uint32_t)((uint64_t)t % w);
  *out_y = (uint32_t)((uint64_t)t / w);
  return UB_OK;
}

/* Covered pixel i's SH row in the current state: the file's floats while loading (plain
 * SH), afterwards (tch_bits) in I_z form, from the lightmap blend for a touched texel, from
 * the halves for the others (into srow). */
static const float *texel_row(const ub_runtime *rt, uint32_t a, size_t i,
                              float srow[UB_SH1_FLOATS])
{
  if (!rt->tch_bits)
    return rt->bf->atlases[a].sh + i * UB_SH1_FLOATS;
  uint64_t ix;
  if (slot_touched(rt, rt->slot_first[a] + slot_of(rt, a, i), &ix)) {
    int got = ub_blend_row(rt->lm_blend, (uint32_t)ix, srow);
    assert(got); /* a touched texel is in a group */
    (void)got;
  } else {
    for (int c = 0; c < UB_SH1_FLOATS; c++)
      srow[c] = ub_half_to_float(rt->lm_static[ix * UB_SH1_FLOATS + c]) * rt->lm_static_scale;
  }
  return srow;
}

ub_result ub_runtime_texel_irradiance(const ub_runtime *rt, uint32_t atlas, uint32_t x,
                                      uint32_t y, const float n[3], float out_rgb[3])
{
  assert(rt && n && out_rgb);
  float nn[3];
  if (!texel_in_range(rt, atlas, x, y) || !normalise3(n, nn))
    return UB_ERR_INVALID_ARGUMENT;
  const ub_bakefile_atlas *at = &rt->bf->atlases[atlas];
  const int64_t t = texel_pixel(rt, atlas, (size_t)y * at->width + x);
  if (t < 0) {
    out_rgb[0] = out_rgb[1] = out_rgb[2] = 0.0f;
    return UB_OK;
  }
  /* the texel's AHD in float, encoded from its current SH as the update does (the
   * stored, packed one is this rounded to half: ub_runtime_texel_ahd) */
  float srow[UB_SH1_FLOATS];
  ub_ahd ahd;
  encode_texel(rt, atlas, texel_row(rt, atlas, (size_t)t, srow), rt->tch_bits != NULL,
               (size_t)t, &ahd);
  ub_ahd_irradiance(&ahd, nn, out_rgb);
  return UB_OK;
}

float ub_runtime_ahd_scale(const ub_runtime *rt)
{
  assert(rt);
  return rt->ahd ? rt->ahd_scale : 1.0f;
}

ub_result ub_runtime_texel_ahd(const ub_runtime *rt, uint32_t atlas, uint32_t x, uint32_t y,
                               ub_ahd_packed *out)
{
  assert(rt && out);
  if (!texel_in_range(rt, atlas, x, y))
    return UB_ERR_INVALID_ARGUMENT;
  const int64_t t = texel_pixel(rt, atlas, (size_t)y * rt->bf->atlases[atlas].width + x);
  if (t < 0)
    return UB_ERR_NOT_BAKED;
  *out = *texel_ahd_of(rt, atlas, (size_t)t);
  return UB_OK;
}

int ub_runtime_llg_changed(const ub_runtime *rt, uint32_t model)
{
  assert(rt);
  return rt->llg_chg && model < rt->bf->llg_count &&
         atomic_load_explicit(&rt->llg_chg[model], memory_order_relaxed);
}

uint64_t ub_runtime_changed_texel_count(const ub_runtime *rt)
{
  assert(rt);
  return rt->chg_texels;
}

/* Changed texels [first, first + count) of rank order into out: the slot's pixel split into
 * x, y without a division per texel (the atlas's 1/width in double, corrected to exact:
 * pixel indices are < 2^31, so the product is off by less than one), the slots' pixels
 * requested a few texels ahead (a random read each: ranks are group-major). */
static void changed_texels_run(const ub_runtime *rt, uint64_t first, uint64_t count,
                               ub_runtime_texel_change *out)
{
  enum { AHEAD = 16 };
  uint32_t a = UINT32_MAX, w = 0;
  uint64_t lo = 0, hi = 0; /* slots of atlas a */
  double inv_w = 0.0;
  for (uint64_t k = 0; k < count; k++) {
    if (k + AHEAD < count)
      __builtin_prefetch(&rt->slot_pixel[rt->tch_slot[first + k + AHEAD]]);
    const uint64_t s = rt->tch_slot[first + k];
    if (s < lo || s >= hi) {
      a = slot_atlas(rt, s);
      lo = rt->slot_first[a];
      hi = rt->slot_first[a + 1];
      w = rt->bf->atlases[a].width;
      inv_w = 1.0 / (double)w;
    }
    const uint32_t px = rt->slot_pixel[s];
    uint32_t y = (uint32_t)((double)px * inv_w);
    if ((uint64_t)y * w > px)
      y--;
    else if ((uint64_t)(y + 1) * w <= px)
      y++;
    out[k].atlas = a;
    out[k].x = px - y * w;
    out[k].y = y;
    out[k].ahd = rt->ahd[first + k];
  }
}

/* Changed texels [k0, k0 + m) of run [first, first + count) into out, returning how many
 * were written: the run's ranks but the merged texels the update left (pad_stay). out
 * NULL: how many the run has (k0 and m ignored). */
static uint64_t changed_texels_gaps(const ub_runtime *rt, uint64_t first, uint64_t count,
                                    uint64_t k0, uint64_t m, ub_runtime_texel_change *out)
{
  const uint64_t end = first + count;
  uint64_t n = 0, seen = 0, r = first, i = first; /* [i, r): no texel left */
  const int stays = rt->chg_stay; /* (else pad_stay may be a former update's) */
  uint32_t k = stays ? pad_index_at(rt, first) : 0;
  for (;;) {
    uint64_t s = end; /* the next texel left, or end */
    while (stays && (r = pad_next(rt, r, end)) < end) {
      const int stayed = rt->pad_stay[k++];
      if (stayed) {
        s = r++;
        break;
      }
      r++;
    }
    const uint64_t len = s - i;
    if (out && seen + len > k0) {
      const uint64_t a = k0 > seen ? k0 - seen : 0, take = len - a < m - n ? len - a : m - n;
      changed_texels_run(rt, i + a, take, out + n);
      n += take;
    }
    seen += len;
    if (s >= end || (out && n >= m))
      break;
    i = s + 1;
  }
  return out ? n : seen;
}

size_t ub_runtime_changed_texels(const ub_runtime *rt, uint64_t start, size_t max,
                                 ub_runtime_texel_change *out)
{
  assert(rt && (out || !max));
  size_t n = 0;
  if (rt->chg_all) {
    if (start < rt->touched) {
      n = rt->touched - start < max ? (size_t)(rt->touched - start) : max;
      changed_texels_run(rt, start, n, out);
    }
    return n;
  }
  if (start >= rt->chg_texels || !rt->chg_at) /* (no lightmap records: no runs kept) */
    return 0;
  uint64_t seen = 0; /* changed texels in the runs before (counted up to start) */
  for (uint32_t j = 0; j < rt->chg_jobs && n < max; j++) {
    const uint32_t *runs = rt->chg_runs + (size_t)rt->chg_at[j] * 2;
    for (uint32_t r = 0; r < rt->jobs[j].runs && n < max; r++) {
      const uint64_t first = runs[2 * r], count = runs[2 * r + 1];
      uint64_t k0 = 0;
      if (seen < start) { /* (counted only while skipping to start) */
        const uint64_t changed = changed_texels_gaps(rt, first, count, 0, 0, NULL);
        if (seen + changed <= start) {
          seen += changed;
          continue;
        }
        k0 = start - seen;
        seen = start;
      }
      n += (size_t)changed_texels_gaps(rt, first, count, k0, max - n, out + n);
    }
  }
  return n;
}

ub_result ub_runtime_atlas_ahd(const ub_runtime *rt, uint32_t atlas, ub_ahd_packed *out)
{
  assert(rt && out);
  if (atlas >= rt->bf->atlas_count)
    return UB_ERR_INVALID_ARGUMENT;
  const size_t n = (size_t)rt->bf->atlases[atlas].width * rt->bf->atlases[atlas].height;
  for (size_t i = 0; i < n; i++) {
    const int64_t t = texel_pixel(rt, atlas, i);
    if (t < 0)
      memset(&out[i], 0, sizeof out[i]);
    else
      out[i] = *texel_ahd_of(rt, atlas, (size_t)t);
  }
  return UB_OK;
}

/* ---------------------------------------------------------------------------------- */
/* Closest point on a triangle (Ericson, Real-Time Collision Detection §5.1.5), in double, */
/* returning barycentrics. Degenerate triangles fall back to their edges.              */

static double dot3d(const double a[3], const double b[3])
{
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void sub3d(const double a[3], const double b[3], double out[3])
{
  for (int i = 0; i < 3; i++)
    out[i] = a[i] - b[i];
}

/* Closest point on segment ab to p as the parameter t ∈ [0, 1] (a + t·(b − a)). */
static double closest_t_segment(const double p[3], const double a[3], const double b[3])
{
  double ab[3], ap[3];
  sub3d(b, a, ab);
  sub3d(p, a, ap);
  double l2 = dot3d(ab, ab);
  if (!(l2 > 0.0))
    return 0.0;
  double t = dot3d(ap, ab) / l2;
  return t < 0.0 ? 0.0 : t > 1.0 ? 1.0 : t;
}

static void bary_point(const double a[3], const double b[3], const double c[3],
                       const double bary[3], double out[3])
{
  for (int i = 0; i < 3; i++)
    out[i] = bary[0] * a[i] + bary[1] * b[i] + bary[2] * c[i];
}

static void closest_on_edges(const double p[3], const double a[3], const double b[3],
                             const double c[3], double out_bary[3])
{
  const double *v[3] = {a, b, c};
  double best = INFINITY;
  for (int e = 0; e < 3; e++) {
    int i = e, j = (e + 1) % 3;
    double t = closest_t_segment(p, v[i], v[j]);
    double bary[3] = {0, 0, 0}, q[3], d[3];
    bary[i] = 1.0 - t;
    bary[j] = t;
    bary_point(a, b, c, bary, q);
    sub3d(p, q, d);
    double d2 = dot3d(d, d);
    if (d2 < best) {
      best = d2;
      memcpy(out_bary, bary, sizeof bary);
    }
  }
}

static void closest_on_triangle(const double p[3], const double a[3], const double b[3],
                                const double c[3], double out_bary[3])
{
  double ab[3], ac[3], ap[3], bp[3], cp[3];
  sub3d(b, a, ab);
  sub3d(c, a, ac);
  double cr[3] = {ab[1] * ac[2] - ab[2] * ac[1], ab[2] * ac[0] - ab[0] * ac[2],
                  ab[0] * ac[1] - ab[1] * ac[0]};
  if (!(dot3d(cr, cr) > 0.0)) {
    closest_on_edges(p, a, b, c, out_bary);
    return;
  }
  sub3d(p, a, ap);
  double d1 = dot3d(ab, ap), d2 = dot3d(ac, ap);
  if (d1 <= 0.0 && d2 <= 0.0) { /* vertex region A */
    out_bary[0] = 1, out_bary[1] = 0, out_bary[2] = 0;
    return;
  }
  sub3d(p, b, bp);
  double d3 = dot3d(ab, bp), d4 = dot3d(ac, bp);
  if (d3 >= 0.0 && d4 <= d3) { /* vertex region B */
    out_bary[0] = 0, out_bary[1] = 1, out_bary[2] = 0;
    return;
  }
  double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) { /* edge AB */
    double v = d1 - d3 > 0.0 ? d1 / (d1 - d3) : 0.0;
    out_bary[0] = 1.0 - v, out_bary[1] = v, out_bary[2] = 0;
    return;
  }
  sub3d(p, c, cp);
  double d5 = dot3d(ab, cp), d6 = dot3d(ac, cp);
  if (d6 >= 0.0 && d5 <= d6) { /* vertex region C */
    out_bary[0] = 0, out_bary[1] = 0, out_bary[2] = 1;
    return;
  }
  double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) { /* edge AC */
    double w = d2 - d6 > 0.0 ? d2 / (d2 - d6) : 0.0;
    out_bary[0] = 1.0 - w, out_bary[1] = 0, out_bary[2] = w;
    return;
  }
  double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0) { /* edge BC */
    double den = (d4 - d3) + (d5 - d6);
    double w = den > 0.0 ? (d4 - d3) / den : 0.0;
    out_bary[0] = 0, out_bary[1] = 1.0 - w, out_bary[2] = w;
    return;
  }
  double den = va + vb + vc;
  if (!(den > 0.0)) {
    closest_on_edges(p, a, b, c, out_bary);
    return;
  }
  double v = vb / den, w = vc / den;
  out_bary[0] = 1.0 - v - w, out_bary[1] = v, out_bary[2] = w;
}

/* ---------------------------------------------------------------------------------- */
/* Bilinear AHD lookup.                                                                */

/* The AHD at lightmap uv: bilinear over the covered texels' SH and normals, encoded once.
 * Empty texels and texels separated from the nearest one by geometry (the .ubk's texel
 * links) are left out and the weights renormalised; with all four empty, the
 * nearest non-empty texel within UB_RT_EMPTY_SEARCH_RADIUS is used. */
static int sample_ahd(const ub_runtime *rt, uint32_t atlas, float u, float v, ub_ahd *out)
{
  const ub_bakefile_atlas *at = &rt->bf->atlases[atlas];
  u = u > 0.0f ? (u < 1.0f ? u : 1.0f) : 0.0f; /* NaN → 0 */
  v = v > 0.0f ? (v < 1.0f ? v : 1.0f) : 0.0f;
  float fx = u * (float)at->width - 0.5f, fy = v * (float)at->height - 0.5f;
  float x0f = floorf(fx), y0f = floorf(fy);
  float tx = fx - x0f, ty = fy - y0f;
  int64_t x0 = (int64_t)x0f, y0 = (int64_t)y0f;
  int64_t w = at->width, h = at->height;

  /* Bilinear over the texels' linear data (SH L1 of the current state and the encode
   * normals), then one AHD encode: filtering the AHD parameters themselves (non-linear)
   * is off by up to 40% along the normal between texels that are each exact. */
  const int cur = rt->tch_bits != NULL; /* texel_row's rows are in I_z form */
  double sw = 0, sh[UB_SH1_FLOATS] = {0}, nn[3] = {0, 0, 0};
  /* not across a wall or closed door standing between texels (runtime/texel_links.h) */
  unsigned keep = ub_texel_links_keep(at->link, w, h, x0, y0, tx, ty);
  for (int k = 0; k < 4; k++) {
    if (!(keep & (1u << k)))
      continue;
    int64_t x = x0 + (k & 1), y = y0 + (k >> 1);
    x = x < 0 ? 0 : x >= w ? w - 1 : x;
    y = y < 0 ? 0 : y >= h ? h - 1 : y;
    const int64_t ti = texel_pixel(rt, atlas, (size_t)y * (size_t)w + (size_t)x);
    if (ti < 0)
      continue;
    const size_t i = (size_t)ti; /* padding: the texel it copies */
    double wt = ((k & 1) ? tx : 1.0f - tx) * ((k >> 1) ? ty : 1.0f - ty);
    if (!(wt > 0.0))
      continue;
    sw += wt;
    float ts[UB_SH1_FLOATS], tn[3];
    float srow[UB_SH1_FLOATS];
    texel_sh_at(rt, atlas, texel_row(rt, atlas, i, srow), cur, i, ts, tn);
    for (int c = 0; c < UB_SH1_FLOATS; c++)
      sh[c] += wt * ts[c];
    for (int c = 0; c < 3; c++)
      nn[c] += wt * tn[c];
  }
  if (!(sw > 0.0)) {
    /* Nearest non-empty texel around the sample point. */
    int64_t cx = (int64_t)floorf(u * (float)at->width), cy = (int64_t)floorf(v * (float)at->height);
    double best = INFINITY;
    size_t bi = 0;
    for (int64_t y = cy - UB_RT_EMPTY_SEARCH_RADIUS; y <= cy + UB_RT_EMPTY_SEARCH_RADIUS; y++)
      for (int64_t x = cx - UB_RT_EMPTY_SEARCH_RADIUS; x <= cx + UB_RT_EMPTY_SEARCH_RADIUS; x++) {
        if (x < 0 || y < 0 || x >= w || y >= h)
          continue;
        const int64_t ti = texel_pixel(rt, atlas, (size_t)y * (size_t)w + (size_t)x);
        double dx = (double)x - fx, dy = (double)y - fy, d2 = dx * dx + dy * dy;
        if (ti >= 0 && d2 < best) {
          best = d2;
          bi = (size_t)ti;
        }
      }
    if (best == INFINITY)
      return 0;
    ub_ahd_unpack(texel_ahd_of(rt, atlas, bi), rt->ahd_scale, out);
    return 1;
  }
  float fsh[UB_SH1_FLOATS], fn[3] = {(float)nn[0], (float)nn[1], (float)nn[2]}, un[3];
  for (int c = 0; c < UB_SH1_FLOATS; c++)
    fsh[c] = (float)(sh[c] / sw);
  if (!normalise3(fn, un))
    sh_dominant_direction(fsh, un);
  ub_ahd_encode(fsh, un, out);
  return 1;
}

ub_result ub_runtime_query_lightmap_ex(const ub_runtime *rt, const float p[3],
                                       const float n[3], float out_rgb[3],
                                       ub_runtime_lightmap_hit *out_hit)
{
  assert(rt && p && n && out_rgb);
  if (rt->lit_count == 0)
    return UB_ERR_NOT_BAKED;
  float nn[3];
  if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]) || !normalise3(n, nn))
    return UB_ERR_INVALID_ARGUMENT;

  /* The closest lightmapped surface point among the triangles the current state shows
   * (a hidden object's or door leaf's surface is not in the level now: its texels hold
   * the lighting it had when shown); the closest hidden one is remembered for the hit. */
  const ub_bakefile *bf = rt->bf;
  double pd[3] = {p[0], p[1], p[2]};
  double best_d2 = INFINITY, best_bary[3] = {1, 0, 0}, hid_d2 = INFINITY;
  uint32_t best_tri = UINT32_MAX, hid_tri = UINT32_MAX;
  for (uint32_t k = 0; k < rt->lit_count; k++) {
    uint32_t t = rt->lit_tris[k];
    int shown = ub_runtime_triangle_shown(rt, t);
    double v[3][3];
    for (int j = 0; j < 3; j++) {
      const float *pos = &bf->positions[(size_t)bf->indices[(size_t)t * 3 + j] * 3];
      v[j][0] = pos[0], v[j][1] = pos[1], v[j][2] = pos[2];
    }
    double bary[3], q[3], d[3];
    closest_on_triangle(pd, v[0], v[1], v[2], bary);
    bary_point(v[0], v[1], v[2], bary, q);
    sub3d(pd, q, d);
    double d2 = dot3d(d, d);
    if (!shown) {
      if (d2 < hid_d2) {
        hid_d2 = d2;
        hid_tri = t;
      }
    } else if (d2 < best_d2) {
      best_d2 = d2;
      best_tri = t;
      memcpy(best_bary, bary, sizeof bary);
    }
  }
  if (best_tri == UINT32_MAX)
    return UB_ERR_NOT_BAKED; /* every lightmapped triangle is hidden */

  const float *uv = &bf->tri_uv[(size_t)best_tri * 6];
  double u = best_bary[0] * uv[0] + best_bary[1] * uv[2] + best_bary[2] * uv[4];
  double v = best_bary[0] * uv[1] + best_bary[1] * uv[3] + best_bary[2] * uv[5];
  ub_ahd ahd;
  if (sample_ahd(rt, (uint32_t)bf->tri_atlas[best_tri], (float)u, (float)v, &ahd))
    ub_ahd_irradiance(&ahd, nn, out_rgb);
  else
    out_rgb[0] = out_rgb[1] = out_rgb[2] = 0.0f;
  if (out_hit) {
    ub_runtime_lightmap_hit h;
    h.triangle = best_tri;
    h.distance = (float)sqrt(best_d2);
    h.hidden_closer = hid_d2 < best_d2;
    h.hidden_triangle = h.hidden_closer ? hid_tri : UINT32_MAX;
    h.hidden_element = -1;
    if (h.hidden_closer && bf->tri_role && bf->tri_role[hid_tri])
      h.hidden_element = (int32_t)(bf->tri_role[hid_tri] & 0xFFFFFFu);
    h.hidden_distance = h.hidden_closer ? (float)sqrt(hid_d2) : INFINITY;
    *out_hit = h;
  }
  return UB_OK;
}

ub_result ub_runtime_query_lightmap(const ub_runtime *rt, const float p[3], const float n[3],
                                    float out_rgb[3], float *out_distance)
{
  ub_runtime_lightmap_hit h;
  ub_result r = ub_runtime_query_lightmap_ex(rt, p, n, out_rgb, &h);
  if (r == UB_OK && out_distance)
    *out_distance = h.distance;
  return r;
}

ub_result ub_runtime_lightmap_at(const ub_runtime *rt, uint32_t tri, float b1, float b2,
                                 const float n[3], float out_rgb[3])
{
  assert(rt && n && out_rgb);
  const ub_bakefile *bf = rt->bf;
  float nn[3];
  if (tri >= bf->triangle_count || bf->tri_atlas[tri] < 0 || !isfinite(b1) ||
      !isfinite(b2) || !normalise3(n, nn) || !ub_runtime_triangle_shown(rt, tri))
    return UB_ERR_INVALID_ARGUMENT;
  const float *uv = &bf->tri_uv[(size_t)tri * 6];
  float b0 = 1.0f - b1 - b2;
  float u = b0 * uv[0] + b1 * uv[2] + b2 * uv[4];
  float v = b0 * uv[1] + b1 * uv[3] + b2 * uv[5];
  ub_ahd ahd;
  if (sample_ahd(rt, (uint32_t)bf->tri_atlas[tri], u, v, &ahd))
    ub_ahd_irradiance(&ahd, nn, out_rgb);
  else
    out_rgb[0] = out_rgb[1] = out_rgb[2] = 0.0f;
  return UB_OK;
}
