/* ubake/runtime.h — the run-time library: load a baked level (.ubk) and answer lighting
 * queries the way the game would.
 *
 * What it is: a ub_runtime holds a validated bake file (ubake/bakefile.h) and, per
 * lightmap texel, the AHD encoding (ubake/ahd.h) of its SH L1 in the current state with
 * the texel's stored normal (a texel without a usable normal takes the normal of the
 * nearest texel that has one), stored packed (ub_ahd_packed, 16 B: what a game uploads).
 * The padding the baker dilates around charts (coverage 2) has no state of its own: each
 * padding pixel shows the covered texel it copies (ub_runtime_texel_source). Lightmap
 * queries find the closest lightmapped surface point, filter the texels' SH and normals
 * bilinearly there, encode that to AHD and decode irradiance for a normal.
 * It does not depend on Embree or on the baker.
 *
 * Lifecycle: ub_runtime_load() → queries → ub_runtime_free() (NULL-safe). On failure
 * nothing is allocated and *out is left untouched.
 * Ownership: the runtime owns its bake file; ub_runtime_bakefile() lends it (valid until
 * ub_runtime_free()). Thread safety: after loading, queries take a const ub_runtime and
 * may run on any number of threads at once. The log passed to ub_runtime_load() is used
 * during that call only.
 *
 * Lightmap addressing (docs/FORMAT.md): texel (x, y) of a W × H atlas covers
 * u ∈ [x/W, (x+1)/W), v ∈ [y/H, (y+1)/H); its centre is at ((x+0.5)/W, (y+0.5)/H).
 */
#ifndef UBAKE_RUNTIME_H
#define UBAKE_RUNTIME_H

#include <stdint.h>

#include "ubake/ahd.h"
#include "ubake/bakefile.h"
#include "ubake/error.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct ub_runtime ub_runtime;

/* Reads and validates path (.ubk) and prepares the AHD atlases. Errors: UB_ERR_IO,
 * UB_ERR_INVALID_DATA, UB_ERR_UNSUPPORTED_VERSION, UB_ERR_OUT_OF_MEMORY, each with one
 * message to log naming the file. */
ub_result ub_runtime_load(const char *path, const ub_log *log, ub_runtime **out);
/* Load flags. UB_RUNTIME_RECORDS_8BIT: the run-time keeps the dynamic elements' records
 * (lightmap, GLG and LLG) in 8 bits instead of the file's halves: per record row the DC
 * values (a texel's I_z, a probe's L00, RGB) stay halves, the other coefficients become
 * signed bytes times a power of two per row (|error| ≤ the row's largest such |value| /
 * 127). About 40% less record memory (16 B a texel row instead of 24, 32 B a probe row
 * instead of 54); the state is base + Σ weight · (the rounded records), still linear, still
 * exact along each texel's normal (I_z is kept), but the blends decode the bytes, so
 * updates cost more (README, "8-bit records", gives the measured price). */
#define UB_RUNTIME_RECORDS_8BIT 1u
/* By default the blends also keep, for every receiver where 6 or more elements overlap,
 * base + the sum of those elements' records (float, 4 B a value: 48 B a texel, 108 B a
 * probe), and compute such a receiver as that sum + Σ (weight − 1)·record over the
 * elements whose weight is not 1 whenever that reads fewer bytes (UB_BLEND_ONES_SUM,
 * runtime/blend.h): with most sets on, a toggle there reads one record instead of every
 * overlapping set's. Equal to the plain sum to float rounding; the state still depends on
 * the weights alone. UB_RUNTIME_PLAIN_SUMS keeps no such sums: less memory (full ESTATE
 * −22.5 MiB), slower toggles where many sets overlap (README, "All-ones sums"). */
#define UB_RUNTIME_PLAIN_SUMS 2u
/* UB_RUNTIME_KEEP_STATE: ub_runtime_keep_state() at load (the load state: every set on,
 * doors closed, objects as baked). */
#define UB_RUNTIME_KEEP_STATE 4u
/* UB_RUNTIME_GLG_SMALL_WALK: the GLG keeps no 64-byte walk record per tet, only its links
 * and the probe positions (ub_glg_desc.small_walk): 48 B a tet less (full ESTATE, 1.3 M
 * tets: −57 MiB), each walk step and cached-tet test computes the barycentrics from the
 * corners instead (README, "Small GLG walk", gives the measured price). */
