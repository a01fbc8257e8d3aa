/* runtime/blend.h — the run-time blend engine: final = base + Σ ω_i·S_i (paper eq. 2).
 *
 * What it is: one ub_blend re-blends ONE representation (lightmap texels, LLG probes or
 * GLG probes; runtime.c makes one per representation). A representation is an array of
 * receiver_count receivers with `stride` floats each, RGB interleaved, coefficient-major:
 * value[r*stride + k*3 + c] for coefficient k, channel c (texels: SH L1, stride 12;
 * probes: SH L2, stride 27). Inputs:
 *   - base: receiver_count × stride floats, the base bake;
 *   - elements (dynamic light sets; later doors and show/hide objects): each a sparse,
 *     linear record = `count` sorted, unique receiver indices + count × stride values
 *     (float or IEEE half), receiver-major;
 *   - a weight per element: RGB ω_i; channel c of every coefficient of S_i is scaled by
 *     ω_i[c] (a scalar weight w is (w, w, w)). Every weight starts at 0 (the base state).
 * Output: a caller-owned out array of receiver_count × stride floats, set to base by
 * ub_blend_create(). ub_blend_update() writes, for every receiver of every group holding
 * an element whose weight changed, out[r] = base[r] + Σ_{ω_i ≠ 0} ω_i·S_i[r], summed in
 * element-id order in registers and stored ONCE (no read-modify-write of out, paper
 * §3.3). No other receiver is written. Streaming mode (out_values NULL at update): the
 * rows are blended into a small L1-resident scratch and handed to the touched callback
 * (e.g. to re-encode lightmap texels to AHD without keeping a blended SH array at all).
 *
 * Grouping (paper §3.3, second game): at create time, every receiver touched by ≥ 1
 * element gets its combination (sorted element ids); receivers with the same combination
 * form a group. A group stores its receivers either as runs of consecutive receivers
 * (first receiver + length) or, when runs are short, as a list (one index per receiver),
 * and the engine keeps its own copy of the record values: per element, its rows for its
 * groups in ascending group order (a group's in its receivers' order), so an update reads
 * each member of a group as one sequential stream, and an element's rows over all its
 * groups as one stream too (records are scattered otherwise; a layout per group, members
 * side by side, made a big set's toggle jump from group to group), and keeps no record
 * positions; the records themselves are not needed after create. Kernels are specialised
 * for the stride (12, 27, other) and 1..8 non-zero members; a generic kernel takes any
 * count. On a CPU with AVX and F16C (checked at create, unless UB_BLEND_PORTABLE) each
 * run of consecutive receivers is blended as one flat array, 8 lanes at a time,
 * converting half records in registers; otherwise half rows are decoded exactly to float
 * (SSE2 bit operations) a chunk at a time into an L1 scratch, then blended in float.
 * 8-bit rows (UB_BLEND_STORE_Q8) are decoded exactly too: in registers a receiver at a
 * time with AVX2 (strides 12 and 27), else a chunk at a time into the L1 scratch.
 * Every path does the same float operations per value, so they give the same bits. A group
 * whose weights are all 0 copies base rows (the "light off" fast path). Elements with
 * weight 0 are skipped, so a receiver's value depends only on the current weights, never
 * on the update history: setting weights back gives bit-identical output.
 * Numerics: each term is rounded once (product) and summed once in float, so
 * |out − exact| ≤ γ_{k+1}·(|base| + Σ|ω_i·S_i|) per value, γ_n = n·2^-24/(1 − n·2^-24).
 *
 * Row queries (UB_BLEND_ROW_QUERY): a receiver's current row computed on demand from the
 * base and record rows (ub_blend_row), so a streaming caller keeps no blended array.
 *
 * Lifecycle: ub_blend_create() → { ub_blend_set_weight()…, ub_blend_update() }… →
 * ub_blend_free() (NULL-safe). On failure nothing is allocated, *out_blend and
 * out_values are left untouched.
 * Ownership: the engine BORROWS base (unless UB_BLEND_OWN_BASE): it must stay valid and
 * unchanged until ub_blend_free(). The records (receivers, values), the desc and its
 * elements array are read during ub_blend_create() only (the engine copies the values,
 * Σ count × stride of them, = info.record_bytes) and may be freed after. The out array is the caller's; pass
 * the same array to every update (to fill a new one: copy base, then ub_blend_update_all),
 * or always NULL (streaming).
 * Floating point: updates run with FTZ/DAZ cleared (restored on return), so results do not
 * depend on the caller's MXCSR.
 * Thread safety: an instance is single-threaded (no locks) except for the parts of one
 * parallel update (below); distinct instances are independent and may be updated on
 * different threads at once. The log is used during
 * ub_blend_create() only.
 */
