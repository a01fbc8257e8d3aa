/* ubake/scene.h — a level as plain C arrays, loaded from glTF 2.0 (.gltf or .glb).
 *
 * What it is: the flattened, world-space level the baker works on. Every mesh primitive
 * instance is transformed to world space (metres, Y-up) and appended to one triangle soup;
 * triangles keep their material and the node they came from. Lights, tagged nodes and the
 * level's settings (DESIGN §3, §4) are resolved here; nothing downstream knows glTF.
 *
 * Lifecycle: ub_scene_load() fills a ub_scene it allocates; ub_scene_free() releases it
 * (NULL-safe). On failure nothing is allocated and *out_scene is left untouched.
 * Ownership: the scene owns all arrays. Thread safety: a loaded scene is read-only and may
 * be shared by any number of threads.
 */
#ifndef UBAKE_SCENE_H
#define UBAKE_SCENE_H

#include <stddef.h>
#include <stdint.h>

#include "ubake/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/* World coordinates beyond ±this (metres: 10,000 km, where float spacing is 1 m) are
 * rejected by the loader (vertices, lights) and by what takes points in the level
 * (reference paths, queries): products of such coordinates (extents, cross products)
 * overflow float, and from ~1.8e18 Embree rejects the rays outright. */
#define UB_SCENE_MAX_COORDINATE 1e7
/* A light's colour × intensity (W/sr for point and spot lights, W/m² for directional) and
 * a material's emission, per channel, beyond this are rejected: a million times the sun
 * at a metre still fits, while the bake's sums of such values over many paths would leave
 * the range the .ubk stores (halves times a power of two up to 2^100), and be clamped. */
#define UB_SCENE_MAX_INTENSITY 1e20

typedef enum ub_light_type {
  UB_LIGHT_POINT = 0,
  UB_LIGHT_SPOT,
  UB_LIGHT_DIRECTIONAL
} ub_light_type;

/* Path class (DESIGN §3): primary lights bake indirect only. */
typedef enum ub_light_class {
  UB_LIGHT_STATIC = 0,
  UB_LIGHT_PRIMARY
} ub_light_class;

typedef enum ub_receiver_kind {
  UB_RECEIVER_LIGHTMAP = 0,
  UB_RECEIVER_LLG,
  UB_RECEIVER_NONE
} ub_receiver_kind;

/* Why a node has its receiver kind. */
typedef enum ub_receiver_source {
  UB_RECEIVER_DEFAULT = 0, /* no ubake_receiver tag: lightmap, unless the bake switches it */
  UB_RECEIVER_TAGGED,      /* ubake_receiver on the node or an ancestor: always kept */
  UB_RECEIVER_AUTO         /* set by the bake: a small prop with poor charts became an LLG
                              (probes/llg.h, ub_llg_auto_select) */
} ub_receiver_source;

typedef struct ub_light {
  ub_light_type type;
  ub_light_class cls;
  float position[3];  /* world, metres (point/spot) */
  float direction[3]; /* unit vector the light travels along (spot/directional) */
  float intensity[3]; /* colour × intensity: W/sr (point/spot), W/m² at normal incidence (directional) */
  float range;        /* metres; 0 = unbounded (inverse square forever) */
  float cos_inner;    /* spot: cos(innerConeAngle); 1 for others */
  float cos_outer;    /* spot: cos(outerConeAngle); -1 for others */
  int32_t dls;        /* index into ub_scene.dls_names, -1 = base bake */
  int32_t node;       /* index into ub_scene.nodes */
} ub_light;

typedef struct ub_material {
  float albedo[3];   /* total diffuse reflectance, each in [0, 0.999] */
  float emission[3]; /* emitted radiance, W/(m²·sr) */
  char *name;
} ub_material;

