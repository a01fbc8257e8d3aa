/* bake/dls.h — dynamic light sets: one pass each, limited to the receivers they reach.
 *
 * UberBake §3.1–3.2: lights tagged `ubake_dls: NAME` are left out of the base bake. Each
 * set first runs a cheap influence pass (direct light + UB_DLS_INFLUENCE_BOUNCES bounces,
 * few rays; the paper has 2); the receivers it keeps are those lit directly, or whose
 * indirect light (extrapolated past the last bounce by its geometric tail) exceeds 1% of
 * the mean indirect light of the directly lit texels. Before full passes of a fixed B ≤
 * UB_DLS_INFLUENCE_BOUNCES bounces: B influence bounces, no tail, 0.5%
 * (ub_dls_influence_bounces). GLG and LLG probes likewise: the record
 * carries the LLG probes it keeps, llg_probe_index/llg_probe_sh). The full-quality
 * pass then simulates only those receivers (the culled texels' influence-pass bounces
 * still light them: ub_pass_desc.outside_bounce_iz), and its result is stored as a sparse, linear
 * record (ubake/bakefile.h). A set whose lights reach nothing is reported and costs
 * nothing more. The caller owns the records (ub_dls_records_free, NULL-safe).
 */
#ifndef UBAKE_BAKE_DLS_H
#define UBAKE_BAKE_DLS_H

#include "bake/pass.h"
#include "bake/plan.h"
#include "ubake/bakefile.h"

#define UB_DLS_INFLUENCE_FRACTION 0.01 /* of the mean indirect of directly lit texels */
/* The same when the influence pass simulates exactly the full passes' bounces (a fixed
 * count of at most UB_DLS_INFLUENCE_BOUNCES: ub_dls_influence_bounces) and no tail. Its
 * estimate is then what the full pass computes, no longer inflated by later bounces, and
 * culling at 1% dropped 0.3-1.4% of a set's light on estate_small at 2 bounces
 * (tests/test_plan.c dls_culling, which wants < 1%); at 0.5%, texels 0.16-0.89% and LLG
 * probes up to 0.95%, too close to 1% for a test whose figure moves with any change to the
 * estimate; at 0.4%, texels 0.14-0.72%, GLG probes 0.04-0.16%, LLG probes 0-0.47%, for 4%
 * more kept texels and 1.4% more full-pass rays at ESTATE full scale (the added receivers
 * are faint: scaled rays give them few). */
#define UB_DLS_INFLUENCE_FRACTION_EXACT 0.004
/* The same for texels: they are kept on their neighbourhood's estimate as well (bake/dls.c
 * keep_estimate), which averages several of the influence pass's gathers, so a texel's
 * culling is decided on a steadier figure than a probe's and the threshold can be higher
 * for the same light dropped. estate_small at 2 bounces (tests/test_plan.c dls_culling,
 * 2026-12-05), texel record pixels over the 16 sets / the worst set's light dropped: its
 * own estimate at 0.4%: 59,841 / 0.62%; with the neighbourhood at 0.4%: 64,206 / 0.32%,
 * at 0.6%: 62,033 / 0.44%, at 0.8%: 59,339 / 0.59%. */
#define UB_DLS_TEXEL_FRACTION_EXACT 0.008
/* Full passes with scaled rays (ub_plan.dls_scaled_rays): a receiver gathers with at
 * least 2^-UB_DLS_RAY_SHIFT_MAX of the rays. A faint receiver's light can come from rare
 * bright hits (a lit wall seen through a doorway), and one such hit weighs 2^shift times
 * what it weighs at full rays: with the base pass's texel-light rule the worst texel of
 * estate_small (draft, seeds 1-6, `ubake spread`) was 5.42 at 3, 2.27 at 2 and 1.92 with
 * full rays. The sets' passes now take texel lights in every block
 * (ub_pass_desc.texel_lights_everywhere), which find those hits: 1.88 at 3, so 3 stays. */
#ifndef UB_DLS_RAY_SHIFT_MAX
#define UB_DLS_RAY_SHIFT_MAX 3u
#endif
/* Bounces of the influence pass (paper §3.2: 2) when the full passes run more bounces
 * than that or until converged (ub_dls_influence_bounces). */
#ifndef UB_DLS_INFLUENCE_BOUNCES
#define UB_DLS_INFLUENCE_BOUNCES 4u
#endif