#ifndef UBAKE_RUNTIME_BLEND_H
#define UBAKE_RUNTIME_BLEND_H

#include <stddef.h>
#include <stdint.h>

#include "ubake/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Floats per receiver: a multiple of 3 (RGB), 3..UB_BLEND_MAX_STRIDE (SH L3 × RGB). */
#define UB_BLEND_MAX_STRIDE 48

/* desc.flags */
#define UB_BLEND_PORTABLE 1u /* baseline kernels only (no AVX/F16C): for tests */
/* The engine keeps its own copy of the base rows of the receivers some element touches
 * (in group order, so a group's base rows are read as one stream) and never reads
 * desc->base after create: the caller may free it. The rows no element touches are the
 * caller's out array, set to base at create and never written again, so base and
 * current share them. Memory: touched × stride × 4 bytes (2 with UB_BLEND_BASE_HALF)
 * instead of receiver_count × stride × 4 (ESTATE-like: 36% of texels touched). Same
 * results, bit for bit. */
#define UB_BLEND_OWN_BASE 2u
/* Float records (UB_BLEND_FLOAT32) kept by the engine as half (runtime/half.h, round to
 * nearest even; values must be within the half range: scale them first): the engine then
 * works as with half records, without the caller building a half copy first. */
#define UB_BLEND_STORE_HALF 4u
/* ub_blend_row() is available: the engine keeps a map from receivers to their groups'
 * units (16 B per run, per list receiver), and when it is no smaller, 4 B per receiver
 * giving each its unit directly (receivers mostly in lists, e.g. GLG probes), and the
 * weights of the last update. */
#define UB_BLEND_ROW_QUERY 8u
/* With UB_BLEND_OWN_BASE: the engine's base rows are kept as IEEE half times a power of
 * two, base_scale (info), the smallest ≥ 1 that brings the touched rows' largest |value|
 * to ≤ 32768: each value rounded once to nearest (relative error ≤ 2^-11, absolute ≤
 * 2^-25·base_scale; exact when the rows are already halves times a power of two ≥
 * base_scale, as a bake file's are). Half the bytes of the base rows, read and kept.
 * Results are those of a float engine whose base is the rounded rows, bit for bit: a
 * half is turned into float and multiplied by base_scale exactly. The out array given to
 * create gets the rounded rows too (touched receivers), so it always holds the state. */
#define UB_BLEND_BASE_HALF 16u
/* Records kept in 8 bits (lossy; float or half records): per row the first 3 values (the
 * DC coefficient, RGB) as IEEE half, rounded to nearest even (exact for half records),
 * and the other stride − 3 as signed 8-bit integers q times a power of two 2^e per row, e
 * chosen so the row's largest |value| v_max gives |q| ≤ 127 with the finest step:
 * |error| ≤ 2^(e−1) ≤ v_max / 127 per value (0 for a row of zeros; rows whose v_max is
 * below 2^-119 keep the step 2^-126 instead, finer values then round to 0). A row takes
 * ub_blend_q8_row_bytes(stride) bytes: 16 for SH L1 × RGB (24 as half), 32 for SH L2 ×
 * RGB (54). Why the DC apart: a texel's DC slot holds I_z, the irradiance along its
 * normal, and under grazing light it is ~1000× smaller than its L1 terms (docs/FORMAT.md,
 * ATLS), so one step for the whole row would erase it. The blend stays linear: results
 * are those of a float engine whose records are ub_blend_q8_row(…) of the given rows,
 * bit for bit, on every path. Float DC values must round to a finite half (|v| < 65520). */
