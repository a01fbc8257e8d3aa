/* doors/object.h — show/hide objects (`ubake_semidynamic`): sparse records of what each
 * object changes, baked by a guided series expansion over its influence region only.
 *
 * Default state baked into the base: every object SHOWN (the level as designed, see
 * bake/geomstate.h). An object's record is D = L(shown) − L(hidden), everything else as
 * in the base; the run-time applies it with weight (v − 1), v ∈ [0,1] its visibility.
 *
 * Formulation. With L_s = E_s + K_s(L_s + P_s) the stored base lighting (K_s: a final
 * gather in the shown geometry, P_s: primary lights' direct light at the gathered hits,
 * never stored) and the same in the hidden geometry, D satisfies
 *     D = T + K_h D,   T = (E_s − E_h) + K_s(L_s + P_s) − K_h(L_s + P_h)
 * T is first order and reads only the base: static lights' direct light the object
 * blocks at the receiver (shadow rays whose segment meets the object's box, traced in
 * both states), gather rays that hit the object in the shown state (object's stored
 * radiance + primary NEE there, minus what the same ray sees without it: stored radiance
 * of the hidden hit + primary NEE, or sky), and for rays that hit the same point in both
 * states the change of primary NEE at that hit (again only if the shadow segment meets
 * the box). Rays that miss the box contribute exactly zero, so T has no noise away from
 * the object. K_h D is iterated (series expansion, gather in the hidden geometry reading
 * the previous iterate) until a bounce adds < stop_fraction. T's gather is guided toward
 * the object's OBB and mixed with cosine (sphere for probes) by one-sample MIS, balance
 * heuristic (doors/guide.h), so the rare rays that see a small object are many.
 *
 * Influence region (receivers outside are never touched and the record is 0 there): a
 * texel or GLG probe is a candidate when the segment from it to any light of the pass
 * crosses the object's box (it can be in the object's shadow), or when the box is within
 * UB_OBJ_REACH of it (max(UB_OBJ_REACH_MIN, UB_OBJ_REACH_SIZE × the box's half diagonal)
 * from the box centre, plus the half diagonal) and a box corner lies above the texel's
 * horizon (it can see the object). The object's own texels are never in its record.
 * After the pass a candidate is kept when |D| (luminance) > UB_OBJ_KEEP × its base
 * lighting. LLG probes are receivers of the object's own record (candidates like GLG
 * probes, rays against the level without LLG models, kept like GLG probes against the
 * base grid; not for an object that is itself an LLG model); pair and set × object
 * combinations have none. Not simulated: gather hits on LLG-lit models (read as 0).
 *
 * Combinations (kind UB_ELEMENT_COMBO, appended after the objects):
 *  - pairwise shadow correction (paper Fig. 17): for objects a, b whose records overlap
 *    in their shadow parts: at least UB_OBJ_PAIR_MIN_TEXELS texels of a's region from
 *    which a base light's segment crosses both boxes (a first try, Σ_common
 *    min(|D_a|,|D_b|) over the whole records, paired every object in a room: the
 *    bounce-light parts overlap everywhere but their products are tiny), C_ab = D_a − D_a|b hidden = L11 − L10 − L01 + L00, baked with the same
 *    random numbers as D_a (correlated, so the difference has little noise), applied with
 *    (v_a − 1)(v_b − 1);
 *  - set × object: for each dynamic light set whose lights cast into an object's region
 *    (same candidate rule with the set's lights), S_set(shown) − S_set(hidden) with the
 *    set's lights and the set's stored lighting as L_s, applied with w_set · (v − 1).
 * A combination keeps the receivers where |C| > UB_OBJ_KEEP_COMBO × (base + set) there,
 * and is dropped when none is left. (A first rule, Σ|C| > 1% of the set's light in the
 * region, dropped candles × barrel_1 at 0.96%: −17% beside the barrel; at 0.1% the 8 × 8
 * variant of inn kept 64 set × object records, 3.7× the storage.)
 */
#ifndef UBAKE_DOORS_OBJECT_H
#define UBAKE_DOORS_OBJECT_H

#include "bake/pass.h"
#include "bake/plan.h"
#include "ubake/bakefile.h"

#define UB_OBJ_REACH_MIN 2.0f     /* metres */
#define UB_OBJ_REACH_SIZE 6.0f    /* × the object's box half diagonal */
#define UB_OBJ_KEEP 2e-3          /* of the receiver's base lighting (luminance) */
#define UB_OBJ_PAIR_MIN_TEXELS 8 /* texels in both objects' shadows (base lights) */
#define UB_OBJ_KEEP_COMBO 0.01   /* combinations: of base (+ the set) at the receiver */
#define UB_OBJ_MAX_ITER 4         /* iterations of K_h D after the first order */
#define UB_OBJ_GUIDE_COSINE 0.5   /* share of cosine/sphere rays in the guided gather */

typedef struct ub_object_stats {
  uint32_t objects, objects_baked, pairs, set_objects;
  uint64_t rays, texels_kept, probes_kept;
  double seconds;
} ub_object_stats;

/* base: the base pass's settings (scene, rays = base geometry, lightmap, probes, sample
 * budgets, light selection); base_res: its result (stored texel irradiance, probe SH);
 * dls: the sets' records (scene->dls_count, may be NULL when there are none). Appends
 * object records, then combinations, to *io_elems (realloc'd; parents use the numbering
 * [sets, then elems]), so call it after any door records are in. Logs one line per
 * record. */
ub_result ub_object_bake(const ub_pass_desc *base, const ub_plan *plan,
                         const ub_pass_result *base_res, const ub_bakefile_record *dls,
                         const ub_log *log, ub_bakefile_record **io_elems, uint32_t *io_count,
                         ub_object_stats *out_stats);

/* Per-texel irradiance along the normal (out: texel_count × 3, W/m²) and SH (out_sh:
 * texel_count × 12) of a sparse record (its pixel SH read at each texel's pixel; 0 where
 * the record has none). */
void ub_record_texel_iz(const ub_lightmap *lm, const ub_bakefile_record *rec, float *out,
                        float *out_sh);

/* Appends n records (moved: the caller must not free their arrays) to an element array. */
ub_result ub_records_append(ub_bakefile_record **io_elems, uint32_t *io_count,
                            const ub_bakefile_record *add, uint32_t n);

#endif