#define UB_RUNTIME_GLG_SMALL_WALK 8u
/* By default the run-time also keeps the AHD of every texel an element touches as it is
 * with every element at 0 (16 B a touched texel; full ESTATE: 1.25 M texels, 19.1 MiB),
 * encoded at load: an update copies it for the texels whose elements are then all at 0
 * instead of re-encoding them, so turning a set off costs a copy wherever no other set
 * lights the texel (the bits a re-encode gives). UB_RUNTIME_NO_BASE_AHD keeps none: less
 * memory, every such texel re-encoded (README, "Base AHD", gives the measured price). */
#define UB_RUNTIME_NO_BASE_AHD 16u
/* By default texels whose combination of overlapping elements is rare (at most 4 texels
 * share it) get zero rows in up to 6 more elements' lightmap records, so that they join a
 * common combination's overlap group: far fewer groups for an update to visit (full
 * ESTATE: 37,578 → 6,903 lightmap groups; toggles and the all-sets update faster, less
 * memory). The added terms are ω·0: values agree with separate groups' to float rounding
 * (a merged group may take its all-ones sums where the small one summed its rows). An
 * update re-encodes and lists (ub_runtime_changed_texels) only the texels whose own
 * elements changed, as with separate groups. UB_RUNTIME_SEPARATE_GROUPS gives every
 * combination its own group (as before 2026-12-05; faster load). README, "Merged groups",
 * gives the measured price. UB_RUNTIME_MERGE_GROUPS asks for the default (it was opt-in). */
#define UB_RUNTIME_MERGE_GROUPS 32u
#define UB_RUNTIME_SEPARATE_GROUPS 64u
/* ub_runtime_load() with flags (0 or the flags above; UB_ERR_INVALID_ARGUMENT for others). */
ub_result ub_runtime_load_ex(const char *path, const ub_log *log, unsigned flags,
                             ub_runtime **out);
void ub_runtime_free(ub_runtime *rt);

/* The loaded bake file, read-only, owned by rt. It differs from one read with
 * ub_bakefile_read(): glg_neigh, glg_positions and glg_sh are NULL (the GLG keeps its own
 * compact probe store and the positions it needs, its walk records hold the neighbours;
 * glg_tets and the leak planes stay; ub_runtime_glg_probe_sh gives the SH); atlases[a].sh
 * are NULL (the run-time keeps the texels' SH as the file's halves, or computes them from
 * the records: read the lightmap through the queries) and so are atlases[a].normal (kept
 * as the file's halves: ub_runtime_texel_normal). When the file
 * has dynamic elements (sets, doors, objects), the run-time keeps one float copy of the
 * LLG probes' current state and the records in half precision (as the file stores them;
 * 8 bits with UB_RUNTIME_RECORDS_8BIT),
 * so also: every record's texel_sh, probe_sh and llg_probe_sh and its receiver indices
 * (texel_index, probe_index, llg_probe_index) are NULL (the blends keep what they need;
 * counts, names and kinds are kept; read the file with ub_bakefile_read() for the records
 * themselves); llgs[m].probe_sh hold the CURRENT raw state (base + Σ weight·record), updated by
 * ub_runtime_update(). */
const ub_bakefile *ub_runtime_bakefile(const ub_runtime *rt);

/* Bytes the run-time holds (its own arrays and its bake file's), by what they serve. */
typedef struct ub_runtime_memory {
  size_t geometry;  /* triangles, vertices, UVs, albedo, roles, lights; atlas normals and
                       coverage; GLG positions, tets, leak planes; LLG model meshes,
                       visibility, self terms */
  size_t lightmap;  /* per covered texel: AHD (16 B packed), SH (where a record touches it none: the
                       lightmap blend computes it; else the file's halves; touched: encode
                       normal, slot and rank); coverage/touched bitmaps; fallback encode
                       normals; the kept state's AHD (ub_runtime_keep_state); the base
                       state's AHD (unless UB_RUNTIME_NO_BASE_AHD) */
  size_t glg;       /* the GLG's compact probe store (58 B/probe) and its walk data */
  size_t llg;       /* LLG probe SH (current state) */
  size_t records;   /* element records: their values (half, or 8-bit rows), held by the blends */
  size_t blend;     /* the blend engines: tables, weights, touched receivers' base rows,
                       all-ones sums (unless UB_RUNTIME_PLAIN_SUMS), the kept state's LLG
                       probe rows (ub_runtime_keep_state) */
  size_t total;     /* the sum */
} ub_runtime_memory;
void ub_runtime_memory_usage(const ub_runtime *rt, ub_runtime_memory *out_memory);