#define UB_BLEND_STORE_Q8 32u
/* The AVX + F16C kernels only, not the AVX2 ones (8-bit rows): for tests on AVX2 CPUs. */
#define UB_BLEND_NO_AVX2 64u
/* With UB_BLEND_OWN_BASE: the engine also keeps, for every receiver of a group of 6 or
 * more members, its all-ones sum A = base + Σ its members' rows (as the engine holds them,
 * summed in double, rounded once to float; 4 × stride bytes a receiver). An update then
 * computes a group as A + Σ_{ω_i ≠ 1} (ω_i − 1)·S_i (each ω − 1 rounded once per channel,
 * then as the plain kernels: a product rounded, added in member order) whenever that
 * reads fewer bytes than base + Σ_{ω_i ≠ 0} ω_i·S_i (with desc->ones_weight ω1 ≠ 1: A =
 * base + ω1·Σ S, the members with ω ≠ ω1 weighted by ω − ω1): with most sets on, toggling one reads
 * A and one record row instead of the base and every other set's. Still one write per
 * receiver and no read of the output; the choice is a function of the weights, so a
 * receiver's value depends on the current weights alone (no drift), and every path
 * (AVX, portable, streaming, parts, ub_blend_row) gives the same bits. The two forms
 * differ by float rounding: |difference| ≤ γ_{k+2}·(|A| + |base| + Σ (|ω_i| + |ω_i − 1|
 * + 1)·|S_i|) per value, γ_n = n·2^-24/(1 − n·2^-24). */
#define UB_BLEND_ONES_SUM 128u
/* The bytes of one UB_BLEND_STORE_Q8 record row of `stride` values: 3 halves, the
 * exponent byte, stride − 3 bytes, padded to a multiple of 4. */
size_t ub_blend_q8_row_bytes(uint32_t stride);
/* A row as a UB_BLEND_STORE_Q8 engine keeps it, decoded: out = the values the blend adds
 * (weighted) for in (stride finite values, the first 3 within the half range). in and
 * out may be the same array. */
void ub_blend_q8_row(uint32_t stride, const float *in, float *out);

typedef enum ub_blend_storage {
  UB_BLEND_FLOAT32 = 0, /* record values are float */
  UB_BLEND_FLOAT16 = 1  /* record values are IEEE binary16 (runtime/half.h), uint16_t */
} ub_blend_storage;

typedef struct ub_blend_record {
  const uint32_t *receivers; /* count indices, strictly increasing, < receiver_count */
  const void *values;        /* count × stride values (desc storage), naturally aligned */
  uint32_t count;            /* 0 is allowed: the element touches nothing */
} ub_blend_record;

typedef struct ub_blend_desc {
  const char *name;          /* for messages, e.g. "lightmap texels"; may be NULL */
  uint32_t receiver_count;
  uint32_t stride;           /* floats per receiver: 12 (SH L1 × RGB), 27 (SH L2 × RGB) */
  const float *base;         /* receiver_count × stride, finite (W/(m²·sr)) */
  ub_blend_storage storage;  /* of every record's values */
  uint32_t element_count;
  const ub_blend_record *elements; /* element_count records; element id = index */
  uint32_t flags;            /* 0, or UB_BLEND_PORTABLE | UB_BLEND_OWN_BASE |
                                UB_BLEND_STORE_HALF or UB_BLEND_STORE_Q8 |
                                UB_BLEND_ROW_QUERY | UB_BLEND_BASE_HALF and
                                UB_BLEND_ONES_SUM (with UB_BLEND_OWN_BASE) |
                                UB_BLEND_NO_AVX2 */
  float ones_weight;         /* UB_BLEND_ONES_SUM: the weight ω1 (all three channels) the
                                sums are kept at, finite, non-zero; 0 means 1 (a caller
                                whose records are stored ÷ a scale s passes s) */
} ub_blend_desc;

/* Counters of one update (all for that call only). */
typedef struct ub_blend_stats {
  uint32_t groups;          /* groups recomputed (or put back at the reference) */
  uint32_t groups_base;     /* of which all weights were 0: base rows copied */
  uint64_t receivers;       /* receivers written (or reported at the reference), each
                             * exactly once */
  uint64_t bytes_read;      /* base rows (as kept: 2 or 4 bytes a value) + record rows of
                             * non-zero members + group tables; a group from its all-ones
                             * sums: those (4 bytes a value) + the rows of the members
                             * whose weight is not ω1 */
  uint64_t bytes_written;   /* rows stored to out_values: receivers × stride × 4 (0 when
                             * streaming) */
  uint64_t receivers_reference; /* of receivers: at the reference state, reported as
                                 * UB_BLEND_AT_REFERENCE, not computed (0 without one) */
  uint64_t receivers_base;  /* of receivers: every weight 0, reported as UB_BLEND_AT_BASE
                             * (ub_blend_set_base_report), not streamed */
} ub_blend_stats;

