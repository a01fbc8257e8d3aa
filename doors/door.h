/* doors/door.h — the door pass: what a door changes in the base when it opens (UberBake
 * §4, with the closed-door bounce of its §6.2).
 *
 * The base bake sees every closed leaf with its albedo, lightmapped (bake/geomstate.h): no
 * base path crosses it, light bounces off it (S_C). A door's record is
 * S_O − S_C = lighting(this door open) − lighting(base). Formulation (per door, other
 * doors closed):
 *   rt_open = the base geometry − this closed leaf + this leaf's open pose (if any);
 *   rt_leaf = this closed leaf alone.
 * A ray segment "crosses the door" when rt_leaf intersects it. What a crossing ray adds is
 * what it sees open minus what it saw on the leaf:
 *   beyond − leaf = [albedo/π × (stored irradiance at the first open-geometry hit X,
 *   bilinear from the base lightmap, + primary lights' direct light at X) + emission, or
 *   the sky on a miss] − [albedo/π × (the leaf's stored irradiance + primary direct) +
 *   emission at the leaf hit].
 * At each receiver x:
 *  (a) through the door, L_x D* P R (and −S_C's first bounce): gather rays that cross;
 *  (b) one bounce, L_x P D R: gather rays that hit D take albedo/π × E(D), E = light at D
 *      that crosses the door: punctual lights (shadow ray crosses the leaf, open geometry
 *      clear) + one portal sample of beyond − leaf. D beyond the door (a crossing ray,
 *      with (a) as well) is light that crossed and comes back; its punctual lights that
 *      (a) took already are left out;
 *  (c) static punctual lights at x whose shadow ray crosses the door (primary lights'
 *      direct light is the game's);
 *  then further receiver-side bounces (series expansion over the kept texels).
 * (a) and (b) share one set of gather rays from one guide mixture (doors/guide.h):
 * cosine (uniform sphere for probes) + the portal box (the closed leaf's OBB) + up to
 * UB_DOOR_MAX_BOXES boxes around the shadow photons (points of the receiver side lit
 * through the door), one-sample MIS with the balance heuristic. Records are signed.
 * Receivers: texels (not the door's own leaf: it keeps its closed lighting), GLG probes
 * and LLG probes (rays against the level without LLG models, door open, as the LLG pass).
 * Not simulated: the shadow the open leaf casts on paths that never cross the doorway, the
 * leaf's far-side bounce in the stored light beyond (gone when open), stored base light on
 * geometry without a lightmap (LLG models, the open leaf): there only the direct light of
 * the lights that reach the portal, and emission. Since 2026-11-27 further bounces read
 * rays through the doorway too (they added 0: light that crosses into the far room and
 * comes back was missing).
 *
 * Influence region: a cheap version of the pass (influence_rays, one shadow sample) over
 * every receiver; one is kept when |luminance| exceeds UB_DOOR_INFLUENCE_FRACTION × the
 * mean over the receivers it reached (texels, GLG and LLG probes each with their own
 * mean). Only kept receivers are simulated at full quality and stored.
 *
 * Determinism: random numbers are ub_hash4 of (seed, pass, receiver, sample).
 * Ownership: the caller frees the records with ub_dls_records_free (bake/dls.h).
 */
#ifndef UBAKE_DOORS_DOOR_H
#define UBAKE_DOORS_DOOR_H

#include <stdint.h>

#include "bake/pass.h"
#include "bake/plan.h"
#include "doors/guide.h"
#include "ubake/bakefile.h"

#define UB_DOOR_MAX_BOXES 12              /* photon clusters (paper: 12) */
#define UB_DOOR_INFLUENCE_FRACTION 0.01   /* of the mean over the receivers reached */
#define UB_DOOR_BOX_MARGIN 0.15f          /* metres: photon boxes inflated (light lists) */

typedef struct ub_door_desc {
  const ub_pass_desc *base;          /* the base pass: scene, rt, lightmap, probes, seed */
  const ub_pass_result *base_result; /* its stored irradiance (iz) at every texel */
  uint32_t rays;                     /* gather rays per texel (probes: 2×) */
  uint32_t influence_rays;           /* per texel in the influence pass (0: no culling) */
  uint32_t photons;                  /* shadow photon attempts per door */
  int guiding;                       /* 1: portal + photon boxes + cosine (MIS); 0: cosine */
  /* Optional diagnostics: texel_count × 3 irradiance along the normal (W/m²) of door
   * debug_door's record, before dilation (0 outside its influence). */
  float *debug_texel_iz;
  uint32_t debug_door;
} ub_door_desc;

typedef struct ub_door_stats {
  uint32_t doors_baked, doors_empty;
  uint32_t photons_deposited, boxes;     /* summed over doors */
  uint64_t rays_influence, rays_full, rays_photons;
  double seconds_influence, seconds_full;
  uint64_t texels_kept, probes_kept, llg_probes_kept;
  uint32_t combos_baked, combos_skipped; /* door × set combinations (ub_door_combine) */
} ub_door_stats;

/* One record per door (scene->door_count, kind UB_ELEMENT_DOOR, named after the door,
 * parents -1; empty for a door without closed-leaf triangles). */
ub_result ub_door_bake(const ub_door_desc *dd, const ub_log *log,
                       ub_bakefile_record **out_records, ub_door_stats *out_stats);

/* Combinations (issue 5 item 4; the paper's Fig. 9): for each candidate in plan->combos
 * (a set or a door named by the door's `ubake_combine` tag) whose influence region
 * overlaps the door's (the two records share a texel pixel, a GLG probe or an LLG probe),
 * bakes the product correction C = L(both) − L(door only) − L(other only) + L(neither):
 *  - door × set: C = L_set(open) − L_set(closed), the door pass with the set's lights and
 *    the set's stored lighting (its record) in place of the base's; parents (set,
 *    dls_count + door), applied with w_set · t;
 *  - door a × door b: C = S_a|b open − S_a, door a's pass in the state "b open" (b's leaf
 *    gone, its open pose in, stored lighting base + b's record) with its own influence,
 *    minus the same pass in the base state over the same receivers with the same random
 *    numbers (correlated); parents (dls_count + a, dls_count + b), applied with t_a · t_b.
 * One COMBO record each. *io_elems must start with the door_count door records of
 * ub_door_bake (in order); call it after the objects (combinations come last in the
 * element list). Fills each combo's baked/why and logs one line per candidate. */
ub_result ub_door_combine(const ub_door_desc *dd, ub_plan *plan,
                          const ub_bakefile_record *dls, const ub_log *log,
                          ub_bakefile_record **io_elems, uint32_t *io_count,
                          ub_door_stats *io_stats);

#endif
