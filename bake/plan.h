/* bake/plan.h — what the bake simulates, decided before any gather ray is traced.
 *
 * The plan lists the light classes present (sky, emissive triangles, static and primary
 * punctual lights), the passes to run and their sample budgets, and every light it skips
 * with the reason. It is printed and written to the report. Owned by the caller:
 * ub_plan_free() releases its arrays (safe on a zeroed plan).
 */
#ifndef UBAKE_BAKE_PLAN_H
#define UBAKE_BAKE_PLAN_H

#include <stdint.h>

#include "bake/lights.h"
#include "bake/rt.h"
#include "lightmaps/lightmap.h"
#include "ubake/bake.h"

typedef enum ub_light_skip {
  UB_SKIP_NONE = 0,
  UB_SKIP_DARK,          /* zero intensity */
  UB_SKIP_OUT_OF_RANGE,  /* no receiver inside its range / cone */
  UB_SKIP_IN_DLS         /* baked in its dynamic light set's pass, not the base */
} ub_light_skip;

/* A combination the level asks for (`ubake_combine` on a door's closed leaf, README):
 * door × set or door × door, baked as one product-correction record when the two
 * influence regions overlap (doors/door.h, ub_door_combine). Neither a set nor another
 * door (or a pair already listed): never baked, `why` says so. */
typedef struct ub_plan_combo {
  uint32_t door;    /* the tagged door */
  int32_t set;      /* dynamic light set, -1 = the name is not a set */
  int32_t other;    /* the other door of a door × door pair, -1 = none */
  char name[64];    /* the name as tagged */
  int baked;        /* set by the door-combination stage: 1 baked, 0 skipped */
  char why[192];    /* reason, for the log and the report */
} ub_plan_combo;

typedef struct ub_plan {
  int forced;                  /* --plan all: every effect on, no culling (for checking) */
  uint32_t pass_count;
  uint8_t *base_light_enabled; /* light_count */
  uint8_t *light_skip;         /* light_count: ub_light_skip */
  uint8_t *dls_light_reaches;  /* light_count: a DLS light that can reach a receiver */
  float *light_reach;          /* light_count: share of texels it can shine on (no occlusion) */
  uint32_t base_lights, skipped_lights;
  uint32_t static_lights, primary_lights, dls_lights;
  int sky, emissive;
  int influence_culling;       /* DLS full passes only over their influence region */
  int influence_sparse;        /* influence passes gather at one texel per 2×2 of a surface */
  int dls_scaled_rays;         /* DLS full passes: fewer gather rays where a set's light is
                                  faint (bake/dls.h UB_DLS_RAY_SHIFT_MAX) */
  double stop_fraction;        /* a pass stops when a bounce adds less than this share */
  uint32_t gather_rays, emissive_samples, shadow_samples;
  uint32_t near_samples; /* footprint samples of a lamp near a texel (ub_pass_desc) */
  uint32_t probe_rays;         /* full-sphere gather rays per GLG probe per bounce */
  uint32_t influence_rays;     /* gather rays per texel of a DLS influence pass */
  uint32_t dls_passes;         /* sets with at least one light that reaches a receiver */
  double est_rays;             /* estimated rays of the base pass */
  double *dls_est_rays;        /* dls_count: estimated rays per set (0 = skipped) */
  /* dls_count: estimated seconds per set: its influence pass's rays at
   * UB_PLAN_INFLUENCE_RATE × ray_rate and its full pass's at UB_PLAN_FULL_RATE × ray_rate
   * (the reach bound's photons are the plan's own time, dls_reach_seconds) */
  double *dls_est_seconds;
  /* dls_count: share of the level's texels inside the set's reach bound (bake/dls.h), the
   * receivers its influence pass will see (1 without culling); probes are estimated at
   * the same share. */
  double *dls_candidates;
  /* dls_count reach bounds (bake/dls.h) traced by the plan and reused by the sets' passes
   * (NULL without culling); dls_reach_count entries, freed by ub_plan_free. */
  struct ub_dls_reach *dls_reach;
  uint32_t dls_reach_count;
  double dls_reach_seconds;    /* the sets' lights' light_reach and tracing the bounds and
                                  counting their candidates: the sets' work, done here */
  double ray_rate;             /* measured rays/s on this level, all threads */
  double bounce_ratio;         /* mean albedo a cosine gather ray finds (misses count 0) */
  uint32_t est_bounces;        /* bounces the estimates assume (ub_plan_bounces when auto) */
  /* Doors (doors/door.h): one pass per door with a closed leaf; none without doors. */
  uint32_t doors, door_passes;
  uint32_t door_rays;          /* guided gather rays per texel of a door pass (probes 2x) */
  uint32_t door_influence_rays; /* per texel of its influence pass (0: no culling) */
  uint32_t door_photons;       /* shadow photon attempts per door */
  uint32_t combo_count;        /* tagged door × name pairs, in door then tag order */
  ub_plan_combo *combos;
} ub_plan;

ub_result ub_plan_build(const ub_scene *scene, const ub_rt *rt, const ub_emitters *em,
                        const ub_lightmap *lm, uint32_t probe_count,
                        const ub_bake_options *opt, const ub_log *log, ub_plan *out_plan);
/* Prints the plan, one line per pass and per skipped light with the reason. */
void ub_plan_print(const ub_plan *plan, const ub_scene *scene, const ub_log *log);
void ub_plan_free(ub_plan *plan);
const char *ub_light_skip_reason(ub_light_skip s);

/* Bounces an auto-stop pass runs when each bounce brings back the share `ratio` of the
 * last and the pass stops once a bounce adds <= stop_fraction of the indirect light so
 * far (bake/pass.c); at most cap. */
uint32_t ub_plan_bounces(double ratio, double stop_fraction, uint32_t cap);
/* The full-ray bounces that `bounces` bounces of gathers cost when later bounces trace
 * fewer rays (ub_pass_desc.bounce_full_rays = 0; full_rays: they do not, = bounces). A
 * receiver's bounce k − 1 brings r^(k−2) of its bounce 1, so bounce k ≥ 3 would gather
 * with rays >> ⌊(k − 2)·log2(1/r)⌋ (at most UB_BOUNCE_RAY_SHIFT_MAX); the estimate takes
 * half that shift, for the receivers whose light peaks late (rooms lit through doorways:
 * estate_small's base pass saved 20% of its gathers, its sets 45%, oa_dm4 32%). */
double ub_plan_gather_bounces(double ratio, uint32_t bounces, int full_rays);

#endif