/* What create built (for reports, `ubake info` and benchmarks). */
typedef struct ub_blend_info {
  uint32_t receiver_count;
  uint32_t stride;
  uint32_t element_count;
  uint32_t touched_receivers; /* receivers with ≥ 1 element */
  uint32_t max_overlap;       /* largest combination size */
  uint32_t group_count;
  uint32_t run_groups;        /* groups stored as runs (the rest as lists) */
  uint64_t runs;              /* runs over all run groups */
  uint64_t memberships;       /* Σ record counts */
  size_t engine_bytes;        /* the engine's tables, weights, scratch, own base rows */
  size_t record_bytes;        /* the engine's copy of the record values (memberships ×
                                 row_bytes), not in engine_bytes */
  uint32_t row_bytes;         /* bytes per record row: stride × 2 or 4, or
                                 ub_blend_q8_row_bytes(stride) (UB_BLEND_STORE_Q8) */
  float base_scale;           /* UB_BLEND_BASE_HALF: the base rows' scale, else 1 */
} ub_blend_info;

/* Reports the receivers an update just recomputed (ub_blend_mark_part: would recompute,
 * rows NULL): [first, first + count), whose final
 * rows are rows[0 .. count × stride) (= out_values + first × stride, or when streaming a
 * scratch or base rows valid during the call only). Called in ascending group order,
 * right after the rows are computed (cache-hot: re-encode AHD here); every recomputed
 * receiver is reported exactly once, in pieces of consecutive receivers. When streaming,
 * consecutive pieces (of one run, or of groups whose receivers continue each other) are
 * handed over together, up to 32 receivers a call; receivers at the reference state
 * (ub_blend_set_reference, rows UB_BLEND_AT_REFERENCE) come as whole stretches of a
 * group's units, never joined with computed rows. */
typedef void (*ub_blend_touched_fn)(void *user, uint32_t first, uint32_t count,
                                    const float *rows);

/* rows of a touched call for receivers at the reference state (ub_blend_set_reference). */
extern const float ub_blend_at_reference[1];
#define UB_BLEND_AT_REFERENCE (ub_blend_at_reference)
/* rows of a touched call for receivers whose elements' weights are all 0
 * (ub_blend_set_base_report). */
extern const float ub_blend_at_base[1];
#define UB_BLEND_AT_BASE (ub_blend_at_base)

typedef struct ub_blend ub_blend;

/* Validates desc (stride, sorted unique in-range indices, finite base and values), builds
 * the groups and, if out_values is not NULL, copies base into it (receiver_count × stride
 * floats). Errors: UB_ERR_INVALID_ARGUMENT (NULL pointers, bad stride or storage, or
 * UB_BLEND_BASE_HALF without UB_BLEND_OWN_BASE),
 * UB_ERR_INVALID_DATA (records or base), UB_ERR_OUT_OF_MEMORY; one message to log naming
 * desc->name, the element and the position. */
ub_result ub_blend_create(const ub_blend_desc *desc, const ub_log *log, float *out_values,
                          ub_blend **out_blend);
/* ub_blend_create, calling values_done(user, e) once element e's values are copied (create
 * reads them no more; in element order), so a caller can free each while the next are
 * copied (the values of elements it was not told of, after a failure, are still its own):
 * the run-time held the full ESTATE file's texel records twice while the copy was made
 * (146 MB). */
ub_result ub_blend_create_ex(const ub_blend_desc *desc, const ub_log *log, float *out_values,
                             void (*values_done)(void *user, uint32_t element), void *user,
                             ub_blend **out_blend);
void ub_blend_free(ub_blend *b);

/* Sets element's RGB weight (finite, any sign; typical 0..1 × tint). Marks the element
 * dirty only if the value changed (0 and -0 compare equal). UB_ERR_INVALID_ARGUMENT for
 * an element out of range or a non-finite weight (nothing changes). */
