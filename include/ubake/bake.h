/* ubake/bake.h — bake a glTF level into DIR/NAME.ubk, lightmap EXRs/PNGs and a report.
 *
 * ub_bake_level() runs the whole bake as a script of named stages:
 *   load → rays → receivers → plan → passes (series expansion) → encode → write
 * Each stage reports progress through the callback (which may cancel) and its counters
 * in ub_bake_stats. Outputs are written to temporary names and renamed, so a failed or
 * cancelled bake leaves no partial output files.
 * Thread safety: one bake per call; the bake itself is multi-threaded (OpenMP). The
 * progress and log callbacks are called from one thread at a time.
 */
#ifndef UBAKE_BAKE_H
#define UBAKE_BAKE_H

#include <stdint.h>

#include "ubake/error.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef enum ub_quality {
  UB_QUALITY_DRAFT = 0,
  UB_QUALITY_FAST,
  UB_QUALITY_HIGH
} ub_quality;

/* Progress: stage name ("direct", "bounce 2", ...), fraction of the stage done in [0,1],
 * and of the whole bake (estimated). Return non-zero to cancel (UB_ERR_CANCELLED). */
typedef int (*ub_progress_fn)(void *user, const char *stage, double stage_fraction,
                              double total_fraction);

typedef struct ub_bake_options {
  ub_quality quality;
  int bounces;            /* indirect bounces; -1 = until a bounce adds < 0.5% energy */
  int threads;            /* 0 = all cores */
  uint32_t seed;
  const char *out_dir;    /* DIR of DIR/NAME.ubk, NAME_lm<i>.exr, ...; NULL = ".". NAME is
                             the level's file name without its extension, at most 63 bytes
                             (a longer one is refused). Checked and created (with missing
                             parents) when the bake starts, before the first stage (not with
                             plan_only). Files are written into DIR/.NAME.staging-PID and
                             renamed into place only when all of them are: a failed or
                             cancelled bake leaves nothing (nor does one SIGINT or SIGTERM
                             stops, where their action is the default): the staging folder
                             and the empty folders it created are removed; earlier files in
                             DIR stay. A bake killed outright leaves its staging folder;
                             the next bake of NAME into DIR removes it. */
  const char *json_path;  /* report path; NULL = DIR/NAME.report.json. Its folder must
                             exist: checked (a temporary file is made next to it) when the
                             bake starts, before the first stage; the report is renamed into
                             place only when the bake succeeds, and a failed bake removes the
                             temporary file */
  uint32_t gather_rays;   /* 0 = from quality: rays per receiver per bounce */
  float texel_size;       /* 0 = from the level (metres per texel) */
  float glg_spacing;      /* 0 = from the level (metres between coarse GLG probes) */
  uint32_t glg_max_cells; /* 0 = 262,144: cells at the GLG spacing holding surfaces that the
                             placement takes before it widens the spacing (a warning) */
  int plan_all;           /* 1: force every effect on, no culling (to check the plan) */
  int plan_only;          /* 1: stop after printing the plan; write nothing */
  double target_error;    /* > 0: adaptive sampling to this relative standard error per
                             texel / GLG probe (e.g. 0.02), at most 16× the rays per bounce;
                             0 = off (the base pass only) */
  int door_no_guiding;    /* 1: door passes gather with cosine rays only (for comparison) */
  int influence_dense;    /* 1: DLS influence passes gather at every candidate texel
                             (default 0: one gather per 2×2 texels of a surface; for
                             comparison) */
  int dls_full_rays;      /* 1: DLS full passes give every kept receiver the full gather
                             rays (default 0: rays scaled down where the set's estimated
                             light is under half its mean on directly lit texels, to 1/8
                             at most; for comparison) */
  int bounce_full_rays;   /* 1: every bounce gathers with the full rays (default 0: from
                             bounce 3 on, fewer where a receiver's light has faded below
                             its brightest bounce, to 1/4 at most; for comparison) */
  uint32_t door_rays;     /* 0 = from quality: guided gather rays per texel of a door pass */
  ub_progress_fn progress;
  void *progress_user;
} ub_bake_options;

#define UB_BAKE_MAX_BOUNCES 64
#define UB_BAKE_MAX_STAGES 16

typedef struct ub_bake_stats {
  char level_name[64];
  uint32_t triangles, lights, emissive_triangles;
  uint32_t atlases, texels, backface_fixes;
  uint32_t glg_probes, glg_tets, glg_leak_tets;
  uint32_t llg_auto_nodes;               /* untagged small props made LLG receivers */
  uint32_t dls_sets;                     /* dynamic light sets baked */
  uint32_t door_passes;                  /* door passes run (0: no door code ran) */
  uint64_t rays_emissive, sky_hits, emitter_hits; /* effect counters of the base pass */
  uint32_t bounces;                      /* indirect bounces baked */
  double bounce_energy[UB_BAKE_MAX_BOUNCES + 1]; /* Σ luminance(E) per bounce, 0 = direct */
  double bounce_cap_tail;  /* > 0: the bounce cap ended the series; the energy still missing
                              (geometric tail) as a fraction of the total */
  uint64_t rays_total, rays_gather, rays_shadow;
  double gather_seconds;                 /* wall seconds spent in gather passes */
  uint64_t rays_adaptive;                /* rays of the adaptive rounds (target_error) */
  double texel_rel_se_mean, texel_rel_se_p95; /* estimated relative standard error, lit
                                                 texels (report.json: error_estimate) */
  uint32_t stage_count;
  char stage_name[UB_BAKE_MAX_STAGES][24];
  double stage_seconds[UB_BAKE_MAX_STAGES];
  double total_seconds;
  uint64_t clamped_values;               /* non-finite or negative values clamped, and values
                                            clamped to the half range in the .ubk */
  uint64_t backface_hits;                /* gather rays that hit the back of a surface */
  uint64_t unlit_hits;                   /* gather rays that hit a surface with no receiver */
  long peak_rss_kb;
  char ubk_path[1024];
} ub_bake_stats;

void ub_bake_options_default(ub_bake_options *out_options);
const char *ub_quality_name(ub_quality q);
/* The quality named "draft", "fast" or "high" into *out: 1, or 0 (out untouched). */
int ub_quality_from_name(const char *name, ub_quality *out);

ub_result ub_bake_level(const char *level_path, const ub_bake_options *options,
                        const ub_log *log, ub_bake_stats *out_stats);

#ifdef __cplusplus
}
#endif
#endif