/* Baked irradiance (W/m², linear RGB) at the lightmapped surface point closest to p
 * (world, metres), for the unit normal n (normalised here), from the bilinearly filtered
 * AHD lightmap. Only triangles the current state shows count (ub_runtime_triangle_shown):
 * a hidden object's or door leaf's surface is not in the level, so a point on it is
 * answered by the closest shown surface; ub_runtime_query_lightmap_ex() says when that
 * happened. out_distance (may be NULL): metres from p to the surface point used.
 * Returns UB_ERR_NOT_BAKED if the file has no lightmapped triangle or the state hides
 * every one (outputs untouched), UB_ERR_INVALID_ARGUMENT for a non-finite p or a zero /
 * non-finite n. */
ub_result ub_runtime_query_lightmap(const ub_runtime *rt, const float p[3], const float n[3],
                                    float out_rgb[3], float *out_distance);

/* Where a lightmap query was answered. hidden_closer is 1 when a lightmapped triangle the
 * current state hides (e.g. the surface of an object switched off) is closer to p than
 * the shown surface that answered: a query meant for that surface gets "not shown". */
typedef struct ub_runtime_lightmap_hit {
  uint32_t triangle;        /* the shown triangle that answered */
  float distance;           /* metres from p to it */
  int hidden_closer;        /* 1: a hidden lightmapped triangle is closer (below) */
  uint32_t hidden_triangle; /* the closest hidden one, UINT32_MAX unless hidden_closer */
  int32_t hidden_element;   /* its element (ub_runtime_element_name), -1 if none */
  float hidden_distance;    /* metres from p to it; INFINITY unless hidden_closer */
} ub_runtime_lightmap_hit;
/* ub_runtime_query_lightmap() with the hit described (out_hit may be NULL; untouched on
 * error). */
ub_result ub_runtime_query_lightmap_ex(const ub_runtime *rt, const float p[3],
                                       const float n[3], float out_rgb[3],
                                       ub_runtime_lightmap_hit *out_hit);

/* Irradiance (W/m²) decoded from the AHD of texel (x, y) of atlas `atlas` for unit normal
 * n (normalised here); for a padding pixel its source texel's (ub_runtime_texel_source);
 * 0 for an empty texel (coverage 0). The AHD in float, encoded from the texel's current
 * SH as an update encodes it (along the texel's stored normal it is the SH's irradiance,
 * linear in the sets' weights to float rounding); the stored, packed AHD a game uploads
 * (ub_runtime_texel_ahd) is this rounded to half. UB_ERR_INVALID_ARGUMENT for an atlas or
 * texel out of range or a zero / non-finite n (outputs untouched). */
ub_result ub_runtime_texel_irradiance(const ub_runtime *rt, uint32_t atlas, uint32_t x,
                                      uint32_t y, const float n[3], float out_rgb[3]);
/* The stored normal of texel (x, y) of atlas `atlas`, as the bake file has it (world, unit
 * to half precision; zero for an empty texel or one without a normal): what the AHD
 * encode and the I_z form use; for a padding pixel its source texel's
 * (ub_runtime_texel_source), as for its irradiance (zero for padding no texel reaches).
 * UB_ERR_INVALID_ARGUMENT for an atlas or texel out of range (output untouched). */
ub_result ub_runtime_texel_normal(const ub_runtime *rt, uint32_t atlas, uint32_t x, uint32_t y,
                                  float out_n[3]);
/* The covered texel (coverage 1) whose state pixel (x, y) of atlas `atlas` shows: itself,
 * or for a padding pixel (coverage 2) the texel it copies — one at the smallest Chebyshev
 * distance, found ring by ring as the baker grows its padding (each ring's pixel takes its
 * first 8-neighbour of the ring before, rows top to bottom, left to right). A game fills
 * its lightmap's padding by copying these texels' AHD. UB_ERR_NOT_BAKED for an empty
 * pixel (or padding no texel reaches), UB_ERR_INVALID_ARGUMENT out of range (outputs
 * untouched). */