ub_result ub_blend_set_weight(ub_blend *b, uint32_t element, const float rgb[3]);
/* The element's current weight (0 for an element out of range). */
void ub_blend_weight(const ub_blend *b, uint32_t element, float out_rgb[3]);
/* Whether the element's weight changed since the last ub_blend_update_begin (the next
 * update recomputes its groups); 0 for an element out of range. */
int ub_blend_element_dirty(const ub_blend *b, uint32_t element);

/* Recomputes every group holding a dirty element, writes those receivers' rows of
 * out_values (the array given to create; NULL: streaming, then touched is required),
 * calls touched (may be NULL otherwise) for them, clears the dirty marks. out_stats may
 * be NULL. Cost ∝ the receivers of the changed elements. */
void ub_blend_update(ub_blend *b, ub_blend_touched_fn touched, void *user,
                     float *out_values, ub_blend_stats *out_stats);
/* The same for every group (every touched receiver), dirty or not. */
void ub_blend_update_all(ub_blend *b, ub_blend_touched_fn touched, void *user,
                         float *out_values, ub_blend_stats *out_stats);

/* Parallel updates (a job system's threads; the engine starts none):
 *   ub_blend_update_begin(b, all) collects the groups to recompute (those of dirty
 *   elements, or with all != 0 every group), clears the dirty marks and takes the weights;
 *   ub_blend_update_part(b, p, parts, …) for every p < parts recomputes part p of them:
 *   about a parts-th of their rows, in the plain update's order (ascending groups; a
 *   group may be cut at a receiver between two parts); the parts may run on different
 *   threads at once (they write disjoint receivers and use their own scratch; touched is
 *   called from the part's thread); parts ≤ the parts reserved with
 *   ub_blend_reserve_parts (1 after create).
 * Every receiver gets the same bits whatever the split: a receiver's operations depend
 * only on its group's members and weights, never on where a part starts. No weight may change and no other
 * update may start until every part has returned. ub_blend_update() is begin + the one
 * part of 1; the stats of the parts add up to a plain update's. */
#define UB_BLEND_MAX_PARTS 256
/* Scratch for `parts` parts (kept until free; counted in engine_bytes). Errors:
 * UB_ERR_INVALID_ARGUMENT (0 or > UB_BLEND_MAX_PARTS), UB_ERR_OUT_OF_MEMORY (the parts
 * reserved before stay usable). */
ub_result ub_blend_reserve_parts(ub_blend *b, uint32_t parts);
void ub_blend_update_begin(ub_blend *b, int all);
void ub_blend_update_part(const ub_blend *b, uint32_t part, uint32_t parts,
                          ub_blend_touched_fn touched, void *user, float *out_values,
                          ub_blend_stats *out_stats);

/* Part `part` of the update begun, without computing: touched(user, first, count, NULL)
 * for every receiver update_part would recompute, once each (in pieces of consecutive
 * receivers of one group, each as long as the group's units allow: not update_part's
 * pieces; groups in ascending order), so a caller can compute them later with ub_blend_row
 * (under the weights taken at begin: UB_BLEND_ROW_QUERY). Stats: groups and receivers as
 * update_part's (groups_base 0), bytes_read the group tables only, nothing written. */
void ub_blend_mark_part(const ub_blend *b, uint32_t part, uint32_t parts,
                        ub_blend_touched_fn touched, void *user, ub_blend_stats *out_stats);
/* The receivers of a group kept as a list (scattered receivers, e.g. GLG probes), count ≥
 * 1 of them in ascending order, valid during the call only. */
typedef void (*ub_blend_listed_fn)(void *user, const uint32_t *receivers, uint32_t count);
/* ub_blend_mark_part, but a list group's receivers of the part go to listed (when not
 * NULL) in one call instead of to touched in pieces (one a receiver unless consecutive):
 * every receiver still reported once, to one of the two, groups in ascending order. */
void ub_blend_mark_part_ex(const ub_blend *b, uint32_t part, uint32_t parts,
                           ub_blend_touched_fn touched, ub_blend_listed_fn listed, void *user,
                           ub_blend_stats *out_stats);

/* The first work item (a group to recompute, in the update's ascending order) of part
 * `part` of `parts` of the update begun (part == parts: the work's size). Part p reaches
 * from item first(p) to item first(p + 1) inclusive when a group is cut between them, so
 * it touches at most first(p + 1) − first(p) + 1 groups, and all parts together at most
 * groups + parts. */
