/* probes/placement.h — where the global light grid (GLG) puts its probes.
 *
 * A coarse lattice at the level's GLG spacing, its points kept within a cell of a surface,
 * plus the 8 corners of the bounds (so every point of the level lies inside the probes'
 * hull, and empty space far from any surface gets no probes); cells that hold surfaces get
 * a lattice twice as fine (adaptive: probes are denser near geometry, where lighting
 * changes). Only occupied cells and their neighbours are stored, so a huge level keeps
 * its spacing (up to 2^20 cells per axis). Candidates inside solid geometry (most of
 * their probe rays hit back faces) are dropped. Deterministic: candidates are generated
 * and filtered in lattice order. The caller owns out->pos (free with ub_glg_points_free,
 * NULL-safe).
 */
#ifndef UBAKE_PROBES_PLACEMENT_H
#define UBAKE_PROBES_PLACEMENT_H

#include <stdint.h>

#include "bake/rt.h"
#include "lightmaps/lightmap.h"

typedef struct ub_glg_points {
  uint32_t count;
  float *pos;               /* count × 3 */
  uint32_t coarse, fine;    /* candidates kept from each lattice */
  uint32_t rejected_inside; /* candidates inside solid geometry */
  float spacing;            /* metres, coarse lattice */
} ub_glg_points;

/* spacing: metres between coarse probes (> 0). Surfaces are taken from the lightmap
 * texels (every lightmapped surface) and the triangles' vertices. max_occupied bounds the
 * cells (at the spacing) that hold surfaces: with more, the spacing widens until they fit,
 * with a warning (0: no bound; the bake passes ub_bake_options.glg_max_cells, by default
 * UB_GLG_MAX_OCCUPIED_DEFAULT, 9× the full ESTATE-scale level's 27,909). */
#define UB_GLG_MAX_OCCUPIED_DEFAULT 262144u
ub_result ub_glg_place(const ub_scene *scene, const ub_rt *rt, const ub_lightmap *lm,
                       float spacing, uint32_t max_occupied, const ub_log *log,
                       ub_glg_points *out);
void ub_glg_points_free(ub_glg_points *pts);

#endif
