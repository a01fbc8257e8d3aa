/* ubake/bakefile.h — the .ubk bake file: what the run-time needs, in memory and on disk.
 *
 * On disk (docs/FORMAT.md): little-endian, a fixed header with magic "UBK\0" and a format
 * version, a section table, and sections each with its own CRC-32. Writing goes to
 * "PATH.tmp" and is renamed into place, so a failed write leaves no file behind.
 * Reading validates every length, count, index and float before anything trusts it: a
 * truncated, corrupted or hostile file gives UB_ERR_INVALID_DATA (or
 * UB_ERR_UNSUPPORTED_VERSION) and a message naming the file and the section.
 *
 * Lifecycle: ub_bakefile_read*() allocate a ub_bakefile; ub_bakefile_free() releases it
 * (NULL-safe). A ub_bakefile built by the baker for writing is owned by the baker.
 * Thread safety: a read bakefile is immutable and may be shared.
 */
#ifndef UBAKE_BAKEFILE_H
#define UBAKE_BAKEFILE_H

#include <stddef.h>
#include <stdint.h>

#include "ubake/error.h"

#ifdef __cplusplus
extern "C" {
#endif

#define UB_BAKEFILE_VERSION 2u /* 2: record kinds, parents, LLG probes; section ELEM */
#define UB_SH1_FLOATS 12 /* SH L1 × RGB, coefficient-major: [k*3 + c] */

typedef struct ub_bakefile_atlas {
  uint32_t width, height;
  /* width × height × UB_SH1_FLOATS floats: base radiance SH L1 per texel (W/(m²·sr)),
   * padding texels dilated from their neighbours. */
  float *sh;
  /* width × height: 0 = empty, 1 = covered by a surface, 2 = dilated padding. */
  uint8_t *coverage;
  /* width × height × 3: unit surface normal per covered texel, a padding texel's that of
   * the texel it was dilated from, 0 for empty ones (FORMAT.md). NULL in the run-time's
   * copy (ub_runtime_bakefile): it keeps them as halves (ub_runtime_texel_normal). */
  float *normal;
  /* Section TXLK (NULL = none): width × height link bytes, UB_LINK_X / UB_LINK_Y
   * (runtime/texel_links.h) set where the texel and its +x / +y neighbour are separated by
   * geometry; lightmap lookups do not blend across them. */
  uint8_t *link;
} ub_bakefile_atlas;

/* A dynamic element's sparse, linear record (section DLSR): what it adds to the base when
 * its weight is 1. Receiver indices are sorted and unique. Lightmap receivers are pixels
 * of the atlases taken in order (pixel = Σ_{b<a} W_b·H_b + y·W_a + x), padding included;
 * GLG receivers are probe indices. */
enum {
  UB_TRI_ROLE_DOOR_CLOSED = 1, /* a door's leaf in its closed pose: shown while t < 1/2 */
  UB_TRI_ROLE_DOOR_OPEN = 2,   /* a door's leaf in its open pose: shown while t ≥ 1/2 */
  UB_TRI_ROLE_OBJECT = 3       /* a show/hide object: shown while v ≥ 1/2 */
};

/* Kinds of dynamic element (ub_bakefile_record.kind). */
typedef enum ub_element_kind {
  UB_ELEMENT_DLS = 0,     /* a dynamic light set (ub_bakefile.dls) */
  UB_ELEMENT_DOOR = 1,    /* a door: S_open − S_closed, weight = opening fraction t */
  UB_ELEMENT_OBJECT = 2,  /* a show/hide object: lighting(shown) − lighting(hidden) */
  UB_ELEMENT_COMBO = 3    /* a combination of two elements (paper Fig. 9 / pairwise
                             shadow correction): weight = weight(parent[0]) ⊙ weight(parent[1]) */
} ub_element_kind;

typedef struct ub_bakefile_record {
  char name[64];            /* the set's name (ubake_dls), NUL-terminated */
  /* Section DLSR holds kind UB_ELEMENT_DLS only (parents -1); section ELEM the others.
   * Parents (COMBO only, else -1) use one numbering for all elements: [0, dls_count) are
   * the sets, dls_count + e is elems[e]; a parent is never the combination itself. */
  uint32_t kind;
  int32_t parent[2];
  uint32_t light_count;     /* lights in the set */
  float mean_intensity;     /* mean luminance intensity of its lights (W/sr or W/m²) */
  uint32_t texel_count;
  uint32_t *texel_index;    /* texel_count, < Σ W·H */
  float *texel_sh;          /* texel_count × 12: radiance SH L1 (I_z-exact), W/(m²·sr) */
  uint32_t probe_count;
  uint32_t *probe_index;    /* probe_count, < glg_probe_count */
  float *probe_sh;          /* probe_count × 27: radiance SH L2, W/(m²·sr) */
  /* LLG receivers: global LLG probe indices (models in order, each model's probes in its
   * own order: Σ_{m' < m} probes(m') + local index), < Σ probes of all models. */
  uint32_t llg_probe_count;
  uint32_t *llg_probe_index;
  float *llg_probe_sh;      /* llg_probe_count × 27: radiance SH L2, W/(m²·sr) */
  /* Read with UB_BAKEFILE_RECORD_HALVES: the values as the file stores them instead (the
   * three float arrays above NULL): IEEE halves, value = half × sh_half_scale (a power of
   * two); texel rows in the file's I_z form (runtime/texel_sh.h: packed along the pixel's
   * stored normal where it has one, as written). Such a bake file cannot be written. */
  uint16_t *texel_sh_half, *probe_sh_half, *llg_probe_sh_half;
  float sh_half_scale;
} ub_bakefile_record;

/* A punctual light as the run-time sees it (section LITE): primary lights' direct light is
 * computed at run time; static lights are listed for completeness. Units as in scene.h. */
typedef struct ub_bakefile_light {
  uint32_t type;        /* 0 point, 1 spot, 2 directional */
  uint32_t cls;         /* 0 static (direct baked), 1 primary (direct at run time) */
  int32_t dls;          /* dynamic light set index into dls[], -1 = none */
  float position[3], direction[3], intensity[3];
  float range, cos_inner, cos_outer;
} ub_bakefile_light;

/* One local light grid model (section LLGM; evaluation: ubake/llg.h). Probe (x, y, z) is
 * number (z·dims[1] + y)·dims[0] + x and sits on the box corners and evenly in between. */
typedef struct ub_bakefile_llg {
  char name[64];            /* the node's name, NUL-terminated */
  float center[3];          /* box centre, world metres */
  float axes[9];            /* rows: the box's orthonormal, right-handed axes */
  float half[3];            /* half extents along the axes, metres, > 0 */
  uint32_t dims[3];         /* probes per axis, each in [2, 64] */
  float *probe_sh;          /* dims product × 27: radiance SH L2, W/(m²·sr) */
  uint32_t vertex_count;
  float *positions;         /* vertex_count × 3, world metres */
  float *normals;           /* vertex_count × 3, unit */
  float *vis;               /* vertex_count × 9: self-visibility SH L2 (monochrome) */
  float *self;              /* vertex_count × 3: self-inter-reflection irradiance along the
                               vertex normal, W/m², ≥ 0 */
  uint32_t triangle_count;
  uint32_t *indices;        /* triangle_count × 3, < vertex_count */
  /* Instances share one self-visibility: 0 = vis is this model's own (stored); k > 0 =
   * vis is model k−1's (an earlier model with its own, same vertex count) carried along by
   * vis_rotation, V(ω) = V_{k−1}(Rᵀω): the file stores it once, the reader fills vis. */
  uint32_t vis_shared_from;
  float vis_rotation[9];    /* row-major orthogonal R (used when vis_shared_from > 0) */
} ub_bakefile_llg;

typedef struct ub_bakefile {
  char level_name[64];      /* NUL-terminated */
  uint32_t seed;
  uint32_t bounces;         /* bounces baked */

  /* Lightmapped geometry, for lightmap queries and rendering (world space, metres). */
  uint32_t vertex_count;
  float *positions;         /* vertex_count × 3 */
  uint32_t triangle_count;
  uint32_t *indices;        /* triangle_count × 3, each < vertex_count */
  int32_t *tri_atlas;       /* triangle_count: atlas index or -1 */
  float *tri_uv;            /* triangle_count × 6: lightmap UV per corner, [0,1] */
  float *tri_albedo;        /* triangle_count × 3: diffuse albedo, for rendering */
  /* Section TRIR (NULL = every triangle static): triangle_count roles, 0 = static, else
   * (role << 24) | elems index with role UB_TRI_ROLE_*: which element's state shows or
   * hides the triangle (renderers draw the level as the state has it). */
  uint32_t *tri_role;

  uint32_t atlas_count;
  ub_bakefile_atlas *atlases;

  /* Global light grid (section GLG; glg_probe_count 0 = none baked). */
  uint32_t glg_probe_count;
  float *glg_positions;     /* probe × 3, metres */
  float *glg_sh;            /* probe × 27: radiance SH L2, W/(m²·sr), raw (windowed at query) */
  uint32_t glg_tet_count;
  uint32_t *glg_tets;       /* tet × 4 probe indices, positively oriented */
  int32_t *glg_neigh;       /* tet × 4: tet opposite corner i, -1 on the hull */
  uint32_t glg_plane_count;
  float *glg_planes;        /* plane × 4: unit normal, d (n·x + d = 0) */
  uint32_t *glg_plane_of;   /* tet: leak plane index or UINT32_MAX (see probes/leak.h) */

  /* Punctual lights (section LITE; light_count 0 = none). */
  uint32_t light_count;
  ub_bakefile_light *lights;

  /* Local light grid models (section LLGM; llg_count 0 = none). */
  uint32_t llg_count;
  ub_bakefile_llg *llgs;

  /* Dynamic light sets (section DLSR; dls_count 0 = none). */
  uint32_t dls_count;
  ub_bakefile_record *dls;

  /* Doors, show/hide objects and combinations (section ELEM; elem_count 0 = none), in
   * that order of kinds, names unique per kind. */
  uint32_t elem_count;
  ub_bakefile_record *elems;
} ub_bakefile;

ub_result ub_bakefile_write(const ub_bakefile *bf, const char *path, const ub_log *log);
/* The same, also counting the values clamped to the half range (±65504) on the way; the
 * SH of atlases, GLG probes and records are scaled instead, so only LLG data can clamp. */
ub_result ub_bakefile_write_ex(const ub_bakefile *bf, const char *path, const ub_log *log,
                               uint64_t *out_clamped);
/* Reads path a section at a time (never the whole file at once: the records stream through
 * a buffer of at most 4 MiB), checking every section's CRC before it is parsed. Errors:
 * UB_ERR_IO (cannot open or read it, or it changed while read: inode, size or times),
 * UB_ERR_INVALID_DATA, UB_ERR_UNSUPPORTED_VERSION, UB_ERR_OUT_OF_MEMORY; one message to
 * log naming the file and the section. */
ub_result ub_bakefile_read(const char *path, const ub_log *log, ub_bakefile **out_bf);
/* Flags of ub_bakefile_read_ex. */
#define UB_BAKEFILE_RECORD_HALVES 1u /* records' SH as the file's halves (see the record) */
ub_result ub_bakefile_read_ex(const char *path, const ub_log *log, unsigned flags,
                              ub_bakefile **out_bf);
/* name: used in messages only (e.g. the file name). */
ub_result ub_bakefile_read_memory(const void *data, size_t size, const char *name,
                                  const ub_log *log, ub_bakefile **out_bf);
void ub_bakefile_free(ub_bakefile *bf);
/* Σ W·H over the atlases: the pixel numbering of records' texel indices. */
uint64_t ub_bakefile_atlas_pixels(const ub_bakefile *bf);
/* The stored normal (3 floats, not normalised; a padding pixel's source texel's, 0 for
 * empty pixels) of global atlas pixel p in that numbering, or NULL when p is out of range
 * or the atlas holds no normals (the run-time's copy: ub_runtime_texel_normal). */
const float *ub_bakefile_pixel_normal(const ub_bakefile *bf, uint64_t p);
/* LLG probes of all models: the numbering of records' llg_probe_index. */
uint64_t ub_bakefile_llg_probes(const ub_bakefile *bf);

#ifdef __cplusplus
}
#endif
#endif
