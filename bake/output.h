/* bake/output.h — the bake's last stage: encode and write every output file.
 * Writes DIR/NAME.ubk, DIR/NAME_lm<i>.exr (AHD, half), DIR/NAME_lm<i>.png (irradiance
 * preview) and the report, all staged and renamed into place only on success. */
#ifndef UBAKE_BAKE_OUTPUT_H
#define UBAKE_BAKE_OUTPUT_H

#include "bake/pass.h"
#include "bake/dls.h"
#include "bake/plan.h"
#include "probes/leak.h"
#include "probes/llg.h"
#include "probes/tetgen.h"

/* The GLG as baked: mesh, radiance SH L2 per mesh point, leak planes. */
typedef struct ub_glg_bake {
  const ub_tetmesh *mesh;
  const float *sh;
  const ub_glg_leak *leak;
} ub_glg_bake;

/* llg: the LLG models (or NULL) and llg_sh their probes' SH (llg->probe_count × 27).
 * elems: door, object and combination records (or NULL), kinds in the order of
 * ubake/bakefile.h. tri_material: the materials to show (door leaves keep their own
 * albedo in the file although the base bake saw them black), NULL = the scene's. */
ub_result ub_output_write(const ub_scene *scene, const ub_lightmap *lm, const ub_glg_bake *glg,
                          const ub_llg_set *llg, const float *llg_sh,
                          ub_bakefile_record *dls, const ub_dls_stats *dstats,
                          ub_bakefile_record *elems, uint32_t elem_count,
                          const uint32_t *tri_material, const ub_plan *plan,
                          const ub_pass_result *base, const ub_bake_options *opt,
                          ub_bake_stats *stats, const ub_log *log);

long ub_peak_rss_kb(void);
/* A /proc/self/status line's kB (key with its colon: "VmRSS:", "VmHWM:"), -1 if absent. */
long ub_proc_status_kb(const char *key);
/* Resets the kernel's peak resident set (VmHWM) to the current one; 0 if it cannot. */
int ub_peak_rss_reset(void);

#endif