ub_result ub_runtime_texel_source(const ub_runtime *rt, uint32_t atlas, uint32_t x, uint32_t y,
                                  uint32_t *out_x, uint32_t *out_y);

/* The stored AHD lightmap (ubake/ahd.h, ub_ahd_packed: 16 bytes a texel, halves of value /
 * ub_runtime_ahd_scale and an octahedral direction): what a game uploads to its lightmap
 * texture and re-uploads where an update re-encoded texels. The scale is a power of two
 * ≥ 1, fixed at load: 64 × the largest value of the lightmap's SH rows (base and records,
 * W/m²) fits in the half range (1 unless a row value exceeds 1023). A colour above
 * 65504 × scale (many bright sets adding up with large weights) is stored as
 * 65504 × scale. The stored AHD depends on the current state only, not on the updates
 * before it. */
float ub_runtime_ahd_scale(const ub_runtime *rt);
/* Texel (x, y)'s packed AHD in the current state (a padding pixel: its source texel's).
 * UB_ERR_NOT_BAKED for an empty pixel, UB_ERR_INVALID_ARGUMENT out of range (output
 * untouched). */
ub_result ub_runtime_texel_ahd(const ub_runtime *rt, uint32_t atlas, uint32_t x, uint32_t y,
                               ub_ahd_packed *out);
/* The whole atlas's packed AHD, width × height texels row by row, as a texture: padding
 * pixels copy their source texel, empty pixels are zero. UB_ERR_INVALID_ARGUMENT for an
 * atlas out of range. */
ub_result ub_runtime_atlas_ahd(const ub_runtime *rt, uint32_t atlas, ub_ahd_packed *out);

/* What changed in the lightmap at the last update (ub_runtime_update, or _end), for a
 * game to re-upload: the texels it re-encoded (every texel of every overlap group holding
 * an element whose value changed; the same count as the update's texels_reencoded), in
 * the order the update wrote them, the same list whatever the job count. Padding pixels
 * that copy a changed texel (ub_runtime_texel_source) change with it. Empty before the
 * first update after load (the whole atlas is new then: ub_runtime_atlas_ahd). Kept as
 * runs of texels, one per overlap group: (groups + jobs) × 8 bytes and 4 per job. */
typedef struct ub_runtime_texel_change {
  uint32_t atlas, x, y;
  ub_ahd_packed ahd; /* its new packed AHD */
} ub_runtime_texel_change;
uint64_t ub_runtime_changed_texel_count(const ub_runtime *rt);
/* 1 when the last update wrote some of LLG model `model`'s probes (its grid in the bake
 * file, llgs[model].probe_sh, is then new: a game re-uploads that model's grid), else 0
 * (also for a model out of range, and before the first update after load). */
int ub_runtime_llg_changed(const ub_runtime *rt, uint32_t model);
/* Changed texels [start, start + max) of the last update into out; returns how many were
 * written (fewer than max at the end). Cost: the runs before start, then one texel each. */
size_t ub_runtime_changed_texels(const ub_runtime *rt, uint64_t start, size_t max,
                                 ub_runtime_texel_change *out);
/* Irradiance (W/m², ≥ 0) from the global light grid at any point p for unit normal n:
 * tetrahedral interpolation of the probes' SH L2 with leak planes, windowed, convolved.
 * inout_tet_cache: a caller-owned cache (start at UB_GLG_NO_CACHE; one per moving object
 * or thread), or NULL. UB_ERR_NOT_BAKED when the file has no GLG, UB_ERR_INVALID_ARGUMENT
 * for a non-finite p (outputs untouched; ub_glg_query itself answers at the cached tet's
 * centroid). Unlike the lightmap and LLG queries, a zero or non-finite n is not an error:
 * it gives the mean irradiance π·Y00·L00 over all normals (ubake/glg.h). */
ub_result ub_runtime_query_glg(const ub_runtime *rt, const float p[3], const float n[3],
                               uint32_t *inout_tet_cache, float out_rgb[3]);