/* One glTF node that carried mesh triangles (one entry per node instance). */
typedef struct ub_node {
  char *name;               /* glTF node name, or "node <index>" */
  int32_t gltf_index;       /* index in the glTF nodes array */
  ub_receiver_kind receiver;
  int32_t door;             /* index into door_names, -1 = none (leaf in closed pose) */
  int32_t door_open;        /* index into door_names, -1 = none (leaf in open pose) */
  int32_t semidynamic;      /* index into object_names, -1 = none */
  float texel_size;         /* metres per lightmap texel; 0 = level default */
  char *combine;            /* ubake_combine (on a door leaf): comma-separated names of the
                               sets or doors baked in combination with it; NULL = none */
  uint32_t first_triangle;  /* triangles [first, first+count) belong to this node */
  uint32_t triangle_count;
  ub_receiver_source receiver_source;
  int32_t mesh;             /* glTF mesh index (instances of one mesh share it), -1 = none */
  float world[12];          /* world transform, column-major 3×4 (linear part, then the
                               translation); vertices above are already transformed */
} ub_node;

/* Per-triangle flags. */
enum {
  UB_TRI_HAS_UV1 = 1u << 0,     /* vertices carry authored lightmap UVs (TEXCOORD_1) */
  UB_TRI_DEGENERATE = 1u << 1   /* zero area (kept for counts, never traced or rasterised) */
};

typedef struct ub_scene {
  char *path;               /* file it was loaded from */

  uint32_t vertex_count;
  float *positions;         /* vertex_count × 3, world metres */
  float *normals;           /* vertex_count × 3, unit (geometric normal where the file had none) */
  float *uv1;               /* vertex_count × 2, lightmap UVs in [0,1]; 0 where absent */

  uint32_t triangle_count;
  uint32_t *indices;        /* triangle_count × 3, counter-clockwise seen from the front */
  uint32_t *tri_material;   /* triangle_count */
  uint32_t *tri_node;       /* triangle_count */
  uint8_t *tri_flags;       /* triangle_count, UB_TRI_* */

  uint32_t material_count;
  ub_material *materials;
  uint32_t node_count;
  ub_node *nodes;
  uint32_t light_count;
  ub_light *lights;

  uint32_t dls_count;
  char **dls_names;
  uint32_t door_count;
  char **door_names;
  uint32_t object_count;
  char **object_names;

  int has_sky;
  float sky[3];             /* constant sky radiance, W/(m²·sr) */
  float texel_size;         /* level default, metres per texel (default 0.25) */
  float glg_spacing;        /* level default, metres between GLG probes (default 2) */

  float bounds_min[3], bounds_max[3]; /* of all triangles */
  uint32_t degenerate_count;          /* triangles flagged UB_TRI_DEGENERATE */
  uint32_t skipped_primitives;        /* non-triangle primitives skipped (warned) */
} ub_scene;

/* Loads a .gltf or .glb. Errors (missing file, broken JSON, accessor out of range,
 * NaN/Inf data, bad tag value, no geometry) return a code and log one line naming the
 * file and the node/accessor. Warnings (unknown ubake_* keys, skipped primitives) go to
 * log at UB_LOG_WARNING. */
ub_result ub_scene_load(const char *path, const ub_log *log, ub_scene **out_scene);

/* Same as ub_scene_load() for a whole .gltf (JSON; buffers and images as data: URIs) or
 * .glb held in memory (data[0..size), not kept). External URIs are refused (the loader
 * never touches the filesystem), so this is safe on untrusted bytes. name (may be NULL)
 * is used in messages and as ub_scene.path. */
ub_result ub_scene_load_memory(const void *data, size_t size, const char *name,
                               const ub_log *log, ub_scene **out_scene);

void ub_scene_free(ub_scene *scene);

/* Largest extent of the bounds (metres); used to scale epsilons. */
float ub_scene_extent(const ub_scene *scene);

/* Sum of triangle areas (m²). */
double ub_scene_area(const ub_scene *scene);

/* The next name of a ubake_combine list (ub_node.combine: names between commas, the blanks
 * around them dropped) from list[*pos] on: 1 with the name at list[*start .. *start + *len)
 * (*len ≥ 1) and *pos past it, 0 when no name is left. Start with *pos = 0. The one reading
 * of the list, for the plan and for the loader's checks. */
int ub_combine_next(const char *list, size_t *pos, size_t *start, size_t *len);

#ifdef __cplusplus
}
#endif
#endif
