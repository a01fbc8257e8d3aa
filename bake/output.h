/* bake/output.h — the bake's output folder and its last stage: encode and write every file.
 * Writes DIR/NAME.ubk, DIR/NAME_lm<i>.exr (AHD, half), DIR/NAME_lm<i>.png (irradiance
 * preview), DIR/NAME_error<i>.exr/.png and the report, all staged and renamed into place
 * only on success (the folder, its staging and the signal cleanup: bake/outdir.h).
 * Lifecycle: ub_output_open() before the bake's first stage (creates DIR and the staging
 * folder DIR/.NAME.staging-PID, so a bad output folder fails at once), ub_output_write()
 * as the last stage (writes everything, then renames it into place), ub_output_close()
 * always (removes what a bake that did not finish left: the staging folder, the report's
 * temporary file, the folders open created if they are still empty).
 * Signals: while a bake is open, SIGINT and SIGTERM (when their action was the default)
 * first remove the staging folder and the folders open created, then kill the process as
 * before. One bake per process gets this (the first open one): a handler reaches no context.
 * Thread safety: one ub_output per bake; open, write and close from the bake's thread. */
#ifndef UBAKE_BAKE_OUTPUT_H
#define UBAKE_BAKE_OUTPUT_H

#include <stdio.h>

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

typedef struct ub_output ub_output;

/* s as a JSON string to f: quoted, with quotes, backslashes and control bytes escaped (the
 * report's and `ubake info --json`'s names come from the level's tags). NULL: "". */
void ub_json_write_str(FILE *f, const char *s);

/* Prepares the output of a bake of level_name (DIR/NAME.*; at most 63 bytes, no '/'):
 * creates opt->out_dir ("." when NULL) and the staging folder, removes stale staging
 * folders of NAME whose process is gone (an info line each), and with opt->json_path
 * creates the report's temporary file next to it (DIR_J/.BASE.tmp-PID), so that every
 * step of the write stage that can fail is known to work before the bake's first stage.
 * A --json path naming one of the bake's own files in the output folder (NAME.ubk,
 * NAME_lm<i>, NAME_error<i>) is refused. On failure: one error message naming the folder
 * (or --json path) and the cause, nothing left behind, *out = NULL. */
ub_result ub_output_open(const char *level_name, const ub_bake_options *opt, const ub_log *log,
                         ub_output **out);

/* Removes what out holds that was not moved into place (after a successful write: only the
 * then empty staging folder), restores SIGINT/SIGTERM and frees out. NULL-safe. Output
 * folders open created stay when they hold anything (a failed bake's empty output folder
 * is removed; one holding earlier files is not touched). */
void ub_output_close(ub_output *out);

/* The write stage. llg: the LLG models (or NULL) and llg_sh their probes' SH
 * (llg->probe_count × 27). elems: door, object and combination records (or NULL), kinds in
 * the order of ubake/bakefile.h. tri_material: the materials to show (door leaves keep
 * their own albedo in the file although the base bake saw them black), NULL = the scene's.
 * Every file is written into the staging folder (the report into its temporary file) before
 * the first is renamed into place; then the same level's NAME_lm<i> and NAME_error<i>
 * (.exr, .png) for i at or past the new atlas count, left by an earlier bake with more
 * atlases, are removed. Messages name the final paths, not the staging ones. */
ub_result ub_output_write(ub_output *out, const ub_scene *scene, const ub_lightmap *lm,
                          const ub_glg_bake *glg, const ub_llg_set *llg, const float *llg_sh,
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
