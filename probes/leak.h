/* probes/leak.h — GLG leak control, computed at bake time.
 *
 * Interpolating probes across a wall leaks light (a lit probe on one side brightens a dark
 * room on the other). For every tetrahedron we trace its six edges; when an edge is
 * blocked by geometry, the tet straddles a surface, and we store that surface's plane
 * (the blocking hit nearest the tet's centroid). At query time the run-time uses only the
 * corners on the query point's side of the plane (falling back to all corners if none is
 * on that side). This is a coarse, per-tet form of Iwanicki & Sloan's (2017) per-face
 * visibility: one plane per straddling tet, no rays at run time.
 *
 * Output: plane_of[t] = index into planes (4 floats: unit normal, d; n·x + d = 0) or
 * UB_GLG_NO_PLANE; tets whose planes have the same bits share one entry. The caller frees
 * both arrays.
 */
#ifndef UBAKE_PROBES_LEAK_H
#define UBAKE_PROBES_LEAK_H

#include <stdint.h>

#include "bake/rt.h"

#define UB_GLG_NO_PLANE 0xFFFFFFFFu

typedef struct ub_glg_leak {
  uint32_t plane_count;  /* distinct planes */
  uint32_t tets;         /* tets with a plane */
  float *planes;       /* plane_count × 4 */
  uint32_t *plane_of;  /* tet_count */
  uint64_t rays;
} ub_glg_leak;

ub_result ub_glg_leak_build(const ub_rt *rt, uint32_t point_count, const float *points,
                            uint32_t tet_count, const uint32_t *tets, ub_glg_leak *out);
void ub_glg_leak_free(ub_glg_leak *leak);

#endif
