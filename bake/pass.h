/* bake/pass.h — one bake pass: a set of emitters over one geometry state, run as the
 * series expansion of UberBake §2.3 over every receiver.
 *
 * Bounce 0 is direct light at every receiver (punctual lights with shadow rays and spot
 * cones, emissive triangles by area sampling, the sky by cosine rays). Bounce k is a
 * final gather from every receiver whose hits read bounce k-1 where it is stored: the
 * lightmap texel at the hit's UV (bilinear), times albedo/π. Stored data changes only
 * between bounces, so no locks. `primary` lights feed bounce 1 but are not part of the
 * stored result (UberBake eq. 1).
 *
 * Receivers are lightmap texels (with a surface normal: cosine-distributed gather, SH L1
 * plus the exact irradiance along the normal I_z) and probes (points: full-sphere
 * gather, SH L2); both go through the same code with a receiver-set description. At the end the SH is corrected with a
 * cosine lobe about the normal so that its irradiance along the normal equals I_z exactly
 * (linear in the light, so records stay additive; see Sloan & Silvennoinen 2018).
 *
 * Random numbers are hash(seed, pass, receiver, bounce, sample); receivers are processed
 * in fixed blocks, so results are bit-identical for any thread count.
 */
#ifndef UBAKE_BAKE_PASS_H
#define UBAKE_BAKE_PASS_H

#include <stdint.h>

#include "bake/lights.h"
#include "bake/rt.h"
#include "lightmaps/lightmap.h"
#include "ubake/bake.h"