/* The same through a moving object's cursor (ubake/glg.h: its tet and that tet's four
 * probes' windowed rows, so consecutive queries in one tet skip decoding the probes; the
 * same bits and the same errors). Initialise it with ub_glg_cursor_init; one per object
 * or thread. */
struct ub_glg_cursor;
ub_result ub_runtime_query_glg_cursor(const ub_runtime *rt, const float p[3], const float n[3],
                                      struct ub_glg_cursor *cursor, float out_rgb[3]);

/* Irradiance (W/m², ≥ 0) from the local light grids (ubake/llg.h) at p for unit normal n
 * (normalised here). The model: the first whose box contains p, else the one whose box is
 * closest. Its grid is interpolated trilinearly at p; when the model's surface is within
 * UB_LLG_SURFACE_DISTANCE of p, the self-visibility at the closest surface point (ties
 * between faces, as near a concave edge, go to the face whose normal agrees with n) is
 * multiplied in (SH triple product, before the cosine convolution) and its
 * self-inter-reflection added (ubake/llg.h); farther away (a point in the air around the
 * model) the grid alone answers.
 * flags: 0, or UB_LLG_QUERY_NO_VISIBILITY (grid alone, for comparisons).
 * out_model (may be NULL): the model's index in ub_runtime_bakefile(rt)->llgs.
 * UB_ERR_NOT_BAKED when the file has no LLG; UB_ERR_INVALID_ARGUMENT for a non-finite p
 * or a zero / non-finite n (outputs untouched). */
#define UB_LLG_SURFACE_DISTANCE 0.05f /* metres */
#define UB_LLG_QUERY_NO_VISIBILITY 1u
ub_result ub_runtime_query_llg(const ub_runtime *rt, const float p[3], const float n[3],
                               float out_rgb[3]);
ub_result ub_runtime_query_llg_ex(const ub_runtime *rt, const float p[3], const float n[3],
                                  unsigned flags, float out_rgb[3], uint32_t *out_model);

/* ---- dynamic light sets --------------------------------------------------------------
 * Each set baked into the file has an RGB weight (default 1: its lights on as baked). The
 * lighting used everywhere is base + Σ weight_i · set_i, exact per channel because light
 * transport is linear (a tint keeps colour bleeding). ub_runtime_set_dls() only records
 * the weight; ub_runtime_update() recomputes the receivers of the changed sets (each
 * written once, batched by overlap combination; a set whose weight is back at the last
 * update's is not changed) and re-encodes their AHD texels; their
 * GLG probes it only marks: the first query that reads such a probe blends it (base + Σ
 * weight·set, the same bits) and windows it, so probes no query reads cost nothing (~0.25–
 * 0.37 µs more for each one read, on the querying thread; queries stay thread safe). Not
 * thread safe against concurrent queries: update between frames. */
uint32_t ub_runtime_dls_count(const ub_runtime *rt);
int32_t ub_runtime_dls_find(const ub_runtime *rt, const char *name); /* -1 if absent */
const char *ub_runtime_dls_name(const ub_runtime *rt, uint32_t set);
/* UB_ERR_INVALID_ARGUMENT (nothing changes) while a job-split update is begun, for a set
 * out of range or a channel that is not finite or beyond ±UB_RUNTIME_MAX_WEIGHT: a
 * million times a set's baked light is past any light a level holds, and the GLG's probe
 * store keeps values within a range (a channel beyond it would read 0 there, while the
 * lightmap read the product). */
#define UB_RUNTIME_MAX_WEIGHT 1e6f
ub_result ub_runtime_set_dls(ub_runtime *rt, uint32_t set, const float rgb[3]);
/* A set's weight from its lights' strengths (each 0 = shot out … 1 = as baked): their
 * mean (UberBake §3.1). */
float ub_runtime_dls_weight_from_lights(const float *strengths, uint32_t count);

