/* bake/geomstate.h — geometry states: which triangles exist, and how door leaves behave,
 * for the base bake and for each dynamic element's pass.
 *
 * The base state (what the base bake, every DLS pass and the lightmap layout see):
 *  - a door leaf in its closed pose (`ubake_door`) is present with its real albedo and is a
 *    lightmap receiver: the base holds the light bouncing off the closed leaf (S_C, issue
 *    5 item 3(ii)) and the leaf still blocks every path through the doorway. The door's
 *    record is S_O − S_C (doors/door.h). Exception: a leaf tagged `ubake_receiver: none`
 *    has nowhere to store S_C and stays black (albedo 0, UberBake §4.1).
 *  - a leaf in its open pose (`ubake_door_open`) is absent.
 *  - a show/hide object (`ubake_semidynamic`) is present (shown): the base is the level
 *    as designed, each object's record is lighting(shown) − lighting(hidden) and the
 *    run-time applies it with weight (v − 1) (see ubake/bakefile.h).
 * Open poses are never receivers; closed leaves never become LLG receivers.
 *
 * Other states are described by a ub_geom_state and turned into a triangle mask for
 * ub_rt_create().
 */
#ifndef UBAKE_BAKE_GEOMSTATE_H
#define UBAKE_BAKE_GEOMSTATE_H

#include <stdint.h>

#include "ubake/error.h"
#include "ubake/scene.h"

typedef struct ub_geom_state {
  const uint8_t *door_open;    /* door_count bytes, non-zero = open; NULL = all closed */
  const uint8_t *object_shown; /* object_count bytes, non-zero = shown; NULL = all shown */
} ub_geom_state;

/* Prepares a loaded scene for baking: open poses become non-receivers (logged when a node
 * had asked for a receiver kind), closed leaves lightmap receivers (pinned), and closed
 * leaves tagged `ubake_receiver: none` get a black material appended to the scene's
 * materials. out_orig_material (may be NULL) receives a triangle_count array of
 * the materials before the change (the real leaf albedo, for door passes); caller frees.
 * Idempotent per scene: call once after ub_scene_load(). */
ub_result ub_geom_prepare(ub_scene *scene, const ub_log *log, uint32_t **out_orig_material);

/* Triangle mask (triangle_count bytes, 1 = present) of a state; NULL state = the base
 * state. Returns NULL when out of memory. Caller frees. */
uint8_t *ub_geom_mask(const ub_scene *scene, const ub_geom_state *state);

/* Number of triangles of the closed leaf of door d (0 if d is out of range). */
uint32_t ub_geom_door_triangles(const ub_scene *scene, uint32_t door, int open_pose);

#endif