typedef struct ub_pass_desc {
  const ub_scene *scene;
  const ub_rt *rt;
  const ub_emitters *emitters;   /* may be NULL or empty */
  const ub_lightmap *lightmap;
  const uint8_t *light_enabled;  /* light_count bytes: non-zero = the light emits in this pass */
  int emissive;                  /* emissive triangles emit */
  int sky;                       /* the sky emits */
  uint32_t gather_rays;          /* per receiver per bounce */
  uint32_t emissive_samples;     /* per receiver */
  int emitters_by_power;         /* 1: emitters picked by power alone, the same for every
                                    receiver (before 2026-12-06; for tests and benches);
                                    0: by what each receiver sees of them
                                    (ub_emitters_local_cdf) */
  uint32_t shadow_samples;       /* per receiver per punctual light, ≤ UB_TEXEL_SAMPLES */
  /* Probe receivers (GLG and LLG probes): points in free space, full-sphere gather,
   * radiance SH L2. They receive every bounce; nothing reads them back. */
  uint32_t probe_count;
  const float *probe_pos;        /* probe_count × 3, world */
  uint32_t probe_rays;           /* gather rays per probe per bounce (0 = gather_rays) */
  /* Local light grids (probes/llg.h), or NULL: their probes are a third receiver set
   * (full-sphere gather, SH L2, every bounce, rays against llg->rt_env), and gather rays
   * that hit an LLG model read bounce k-1 from its grid × self-visibility × gain. */
  const struct ub_llg_set *llg;
  /* Influence subset (a dynamic element's pass): only these receivers are simulated; the
   * others stay zero. NULL = every receiver. Indices sorted ascending. */
  const uint32_t *texel_subset;
  uint32_t texel_subset_count;
  const uint32_t *probe_subset;
  uint32_t probe_subset_count;
  const uint32_t *llg_subset;    /* LLG probes (indices into llg->probe_pos), same rule */
  uint32_t llg_subset_count;
  /* Sparse gathers (a DLS influence pass): gather_donor (texel_count entries, or NULL)
   * maps each texel of texel_subset to the texel whose bounce light it takes at bounces
   * ≥ 1: itself (it gathers) or a gathering neighbour on the same surface. Direct light
   * (bounce 0) is computed at every texel of texel_subset; the gathers of bounces ≥ 1 run
   * only at gather_subset (the texels that are their own donor, ascending). */
  const uint32_t *gather_donor;
  const uint32_t *gather_subset;
  uint32_t gather_subset_count;
  /* Likewise for GLG probes (NULL: every probe of probe_subset gathers): bounces ≥ 1 run
   * only at these (a subset of probe_subset, ascending); the others get bounce 0 alone and
   * zero indirect (nothing reads probes back: the caller estimates theirs). */
  const uint32_t *probe_gather_subset;
  uint32_t probe_gather_subset_count;
  /* Likewise for LLG probes (NULL: every probe of llg_subset gathers): llg_gather_donor
   * (llg->probe_count entries) maps each probe of llg_subset to the probe whose bounce light
   * it takes at bounces >= 1 (itself when it gathers; copied after each bounce, before hits
   * read the LLGs again); the gathers run only at llg_gather_subset (ascending). */
  const uint32_t *llg_gather_donor;
  const uint32_t *llg_gather_subset;
  uint32_t llg_gather_subset_count;
  /* Fewer gather rays where a receiver's light is faint (a DLS full pass: its influence
   * pass's estimate), or NULL: receiver r's gathers of bounces >= 1 trace
   * (texel_count / probe_count / llg->probe_count entries) gather_rays >> shift[r] rays
   * (probes: probe_rays >> shift[r]), at least min(rays, 4). Bounce 0 and the texel-light
   * samples keep theirs; the MIS weights use each receiver's own count. */
  const uint8_t *texel_ray_shift;
  const uint8_t *probe_ray_shift;
  const uint8_t *llg_ray_shift;
  /* 0 (default): later bounces trace fewer gather rays where a receiver's light has
   * faded. After bounce b ≥ 1, a receiver whose bounce-b light (texels: I_z luminance;
   * probes: DC luminance) is below its brightest bounce so far by 2^k gathers bounce b + 1
   * with rays >> k more (k ≤ UB_BOUNCE_RAY_SHIFT_MAX with its *_ray_shift; a larger
   * *_ray_shift stays; at least min(rays, 4)): rays go where a bounce still brings light
   * (pass.c, bounce_shifts). 1: every bounce at the full rays (for comparison; the DLS
   * influence passes, whose last bounce is the culling estimate's tail). */
  int bounce_full_rays;
  /* Bounce light of the texels outside texel_subset (a cheaper pass's estimate, e.g. the
   * influence pass's keep_bounce_iz): they are not simulated, but their light still
   * bounces: bounce k's image (what bounce k+1 gathers) holds outside_bounce_iz's bounce k
   * (texel_count × 3 I_z RGB per bounce, bounce k at offset (k−1)·texel_count·3) for
   * k ≤ outside_bounces, and beyond that its last bounce scaled by this pass's own bounce
   * energies (e_k / e_last). NULL: outside texels are dark. */
  const float *outside_bounce_iz;
  uint32_t outside_bounces;
  /* Optional with outside_bounce_iz (ascending; NULL: any texel): the only texels where it
   * may be non-zero (a DLS full pass: its influence pass's candidates, whose estimate it
   * is). The outside texels that hold light are then looked for among these, not among
   * the level's every texel (four single-threaded scans of 1.6 M texels per pass at
   * ESTATE scale: one per outside bounce, then counting and listing). The same act list
   * either way, so the same bits. */
  const uint32_t *outside_candidates;
  uint32_t outside_candidate_count;
  /* Footprint samples of a point or spot light near a texel (within 6 texel widths; k × k
   * jittered strata, rounded down to a square): 0 = UB_NEAR_SAMPLES_DEFAULT. The plan
   * sets 16 / 64 / 256 for draft / fast / high. */
  uint32_t near_samples;
  /* Keep each texel's I_z of bounces 1..keep_bounce_iz in the result (texel_bounce_iz). */
  uint32_t keep_bounce_iz;
  int bounces;                   /* -1 = until a bounce adds < stop_fraction of the total */
  double stop_fraction;          /* e.g. 0.005 */
  uint32_t seed;
  uint32_t pass_id;
  /* Adaptive sampling (0 = off): after each bounce's first round, receivers (texels, GLG
   * probes) whose estimated relative standard error (ub_rel_error) is above target_error
   * get further rounds of the same samples with new random numbers, averaged in, until
   * they meet it or have had max_rounds rounds (0 = UB_ADAPT_MAX_ROUNDS). */
  double target_error;
  uint32_t max_rounds;
  /* 1: texel lights (bounces ≥ 1: an eighth of the gather rays sampled toward the bright
   * texels, MIS against the gathers) for every block of receivers that sees a lit texel,
   * not only where the brightest carries UB_TL_PEAK× the mean power (pass.c
   * tl_block_table). The DLS passes: a set's lamp lights one room, and a faint receiver
   * that sees the lit walls through a doorway gets its light from rare bright gather
   * hits, which the texel lights find. */
  int texel_lights_everywhere;
  /* 1: no standard error estimates (texel_se and probe_se stay 0): their per-sample work
   * (each receiver's sample variance, the variance inherited from the lightmap read) is
   * skipped, for a caller that reads neither (the DLS passes). Ignored with target_error,
   * whose rounds need them. The other outputs are the same bits either way. */
  int no_error_estimate;
  /* 1: only the influence measures are kept (texel_direct / _indirect / _bounce_iz, the
   * probes' and LLG probes' direct / indirect, bounce energies, counters); sh, iz,
   * probe_sh, llg_sh, texel_se and probe_se stay NULL, and values a store would have
   * clamped are not counted. For the DLS influence passes, which read nothing else:
   * their level-sized result arrays were allocated, first-touched and freed per set. */
  int no_store;
  /* 1 (with texel_subset and probe_subset): sh and iz hold the texel subset's rows in its
   * order (row i: texel_subset[i]) and probe_sh the probe subset's, instead of level-sized
   * arrays zero elsewhere (ub_pass_result.compact). For the DLS full passes, which read
   * only those rows: at ESTATE full scale their 119 MB of level-sized store per set were
   * first-touched and freed 132 times (~0.4 M page faults). Same values. */
  int compact_store;
  ub_progress_fn progress;
  void *progress_user;
  double progress_base, progress_span; /* this pass's share of the whole bake */
  /* Optional: what passes over the same scene and lightmap share (the texel-light
   * clusters' geometry, the zero-light images of subset passes, and their level-sized
   * scratch arrays, lent to one pass at a time: passes sharing a cache run one after
   * another), built by the first pass that has it, freed by the caller
   * (ub_pass_cache_free). NULL: every pass builds its own. */
  struct ub_pass_cache *cache;
} ub_pass_desc;