/* ---- doors, show/hide objects, combinations ----------------------------------------
 * Elements of the file's section ELEM (ub_bakefile.elems), each a sparse record blended
 * exactly like a set. Every record is the element's lighting difference from the base
 * state with everything else as baked (ubake/bakefile.h); the run-time applies it with
 * the element's value minus the value baked into the base:
 *   set        value = RGB weight (default 1)       baked 0: applied with w
 *   door       value = opening fraction t in [0,1]  baked 0 (closed): applied with t
 *              (default 0). From a hinge angle a: ub_runtime_door_fraction(a) = 1 − cos a,
 *              the share of the doorway no longer covered by the leaf seen head-on; 1
 *              from 90°.
 *   object     value = visibility v in [0,1]        baked 1 (shown): applied with v − 1
 *              (default 1; 0 hides, values between fade)
 *   combination: applied with the product of its two parents' applied weights (the
 *              mixed second difference of a door × set pass, or the pairwise correction
 *              of two overlapping objects' shadows).
 * Values take effect at the next ub_runtime_update(), which recomputes only receivers of
 * changed elements (and of combinations of them). */
uint32_t ub_runtime_element_count(const ub_runtime *rt);
/* Index into the file's elements of the element of that kind and name, -1 if absent. */
int32_t ub_runtime_element_find(const ub_runtime *rt, ub_element_kind kind, const char *name);
const char *ub_runtime_element_name(const ub_runtime *rt, uint32_t element);
ub_element_kind ub_runtime_element_kind(const ub_runtime *rt, uint32_t element);
/* Sets a door's t or an object's v (finite, in [0, 1]). UB_ERR_INVALID_ARGUMENT for an
 * element out of range, a combination (its weight follows its parents), a bad value or
 * while a job-split update is begun (nothing changes). */
ub_result ub_runtime_set_element(ub_runtime *rt, uint32_t element, float value);
/* The value last set (door t, object v; the default before any set). For combinations and
 * out-of-range elements: UB_ERR_INVALID_ARGUMENT, out untouched. */
ub_result ub_runtime_element_value(const ub_runtime *rt, uint32_t element, float *out_value);
/* Whether triangle t of the file's geometry is present in the state of the last update
 * (section TRIR: a closed door leaf while t < 1/2, an open-pose leaf from 1/2, an object
 * while v ≥ 1/2; every other triangle always). Like the lighting, a door's or object's
 * geometry changes at the update, not at ub_runtime_set_element: the lightmap queries
 * (which skip hidden triangles) and what a game draws stay in step with the lightmaps. A
 * ub_renderer (ubake/render.h) keeps the triangles shown when it was created: create it
 * again after an update that moved a door or an object. */
int ub_runtime_triangle_shown(const ub_runtime *rt, uint32_t triangle);
float ub_runtime_door_fraction(float hinge_angle_radians);

typedef struct ub_runtime_update_stats {
  /* texels whose state the lightmap blend computed, less the merged texels it left as
   * they were (UB_RUNTIME_SEPARATE_GROUPS: none are), and of them those re-encoded */
  uint64_t texels_written, texels_reencoded;
  uint64_t texels_kept; /* of texels_reencoded: copied back from the kept state */
  uint64_t texels_base; /* of texels_reencoded: every element at 0, the base's AHD copied
                           (unless UB_RUNTIME_NO_BASE_AHD) */
  uint64_t probes_written; /* GLG probes marked, blended when a query first reads them */
  uint64_t llg_probes_written;
  uint64_t llg_probes_kept; /* of llg_probes_written: copied back from the kept state */
  /* What the blends read (base and record rows, group tables) and write (current rows),
   * plus the AHD re-encode's normals read and AHD texels written; the kept state's values
   * read where they are copied back (ub_runtime_keep_state). GLG: its group tables only
   * (the rows are read when a query blends a marked probe, not counted here). */
  uint64_t bytes_read, bytes_written;
  uint32_t groups;
  /* Wall-clock seconds of the update's parts (monotonic clock; for benchmarks): lightmap
   * blend + AHD re-encode, GLG marking (the changed probes are blended and windowed by
   * the first query that reads them, see ubake/glg.h "Lazy blending"), LLG blend. */
  double seconds_lightmap, seconds_glg, seconds_llg;
} ub_runtime_update_stats;
/* UB_OK, or UB_ERR_INVALID_ARGUMENT while a job-split update (below) is begun and not
 * ended (nothing changes). */
ub_result ub_runtime_update(ub_runtime *rt, ub_runtime_update_stats *out_stats);