uint32_t ub_blend_part_first(const ub_blend *b, uint32_t part, uint32_t parts);

/* The reference state: a streaming caller that keeps its own product of the rows (the
 * run-time: the AHD texels) as they are now can have them back instead of a re-blend.
 * ub_blend_set_reference() takes the current weights as the reference (the weights of the
 * last update: UB_ERR_INVALID_ARGUMENT while a weight changed since, nothing then
 * changes; UB_ERR_OUT_OF_MEMORY; not between ub_blend_update_begin and the end of its
 * parts, which the engine cannot tell: the weights begin took would become the reference
 * and the parts would skip their groups). It drops rows kept by
 * ub_blend_set_reference_rows. From then on a streaming update (out_values NULL)
 * computes no group whose members' weights all equal their reference weights (== per
 * channel): it reports its receivers to touched with rows = UB_BLEND_AT_REFERENCE (in the
 * same order and pieces as mark_part, a pending stream handed over first), and the caller
 * puts back what it kept. Exact: a receiver's value is a function of its group's weights
 * alone (above), so its rows at those weights are the bits it had at the reference.
 * Updates with out_values compute every group as before (but see _rows below). Memory: 13
 * bytes an element. */
ub_result ub_blend_set_reference(ub_blend *b);
/* The same for a caller that updates with out_values: the engine also keeps the touched
 * receivers' rows of out_values (the array its updates write) as they are now (stride ×
 * 4 bytes a touched receiver; needs UB_BLEND_OWN_BASE, else UB_ERR_INVALID_ARGUMENT), and
 * an update with out_values copies them back for the groups at the reference instead of
 * computing them (touched then gets those rows in out_values, as usual). */
ub_result ub_blend_set_reference_rows(ub_blend *b, const float *out_values);
/* The base state: a streaming caller that keeps its own product of every touched
 * receiver's base rows (the run-time: the AHD texels with every set off) can have them
 * instead of the base rows. With on, a streaming update (out_values NULL) streams no
 * group whose members' weights are all 0 (a group at the reference state stays a
 * reference report): it reports its receivers to touched with rows = UB_BLEND_AT_BASE (in
 * the same order and pieces as mark_part, a pending stream handed over first), and the
 * caller puts back its product of the base rows. Exact: such a group's rows are its base
 * rows, whatever the other weights. Turning a set off is then a copy wherever no other
 * set overlaps it. Updates with out_values are unchanged. Off by default. */
void ub_blend_set_base_report(ub_blend *b, int on);
/* The caller's work per receiver an update hands it (e.g. the run-time's AHD encode of a
 * texel), in the units update_begin counts the blend's own work in (about a CPU cycle: a
 * record row read is 2; at most 1000; 0 by default), when it splits the work into parts
 * of equal cost. Only where the parts are cut depends on it, never a receiver's bits. */
void ub_blend_set_receiver_cost(ub_blend *b, uint32_t cost);
/* 1 while a weight changed since the last update (ub_blend_set_reference refuses then);
 * 0 from ub_blend_update_begin on, before its parts have run too. */
int ub_blend_pending(const ub_blend *b);

/* Receiver r's row as the last update (or create) left it: base + Σ ω_i·S_i under the
 * weights taken at the last ub_blend_update_begin (an update that only marked, too), with
 * the update's operations in its order (the same bits as the row it wrote or streamed),
 * into out_row (stride floats). Needs UB_BLEND_ROW_QUERY
 * at create. Returns 1, or 0 (out_row untouched) for a receiver no element touches when
 * the engine owns its base rows (UB_BLEND_OWN_BASE: it keeps none for those), r out of
 * range or no UB_BLEND_ROW_QUERY. Cost: a binary search over the units (one read with the
 * direct map, below) and one row per non-zero member. Reads only: safe to call between updates from several threads. */
int ub_blend_row(const ub_blend *b, uint32_t r, float *out_row);

void ub_blend_get_info(const ub_blend *b, ub_blend_info *out_info);
/* The engine's bytes besides the record values (= info.engine_bytes). */
size_t ub_blend_memory_bytes(const ub_blend *b);

#ifdef __cplusplus
}
#endif
#endif