/* Later bounces' fewer rays (ub_pass_desc.bounce_full_rays = 0): at most this shift, a
 * quarter of the rays (16 at draft). At 3 (an eighth) estate_small's base pass traced
 * 18.9 instead of 19.5 M gathers but one dark texel became a speck 13× its reference
 * (8 rays, one of them into a bright doorway); at 2 the worst texel is the one that was
 * worst with full rays. */
#define UB_BOUNCE_RAY_SHIFT_MAX 2u

/* A texel's gather ray adds L·Y(ω)/(N·pdf) to the SH, with the cosine pdf: weight ∝ 1/cos θ,
 * unbounded at the horizon. The irradiance along the normal (I_z, cos θ·L/(N·pdf)) is
 * bounded and the stored SH is corrected to it, but the DC and the tangential L1 are not:
 * one ray at cos θ = 0.0002 put 100× a texel's DC into it (README "Grazing gather rays").
 * A ray's SH weight is capped at π/(N·UB_SH_COS_FLOOR), a cosine ray's at this cos θ: a
 * plain gather ray below it adds with weight × cos θ / UB_SH_COS_FLOOR (weights that MIS
 * with lights or a door's guide already bound stay as they are; ub_texel_sh_weight).
 * Biased, by a known amount: for radiance L uniform over the hemisphere the DC (after the
 * I_z correction) comes out (1 − 2·floor/7) of its value and the L1 along n (1 + 2·floor/7),
 * −0.57% / +0.57% at 0.02 (measured on sky_plane: −0.55% / +0.56%), the irradiance at 45°
 * off the normal −0.10%, along the normal exact. In irradiance terms, whatever the light:
 * at a normal α off n it moves E by at most floor·L_h·(sin α/2 + (π/7)(1 − cos α)) ≤
 * 0.019·L_h, L_h the largest radiance arriving below cos θ = floor (README "Grazing gather
 * rays"). I_z and the light the next bounce reads are untouched.
 * 0.05 (bias 1.4%) cut ESTATE's tails no further (README "Grazing gather rays").
 * Checked by tests/hard/test_hard_sh_horizon.c. */
#define UB_SH_COS_FLOOR 0.02

/* A texel receiver's SH weight for a ray of weight wt (1/(n_rays·pdf), or an MIS weight)
 * among n_rays: wt capped at a cosine ray's at UB_SH_COS_FLOOR. The passes, door passes
 * and object passes all use it for their texels' SH; their I_z keeps wt. */
static inline double ub_texel_sh_weight(double wt, uint32_t n_rays)
{
  double cap = 3.14159265358979323846 / ((double)n_rays * UB_SH_COS_FLOOR);
  return wt > cap ? cap : wt;
}

/* A receiver's ray shift for its next bounce (bake/pass.c bounce_shifts): its pass shift,
 * plus one per halving from its brightest bounce so far (peak) down to its last bounce's
 * light (last), up to UB_BOUNCE_RAY_SHIFT_MAX (a larger pass shift stays); nothing more
 * while it has seen no light (peak ≤ 0). */
static inline uint32_t ub_pass_bounce_shift(double peak, double last, uint32_t pass_shift)
{
  uint32_t k = pass_shift;
  if (peak > 0.0) {
    double x = last > 0.0 ? last : 0.0;
    while (k < UB_BOUNCE_RAY_SHIFT_MAX && 2.0 * x <= peak) {
      x *= 2.0;
      k++;
    }
  }
  return k;
}

/* The gather rays of a receiver with ray shift k (ub_pass_desc.texel_ray_shift):
 * rays >> k, at least min(rays, 4). */
static inline uint32_t ub_pass_shifted_rays(uint32_t rays, uint32_t k)
{
  uint32_t m = k < 32 ? rays >> k : 0, lo = rays < 4 ? rays : 4;
  return m < lo ? lo : m;
}