/* Keeps the current state (the last update's) for fast returns to it: a copy of the AHD
 * of every texel an element touches (16 B each; full ESTATE: 1.26 M texels, 19.3 MiB) and
 * of the SH of every LLG probe one touches (108 B each). An update then re-encodes no
 * texel and blends no LLG probe whose elements are all back at their kept values: it
 * copies the kept values back (the same bits a re-blend gives: a receiver's state is a
 * function of its elements' values alone). A set turned off and on again, a door opened
 * and closed, a flickering light: the way back costs a copy. GLG probes are blended
 * lazily by the queries anyway. Call it again to keep another state (one is kept at a
 * time). UB_ERR_INVALID_ARGUMENT (nothing changes) while an element's value differs from
 * the last update's (a value set away and back before the update is no change: that
 * update re-encodes nothing for it) or an update is begun and not ended; UB_ERR_OUT_OF_MEMORY (the LLG
 * probes' state may then be kept without the texels': still exact). */
ub_result ub_runtime_keep_state(ub_runtime *rt);

/* The same update split into jobs for the game's job system (the library starts no
 * thread): ub_runtime_update_begin() takes the changed weights and splits the work into
 * *out_jobs = max_jobs jobs of about equal size (runs of overlap groups, a large group
 * cut at a receiver; with little work some jobs are empty); call
 * ub_runtime_update_job(rt, j) once for every j < *out_jobs, on any threads, at the same
 * time or not (each job sets the floating-point mode it needs on its thread and restores
 * it); then ub_runtime_update_end(). A receiver's operations do not depend on where the
 * cuts fall: every texel and probe gets the same bits as with ub_runtime_update()
 * (which is begin(1) + job 0 + end), whatever the job count. Between begin and end nothing
 * else may use rt (no query; a set, update, begin or keep_state is refused with
 * UB_ERR_INVALID_ARGUMENT). Misuse is harmless: a job index out of range or without a
 * begun update is ignored; ub_runtime_update_end runs any job that was not run (so no
 * receiver is left in the old state) and, with no update begun, changes nothing (the last
 * update's changed texels stay listed) and zeroes *out_stats.
 * Stats: the jobs' counts added; seconds_* the longest job's time in that part.
 * Errors (nothing started, the changes stay pending): UB_ERR_INVALID_ARGUMENT (max_jobs
 * 0 or above UB_RUNTIME_MAX_JOBS, or an update begun and not ended), UB_ERR_OUT_OF_MEMORY (the jobs' scratch, made once
 * for the largest count asked: ~12 KB per job and representation). */
#define UB_RUNTIME_MAX_JOBS 256u
ub_result ub_runtime_update_begin(ub_runtime *rt, uint32_t max_jobs, uint32_t *out_jobs);
void ub_runtime_update_job(ub_runtime *rt, uint32_t job);
void ub_runtime_update_end(ub_runtime *rt, ub_runtime_update_stats *out_stats);

struct ub_glg;
/* Every GLG probe's current radiance SH L2 into out (probe × 27 floats), as the GLG's
 * compact store holds it (ubake/glg.h): raw = base + Σ weight·set rounded to half with the
 * probe's exponent, or windowed (what queries interpolate; probes an update changed and no
 * query has read yet are blended and windowed by this call). UB_ERR_NOT_BAKED without a GLG. */
ub_result ub_runtime_glg_probe_sh(const ub_runtime *rt, int windowed, float *out);

/* The run-time GLG (for resampling into LLG boxes, see ubake/glg.h), or NULL. */
const struct ub_glg *ub_runtime_glg(const ub_runtime *rt);

/* Baked irradiance (W/m², linear RGB) on lightmapped triangle tri at barycentrics (b1, b2)
 * of its corners 1 and 2 (corner 0: 1 − b1 − b2), for the unit normal n (normalised
 * here): the AHD lightmap filtered bilinearly at the interpolated lightmap UV, as
 * ub_runtime_query_lightmap() does, without searching for the closest point (for
 * renderers that already know the surface point). UB_ERR_INVALID_ARGUMENT for tri out of
 * range, not lightmapped (tri_atlas < 0) or hidden in the current state
 * (ub_runtime_triangle_shown), non-finite barycentrics or a zero / non-finite n (outputs
 * untouched). */
ub_result ub_runtime_lightmap_at(const ub_runtime *rt, uint32_t tri, float b1, float b2,
                                 const float n[3], float out_rgb[3]);

#ifdef __cplusplus
}
#endif
#endif