/* Bounces the influence pass simulates before full passes of `bounces` bounces (-1: until
 * converged; ub_pass_desc.bounces): UB_DLS_INFLUENCE_BOUNCES, or the full passes' own count
 * when it is lower. With a fixed count of at most UB_DLS_INFLUENCE_BOUNCES (4 included)
 * the estimate has no tail and the threshold is UB_DLS_INFLUENCE_FRACTION_EXACT. Light
 * that only arrives after more bounces than the full pass traces is never in its
 * record, so the influence pass has no reason to follow it: with
 * --bounces 2 it runs 2 bounces, not 4, and its photons 3 segments, not 5. */
static inline uint32_t ub_dls_influence_bounces(int bounces)
{
  return bounces >= 0 && (uint32_t)bounces < UB_DLS_INFLUENCE_BOUNCES ? (uint32_t)bounces
                                                                       : UB_DLS_INFLUENCE_BOUNCES;
}

/* Reach bound (before the influence pass): a set's light can only arrive where its
 * photons can go. From each light of the set, UB_DLS_REACH_PHOTONS photons (point: the
 * sphere, spot: its outer cone, the first segment clipped at the glTF range) are traced
 * for up to `segments` segments (direct, then cosine bounces, each surviving with
 * the probability of the surface's largest albedo channel, so every photon carries the same
 * share of the set's power; as many segments as the influence pass has light transport
 * steps: direct + ub_dls_influence_bounces bounces), marking the coarse voxels their segments cross
 * and, per voxel, the facing of the surfaces they hit. A texel (looked up a quarter cell
 * out along its normal) or a probe is a candidate when a voxel within one cell of it was
 * crossed or hit (so light may leak past walls thinner than a cell: conservative). Everything else is left out of the influence
 * pass. Occlusion comes for free (photons stop at walls); what it can miss is a region
 * so dim that none of the N photons reaches it: a region receiving the share p of the
 * set's power (over every bounce, each photon path an equal share) is missed with
 * probability (1-p)^N, so a miss costs in expectation at most
 * max_p p·e^(−Np) = 1/(e·N) of the set's power per region (tests/test_plan.c measures the
 * bound against --plan all). A set with a directional light has no bound. */
#define UB_DLS_REACH_PHOTONS 16384u /* per light */
#define UB_DLS_REACH_SEGMENTS (UB_DLS_INFLUENCE_BOUNCES + 1u) /* the most segments */
#define UB_DLS_REACH_CELLS 96u      /* voxels along the level's longest side */

typedef struct ub_dls_reach {
  int unbounded;              /* every receiver is a candidate (directional light) */
  float org[3], cell;         /* grid origin (world) and voxel side (m) */
  uint32_t dim[3];
  uint8_t *mask;              /* dim[0]·dim[1]·dim[2]: bits 0-5 hit facing ±x,±y,±z; 6 crossed */
  uint8_t *near;              /* the same grid: mask OR-ed over each voxel's 3×3×3 block (or
                                 NULL when out of memory: looked up voxel by voxel) */
  uint64_t rays;              /* photon rays traced */
} ub_dls_reach;

/* Grid over [lo, hi] (the receivers' bounds; points outside are always candidates);
 * photons of the lights with enabled[l] != 0, for 1..UB_DLS_REACH_SEGMENTS segments
 * (ub_dls_influence_bounces + 1). Random numbers hash(seed, set, photon, segment): the
 * same bound for any thread count. Free with ub_dls_reach_free. */
ub_result ub_dls_reach_build(const ub_scene *scene, const ub_rt *rt, const uint8_t *enabled,
                             const float lo[3], const float hi[3], uint32_t seed,
                             uint32_t set, uint32_t segments, ub_dls_reach *out);
void ub_dls_reach_free(ub_dls_reach *r);
/* Grows the box [lo, hi] to hold p (non-finite coordinates ignored). */
void ub_dls_bounds_add(const float p[3], float lo[3], float hi[3]);
/* Candidate tests: texel t of lm (its centre and its sample points: a centre under a wall
 * junction stays where it is while the back-face fix moves its samples into the room
 * that lights them, lightmaps/layout.c); a probe (point in free space) at p. */
int ub_dls_reach_texel(const ub_dls_reach *r, const ub_lightmap *lm, uint32_t t);
/* The grid cells ub_dls_reach_texel reads for every texel (its centre and its sample
 * points, each a quarter cell out along the normal), for the reach bounds of one grid:
 * every set's bound is on the same grid (the receivers' bounds), so with this table a
 * set's candidate test is a byte read per point instead of the point's cell arithmetic
 * (at ESTATE full scale, 132 sets × 1.57 M texels: ~11 s in the plan and as much again
 * in the sets' stage). */
