/* probes/tetgen.h — Delaunay tetrahedralisation of GLG probe positions (baker side).
 *
 * Runs the `tetgen` program (Debian package tetgen 1.5) as a child process on a private
 * temporary directory (DESIGN §6: crash isolation and a clean AGPL boundary). Flags
 * "-nQzJNF": -n write .neigh, -Q quiet, -z 0-based indices, -J keep every input vertex
 * (no jettison, so .ele indices are our point indices), -N/-F skip the .node/.face output
 * we do not read. No -q/-a/-p: a plain Delaunay tetrahedralisation of the points, no
 * Steiner points (checked: every index read must be < the number of points written).
 *
 * Before running it the points are cleaned so TetGen always gets a proper 3D set:
 *   - exact and near duplicates (closer than UB_TETGEN_MERGE_REL × bounding-box diagonal)
 *     are merged into the first of them (input_to_point records where each went);
 *   - degenerate sets — one point, all collinear, all coplanar (tested relative to the
 *     diagonal, UB_TETGEN_FLAT_REL) — get 8 extra "hull" points: the corners of the set's
 *     oriented bounding box grown by 10% along its extent and lifted by 10% of the
 *     diagonal (UB_TETGEN_POINT_PAD metres for a single point) in the degenerate
 *     directions. The baker must bake these like any probe.
 * For a degenerate set TetGen gets the points in the padded box's frame with the
 * degenerate axes exactly 0 (TetGen 1.5 aborts on large exactly coplanar subsets of
 * tilted planes, e.g. x = y, but not of axis planes). If TetGen fails on the exact
 * coordinates (non-zero exit or signal) it is retried once on coordinates jittered by
 * UB_TETGEN_RETRY_JITTER × diagonal (deterministic, in double): the connectivity is
 * then used with the real positions, which may leave a few nearly flat tets.
 * After reading, the mesh is validated (indices, positive orientation, neighbour
 * symmetry and shared faces, unused points counted).
 *
 * Lifecycle: ub_tetgen_build allocates *out; ub_tetmesh_free releases it (NULL-safe).
 * Thread safety: independent calls may run concurrently (each uses its own directory).
 */
#ifndef UBAKE_PROBES_TETGEN_H
#define UBAKE_PROBES_TETGEN_H

#include <stdint.h>

#include "ubake/error.h"

#ifdef __cplusplus
extern "C" {
#endif

#define UB_TETGEN_MERGE_REL 1e-6 /* duplicate tolerance, × bounding-box diagonal */
#define UB_TETGEN_FLAT_REL 1e-6  /* collinear/coplanar tolerance, × diagonal */
#define UB_TETGEN_POINT_PAD 1.0  /* metres: half size of the box around a single point */
#define UB_TETGEN_RETRY_JITTER 1e-7 /* retry jitter, × diagonal (see ub_tetgen_build) */

typedef enum ub_tetgen_degeneracy {
  UB_TETGEN_GENERAL = 0, /* a proper 3D set: nothing added */
  UB_TETGEN_COPLANAR,
  UB_TETGEN_COLLINEAR,
  UB_TETGEN_SINGLE_POINT
} ub_tetgen_degeneracy;

typedef struct ub_tetmesh {
  uint32_t point_count; /* kept input points first, then added hull points */
  float *points;        /* point_count × 3, metres */
  uint32_t tet_count;
  uint32_t *tets;        /* tet_count × 4 point indices; det[b−a, c−a, d−a] > 0 */
  int32_t *neigh;        /* tet_count × 4: neigh[4t+i] = tet opposite corner i, −1 on hull */
  uint32_t input_count;  /* n passed to ub_tetgen_build */
  int32_t *input_to_point; /* input_count entries: mesh point each input point became */
  uint32_t merged_count; /* input points merged into an earlier one (duplicates) */
  uint32_t added_first;  /* added hull points are [added_first, point_count) */
  uint32_t added_count;
  uint32_t unused_count; /* mesh points no tet uses (TetGen merged them); 0 normally */
  uint32_t flat_tet_count; /* nearly flat tets (|6·volume| ≤ max(1e-12·lmax³,
                              8·retry_jitter·lmax²)), kept; the GLG copes with them */
  double retry_jitter;     /* metres; 0 unless TetGen failed on the exact coordinates */
  ub_tetgen_degeneracy degeneracy;
} ub_tetmesh;

typedef struct ub_tetgen_options {
  const char *program; /* NULL: "tetgen" looked up in PATH */
} ub_tetgen_options;

/* points: n × 3 floats (metres), all finite, n ≥ 1. On success *out is a validated mesh.
 * Errors: UB_ERR_INVALID_ARGUMENT (n = 0, NULL), UB_ERR_INVALID_DATA (non-finite point,
 * named by index), UB_ERR_IO (temp directory), UB_ERR_OUT_OF_MEMORY, UB_ERR_EXTERNAL
 * (tetgen could not run, exited non-zero, was killed, or wrote invalid output; one
 * message says which). Never aborts. */
ub_result ub_tetgen_build(const float *points, uint32_t n, const ub_log *log,
                          ub_tetmesh **out);
ub_result ub_tetgen_build_ex(const float *points, uint32_t n,
                             const ub_tetgen_options *options, const ub_log *log,
                             ub_tetmesh **out);

/* Checks the invariants listed above (used after reading; also handy in tests).
 * Returns UB_OK or UB_ERR_INVALID_DATA with a message naming the tet. */
ub_result ub_tetmesh_validate(const ub_tetmesh *mesh, const ub_log *log);

void ub_tetmesh_free(ub_tetmesh *mesh);

#ifdef __cplusplus
}
#endif
#endif
