/* bake/dls.h — dynamic light sets: one pass each, limited to the receivers they reach.
 *
 * UberBake §3.1–3.2: lights tagged `ubake_dls: NAME` are left out of the base bake. Each
 * set first runs a cheap influence pass (direct light + 2 bounces, few rays); the
 * receivers it keeps are those lit directly, or whose indirect light exceeds 1% of the
 * mean indirect light of the directly lit texels (GLG probes likewise). The full-quality
 * pass then simulates only those receivers, and its result is stored as a sparse, linear
 * record (ubake/bakefile.h). A set whose lights reach nothing is reported and costs
 * nothing more. The caller owns the records (ub_dls_records_free, NULL-safe).
 */
#ifndef UBAKE_BAKE_DLS_H
#define UBAKE_BAKE_DLS_H

#include "bake/pass.h"
#include "bake/plan.h"
#include "ubake/bakefile.h"

#define UB_DLS_INFLUENCE_FRACTION 0.01 /* of the mean indirect of directly lit texels */

typedef struct ub_dls_stats {
  uint32_t sets_baked, sets_empty;
  uint64_t rays_influence, rays_full;
  double seconds_influence, seconds_full;
  uint64_t texels_kept, probes_kept;     /* summed over sets */
} ub_dls_stats;

/* base: the base pass's settings (scene, rays, lightmap, probes, sample budgets); the
 * light selection, subsets and pass ids are replaced per set. Fills out_records
 * (scene->dls_count entries, empty records for sets that reach nothing). */
ub_result ub_dls_bake(const ub_pass_desc *base, const ub_plan *plan, const ub_log *log,
                      ub_bakefile_record **out_records, ub_dls_stats *out_stats);
void ub_dls_records_free(ub_bakefile_record *records, uint32_t count);

/* Sparse atlas pixels of a record from per-texel SH (sh: texel_count × 12, read at the
 * kept texels only), dilated like the base so padding follows (no seams under bilinear
 * filtering). Fills rec->texel_count/texel_index/texel_sh; shared by DLS and door records. */
ub_result ub_dls_texel_record(const ub_lightmap *lm, const uint32_t *kept, uint32_t nkept,
                              const float *sh, ub_bakefile_record *rec);

/* Global pixel index of a texel (atlases in order, row-major). */
uint32_t ub_dls_texel_pixel(const ub_lightmap *lm, uint32_t texel);

#endif