typedef struct ub_pass_cache ub_pass_cache;
ub_pass_cache *ub_pass_cache_create(void); /* NULL when out of memory (passes then build) */
void ub_pass_cache_free(ub_pass_cache *cache); /* NULL-safe */

#define UB_NEAR_SAMPLES_DEFAULT 16u

typedef struct ub_pass_result {
  float *sh;                     /* texel_count × 12: radiance SH L1 (W/(m²·sr)), I_z-exact */
  float *iz;                     /* texel_count × 3: irradiance along the normal (W/m²) */
  float *probe_sh;               /* probe_count × 27: radiance SH L2 (W/(m²·sr)), raw */
  float *llg_sh;                 /* llg->probe_count × 27: LLG probes' radiance SH L2, invalid
                                    probes filled from their neighbours */
  /* Influence measures (luminance, W/m²): what reached each receiver directly (bounce 0,
   * including primary lights' unstored direct light) and through bounces ≥ 1. */
  float *texel_direct, *texel_indirect; /* texel_count */
  float *probe_direct, *probe_indirect; /* probe_count: DC (mean) irradiance */
  float *llg_direct, *llg_indirect;     /* llg->probe_count (0 without LLGs): likewise */
  float *texel_bounce_iz;        /* desc keep_bounce_iz > 0: texel_count × 3 per bounce 1..keep
                                    (zero past the last bounce run), else NULL */
  uint32_t bounces;
  double bounce_energy[UB_BAKE_MAX_BOUNCES + 1];
  /* When the bounce cap ended an auto-stop series: the missing energy estimated as the
     geometric tail of the last two bounces, as a fraction of the total (warned); else 0. */
  double bounce_cap_tail;
  uint64_t rays_gather, rays_shadow;
  uint64_t clamped, backface_hits, unlit_hits;
  uint64_t misses;               /* gather rays that left the level */
  /* Effect counters (issue: simulate only what the scene calls for): shadow rays toward
   * emissive triangles, gather rays that added sky light or hit an emitter. */
  uint64_t rays_emissive, sky_hits, emitter_hits;
  double gather_seconds;
  /* Standard error estimates (luminance, W/m²) from each receiver's own samples, bounces
   * taken as independent: texels along the normal (of iz), probes of the DC irradiance
   * (probe_direct + probe_indirect). Zero for receivers outside the influence subset,
   * and for all of them with desc.no_error_estimate. */
  float *texel_se;               /* texel_count */
  float *probe_se;               /* probe_count */
  uint64_t rays_adaptive;        /* gather + shadow rays of the adaptive rounds */
  uint32_t adaptive_rounds;      /* extra rounds run, summed over bounces */
  uint64_t adaptive_receivers;   /* receiver-rounds refined, summed over rounds */
  int compact; /* desc.compact_store took effect: sh, iz, probe_sh hold the subsets' rows */
  /* A subset pass with desc.cache: its outputs came from the cache's pool and go back
   * there, zeroed at the rows it wrote (ub_pass_result_recycle); NULL otherwise. */
  struct ub_pass_cache *pool;
  uint32_t *pool_texels, *pool_probes; /* the rows written: act texels, subset probes */
  uint32_t pool_ntexels, pool_nprobes, pool_T, pool_P, pool_LP, pool_keep;
} ub_pass_result;

/* Adaptive sampling's round cap: 16 rounds = 16× the base rays at most, per bounce. */
#define UB_ADAPT_MAX_ROUNDS 16
/* Relative error of a receiver: se / max(E, UB_ERR_FLOOR × mean E over the set's lit
 * receivers), so that receivers in near darkness (where nothing is visible) neither
 * dominate the statistics nor take all the adaptive rays. */
#define UB_ERR_FLOOR 0.1
/* Lit: E above this share of the mean (as the bounce auto-stop counts texels). */
#define UB_ERR_LIT 1e-3

/* UB_ERR_FLOOR × the mean of e[0..n) (non-finite entries count as 0): the floor of
 * ub_rel_error. */
double ub_err_floor(const float *e, uint32_t n);
static inline double ub_rel_error(double se, double e, double floor)
{
  double den = e > floor ? e : floor;
  return den > 0.0 ? se / den : 0.0;
}

ub_result ub_pass_run(const ub_pass_desc *desc, const ub_log *log, ub_pass_result *out_result);
void ub_pass_result_free(ub_pass_result *r);
/* As ub_pass_result_free, but a subset pass's outputs go back to the cache they came
 * from (r->pool) for the next pass: the caller must not have written them outside the
 * pass's subsets (texels, GLG probes; LLG arrays are zeroed whole). Call it before that
 * cache is freed. */
void ub_pass_result_recycle(ub_pass_result *r);

#endif