#define UB_DLS_CELL_OUTSIDE 0xFFFFFFFFu /* a point outside the grid: always a candidate */
typedef struct ub_dls_texel_cells {
  float org[3], cell;
  uint32_t dim[3];
  uint32_t per;  /* cells per texel: 1 + UB_TEXEL_SAMPLES, or 1 without sample points */
  uint32_t *idx; /* texel_count × per grid indices (or UB_DLS_CELL_OUTSIDE) */
} ub_dls_texel_cells;
/* Builds the table on r's grid; 0 (out zeroed) when r is unbounded or out of memory. */
int ub_dls_texel_cells_build(const ub_dls_reach *r, const ub_lightmap *lm,
                             ub_dls_texel_cells *out);
void ub_dls_texel_cells_free(ub_dls_texel_cells *tc);
/* The texels ub_dls_reach_texel finds in r (the same answers), through tc when it was
 * built on r's grid (else, or tc NULL, point by point): their count, and with out, the
 * texels themselves ascending. */
uint32_t ub_dls_reach_texels(const ub_dls_reach *r, const ub_dls_texel_cells *tc,
                             const ub_lightmap *lm, uint32_t *out);
int ub_dls_reach_point(const ub_dls_reach *r, const float p[3]);

/* One set's cost: its influence pass (with the reach bound's photons when the set traced
 * them itself) and its full pass. Zero for a set that reaches nothing. */
typedef struct ub_dls_set_stats {
  uint64_t rays_influence, rays_full;
  double seconds_influence, seconds_full;
} ub_dls_set_stats;

typedef struct ub_dls_stats {
  uint32_t sets_baked, sets_empty;
  uint64_t rays_influence, rays_full;
  double seconds_influence, seconds_full;
  uint64_t texels_kept, probes_kept;     /* summed over sets */
  uint64_t llg_probes_kept;              /* LLG probes, summed over sets */
  /* Reach bound: receivers given to the influence pass, summed over sets, and the
   * photon rays that bounded them (counted in rays_influence too). */
  uint64_t texels_candidate, probes_candidate, llg_probes_candidate;
  uint64_t texels_gathering; /* candidates that gathered in the influence passes (sparse) */
  uint64_t probes_gathering; /* GLG probes likewise */
  uint64_t llg_probes_gathering; /* LLG probes likewise */
  uint64_t rays_reach;
  double seconds_reach;
  /* Full passes' gather rays per bounce summed over kept receivers: with the scaled rays
   * (as traced at bounces 1 and 2; later bounces trace fewer, ub_pass_desc
   * bounce_full_rays), and with every receiver at the full count. */
  uint64_t gather_units, gather_units_full;
  /* Per set (scene->dls_count entries; NULL when there was no memory for them): what the
   * plan's per-set estimates are checked against (report.json, plan.passes). Freed by
   * ub_dls_stats_free. */
  ub_dls_set_stats *sets;
} ub_dls_stats;

void ub_dls_stats_free(ub_dls_stats *st);

/* base: the base pass's settings (scene, rays, lightmap, probes, sample budgets); the
 * light selection, subsets and pass ids are replaced per set. Fills out_records
 * (scene->dls_count entries, empty records for sets that reach nothing). */
ub_result ub_dls_bake(const ub_pass_desc *base, const ub_plan *plan, const ub_log *log,
                      ub_bakefile_record **out_records, ub_dls_stats *out_stats);
void ub_dls_records_free(ub_bakefile_record *records, uint32_t count);

/* Sparse atlas pixels of a record from per-texel SH (sh: texel_count × 12, read at the
 * kept texels only): the kept texels' pixels, ascending (no padding: the run-time shows
 * padding as the texel it copies). Fills rec->texel_count/texel_index/texel_sh; shared by
 * DLS, door and object records. */
ub_result ub_dls_texel_record(const ub_lightmap *lm, const uint32_t *kept, uint32_t nkept,
                              const float *sh, ub_bakefile_record *rec);
/* The same from the kept texels' own rows (sh_rows: nkept × 12, row i for kept[i]: a
 * compact store, ub_pass_desc.compact_store). */
ub_result ub_dls_texel_record_rows(const ub_lightmap *lm, const uint32_t *kept, uint32_t nkept,
                                   const float *sh_rows, ub_bakefile_record *rec);

/* Global pixel index of a texel (atlases in order, row-major). */
uint32_t ub_dls_texel_pixel(const ub_lightmap *lm, uint32_t texel);

#endif
