/* ubake/glg.h — global light grid (GLG) at run time: tetrahedral probe mesh, point
 * location, barycentric SH interpolation and irradiance queries.
 *
 * The GLG is a Delaunay tetrahedralisation of radiance probes (SH L2, ubake/sh.h) placed
 * over the whole level. For a point p the run-time finds the tet containing p by walking
 * from a caller-held cache (the previous tet of the same object), interpolates the four
 * probes' SH barycentrically and convolves with the cosine lobe for a normal.
 *
 *   - Point location: walk from *inout_tet_cache across the face with the most negative
 *     barycentric (never straight back); each tet's barycentric matrix and origin are
 *     precomputed in a 64-byte record with its neighbours, so one step is one cache line
 *     (the neighbours' records are requested as soon as it arrives).
 *     If the cache is invalid (UB_GLG_NO_CACHE) or far from p (beyond two grid cells and
 *     outside the cached tet grown by 20% about its centroid), the walk starts from a
 *     start grid built at init (4 cells per probe, each holding the tet at its centre
 *     as a 16-bit offset from a base tet per 4 × 4 × 4 cells: ~8 B per probe).
 *     After walk_cap steps (4·cbrt(tets) + 64) it falls back to a brute-force scan.
 *   - Outside the probes' convex hull: p is projected onto the hull (closest point on the
 *     closest hull face, found by a local search over hull faces with a brute-force
 *     fallback) and interpolated there. Projection onto a convex set is continuous, so
 *     results are continuous everywhere and bounded by the probe values.
 *   - Robustness: barycentrics are clamped to [0, 1] and renormalised; badly shaped tets
 *     (|det| < 1e-3 × longest edge³, ~0.4% of a random Delaunay mesh) are evaluated in double, singular ones by their
 *     closest face; non-finite p gives the cached tet's centroid. Nothing returns NaN.
 *   - Leak control (Iwanicki & Sloan 2017), two optional hooks, both may be NULL:
 *     corner_visible (tet × 4) weights each corner of each tet, 0 = probe hidden from the
 *     tet's interior, 255 = fully visible; leak planes (the .ubk GLGP section, baked by
 *     probes/leak.c) give a tet one plane n·x + d = 0 and only the corners on the query
 *     point's side of it are used (a corner on the plane counts for both sides).
 *     Interpolation uses w_i = λ_i·vis_i·side_i / Σ_j λ_j·vis_j·side_j, falling back to
 *     plain λ when every weight is 0.
 *   - Windowing: probe SH as stored in the .ubk is raw. ub_glg_query windows the
 *     interpolated SH (ub_sh2_window: a few ns when it is smooth, ~15 µs when it rings)
 *     before the cosine convolution, then clamps at 0. If the caller windowed every probe
 *     itself (sh_windowed = 1) the query skips it: a convex combination of windowed probes
 *     is already non-negative for every normal. ub_glg_sample returns the raw
 *     interpolation (radiance, as the LLG resample needs it).
 *   - Lazy windowing (ub_glg_enable_lazy): when probes change at run time (dynamic light
 *     sets), the updater only marks them stale (ub_glg_mark_stale); the first query that
 *     reads a stale probe windows its raw SH (ub_sh2_window, up to a few µs when it rings)
 *     and writes it back, so an update costs no windowing and only probes something
 *     looks at are ever windowed. The same bits as windowing every probe at once.
 *   - Lazy blending (compact store; ub_glg_set_row_source, ub_glg_mark_unblended): an
 *     update need not even compute the changed probes' rows; it marks them, and the first
 *     query that reads one asks the row source (the run-time: its blend engine's row
 *     query) and stores the row and its window. ESTATE scale: a room set's toggle no
 *     longer blends its ~8,000 GLG probes (a quarter of the toggle); a query reading a
 *     marked probe pays ~0.25–0.37 µs more for it, once.
 *
 *   - Compact probe store (desc.compact = 1, what the run-time uses): 58 B per probe.
 *     Each probe's RAW SH is kept in IEEE half times a per-probe power of two 2^e (the
 *     largest coefficient near 2^14, so dark probes next to bright ones keep 11 bits),
 *     plus one 32-bit word: e, the probe's window and a stale bit (or one of two
 *     reserved values while a probe is marked for lazy blending or being filled). The window of a
 *     channel is ub_sh2_window's, as one parameter τ ∈ [0, 2] (w1 = 1 − τ/2, w2 =
 *     max(0, 1 − τ): its two phases as one curve) stored in 7 bits, code = 128·τ/2
 *     rounded UP (127: w1 = w2 = 0) (for a non-negative radiance every τ between the channel's own and 1
 *     keeps its irradiance ≥ 0: the minimum over normals is concave in τ); the code is
 *     then checked on the stored values with ub_sh2_irradiance_min and raised until the
 *     channel passes (at 127 only its DC term is left). A channel that is not finite or
 *     has DC ≤ 0 is zeroed (3 bits). The query applies the windows while interpolating:
 *     corner i contributes λ_i·((2^e_i·w_band,c)·h), the bracket exact, one product more per
 *     coefficient than plain half SH. Windows are found lazily: ub_glg_set_probes stores new
 *     raw rows and marks them stale, the first query that reads a stale probe finds its
 *     window (a few µs when it rings) and publishes the word with one atomic
 *     compare-and-swap (a stale probe's rows are never written by queries, so readers
 *     never see a torn row; a marked probe's rows (lazy blending) are written by the one
 *     query that claims its word, and its word is published after them (release): a query
 *     reading the probe meanwhile waits for it). Probe positions are not kept: only hull faces' and badly shaped tets'
 *     corners (the walk records hold the rest).
 *
 *   - Speed: one query = the cached-tet test (or a walk), leak weights, a 4 × 27
 *     interpolation (AVX when the CPU has it, else SSE2; the same bits) and the cosine
 *     convolution. Random points are bound by the walk's dependent cache misses;
 *     ub_glg_query_batch overlaps them across queries. Probe SH may be float or half
 *     (sh_half, F16C; with a per-probe power-of-two exponent, 55 B/probe).
 *
 * Lifecycle: ub_glg_init builds the owned acceleration data; ub_glg_release frees it
 * (NULL-safe, idempotent). Borrowed arrays (positions, sh, tets, leak data) must
 * outlive the ub_glg and keep their values (sh may be updated in place by the run-time,
 * with finite, windowed values); neigh is only read during init.
 * Thread safety: after init every query is read-only on the ub_glg (except that, with
 * lazy windowing, it may window a stale probe: a per-probe atomic state lets one thread
 * write it back while the others use their own copy; with lazy blending, it may fill a
 * marked probe: one thread writes it, the others wait); each thread passes its own cache.
 * ub_glg_mark_stale, ub_glg_mark_unblended and ub_glg_set_row_source must not run
 * concurrently with queries. Pure C11, part of the
 * run-time library.
 */
#ifndef UBAKE_GLG_H
#define UBAKE_GLG_H

#include <stddef.h>
#include <stdint.h>

#include "ubake/error.h"

#ifdef __cplusplus
extern "C" {
#endif

#define UB_GLG_NO_CACHE 0xFFFFFFFFu /* initial value of a caller's tet cache */

typedef struct ub_glg_desc {
  uint32_t probe_count;
  const float *positions; /* probe_count × 3, metres */
  const float *sh;        /* probe_count × 27, radiance SH L2, W/(m²·sr), windowed; or NULL
                             when sh_half is given */
  const uint16_t *sh_half; /* optional instead of sh: the same in IEEE half (54 B/probe;
                             ~2^-11 relative rounding per coefficient) */
  const int8_t *sh_half_exp; /* with sh_half, optional: probe q's values are
                             sh_half·2^sh_half_exp[q] (55 B/probe: no subnormals in dark
                             probes next to bright ones); NULL: exponent 0 */
  uint32_t tet_count;
  const uint32_t *tets;  /* tet_count × 4 probe indices (either orientation) */
  const int32_t *neigh;  /* tet_count × 4, neigh[4t+i] = tet opposite corner i, −1 on hull */
  const uint8_t *corner_visible; /* tet_count × 4 visibility weights 0..255, or NULL */
  uint32_t leak_plane_count;
  const float *leak_planes;       /* leak_plane_count × 4: unit normal, d; or NULL */
  const uint32_t *leak_plane_of;  /* tet_count: plane index or UB_GLG_NO_LEAK_PLANE; or NULL */
  int sh_windowed;                /* 1: every probe's sh already went through ub_sh2_window */
  int compact; /* 1: the GLG keeps its own compact probe store (below) made from sh (raw,
                  float; sh_windowed 0; sh_half NULL), read during init only */
  int small_walk; /* 1: no 64-byte walk record per tet (its inverse edge matrix, origin
                     and links): the links alone (16 B a tet) and a copy of the positions
                     (12 B a probe), barycentrics computed from the corners in double at
                     each step; 48 B a tet less (full ESTATE: −57 MiB), queries slower
                     (README "Small GLG walk") */
} ub_glg_desc;

#define UB_GLG_NO_LEAK_PLANE 0xFFFFFFFFu

typedef struct ub_glg_tet ub_glg_tet;   /* private: 64-byte per-tet walk record */
typedef struct ub_glg_hull ub_glg_hull; /* private: one hull face */

/* A probe's current raw SH (27 floats, finite) for the compact store's lazy blending
 * (ub_glg_set_row_source): returns 1, or 0 when it has none (the probe is then zero). Called
 * from queries, on any thread at once: it must only read. */
typedef int (*ub_glg_row_fn)(void *user, uint32_t probe, float out[27]);

typedef struct ub_glg {
  /* borrowed (see ub_glg_desc; positions are read during init only, small_walk copies them) */
  uint32_t probe_count;
  const float *sh;
  const uint16_t *sh_half; /* non-NULL: probes read from here instead of sh */
  const int8_t *sh_half_exp;
  uint32_t tet_count;
  const uint32_t *tets;
  const uint8_t *corner_visible;
  uint32_t leak_plane_count;
  const float *leak_planes;
  const uint32_t *leak_plane_of;
  int sh_windowed;
  /* owned, built by ub_glg_init */
  ub_glg_tet *tet_data;  /* per tet: inverse edge matrix, origin, neighbours/hull links;
                            NULL with small_walk: */
  int32_t *tet_nb;       /* small_walk: per tet the four links (as the record's) ... */
  float *pos;            /* ... and every probe's position (probe_count × 3) */
  uint8_t *tet_flags;    /* per tet: 0 normal, 1 ill-conditioned (double), 2 singular */
  uint8_t *leak_drop;    /* per tet with a leak plane: corners dropped on each side */
  uint32_t hull_count;
  ub_glg_hull *hull;     /* hull faces with hull-surface adjacency and corner positions */
  uint32_t *ill_ids;     /* the ill-conditioned and singular tets, ascending ... */
  float *ill_pos;        /* ... and their corners' positions (12 floats each) */
  uint32_t *start_grid;  /* start grid: a base tet per 4 × 4 × 4 cells, then ... */
  int16_t *start_delta;  /* ... per cell, the tet at its centre − its block's base (in the
                            same allocation as start_grid) */
  uint32_t grid_dim[3];
  float grid_lo[3], grid_inv_cell[3], grid_far2; /* far2: squared "far from cache" radius */
  uint32_t walk_cap;      /* steps before the brute-force fallback */
  uint32_t ill_tet_count; /* tets evaluated in double / singular */
  uint32_t singular_tet_count;
  int simd;               /* 1: AVX (+F16C for sh_half) interpolation, checked at init */
  /* lazy windowing (ub_glg_enable_lazy): windowed rows written back (== sh), raw rows
   * windowed from, per-probe state (private: atomic, 0 windowed, 1 stale, 2 being
   * written back) */
  float *sh_win;
  const float *sh_raw;
  void *stale;
  /* compact probe store (desc.compact): per probe 27 halves (raw SH · 2^−e) and a 32-bit
   * word (private: atomic; exponent e, window code, zeroed channels, stale bit) */
  uint16_t *cp_rows;
  void *cp_word;
  /* compact store, lazy blending (ub_glg_set_row_source): where a marked probe's raw SH
   * comes from */
  ub_glg_row_fn row_fn;
  void *row_user;
} ub_glg;

/* Optional diagnostics of one locate. */
typedef struct ub_glg_locate_info {
  uint32_t steps;      /* tets visited by the walk */
  uint32_t hull_steps; /* hull faces visited by the outside projection */
  uint8_t outside;     /* p was outside the hull and was projected onto it */
  uint8_t fallback;    /* the walk hit walk_cap (or the hull search failed): brute force */
  uint8_t from_grid;   /* the walk started from the start grid, not the cache */
} ub_glg_locate_info;

/* Validates desc (hostile data: index ranges, neighbour symmetry, finite values, closed
 * hull) and builds the owned data. On failure g is zeroed and nothing leaks.
 * Errors: UB_ERR_INVALID_ARGUMENT (NULLs, zero counts), UB_ERR_INVALID_DATA (message names
 * the tet/probe), UB_ERR_OUT_OF_MEMORY. */
ub_result ub_glg_init(ub_glg *g, const ub_glg_desc *desc, const ub_log *log);
void ub_glg_release(ub_glg *g);

/* Tet for p (metres) and its barycentrics out_bary (Σ = 1, each in [0, 1]; for p outside
 * the hull, the barycentrics of p's projection onto a hull face of that tet).
 * inout_tet_cache: the caller's cache, UB_GLG_NO_CACHE initially, updated; an opaque value
 * (a tet, or a hull face while p stays outside), valid only for this ub_glg. NULL: none. */
uint32_t ub_glg_locate(const ub_glg *g, const float p[3], uint32_t *inout_tet_cache,
                       float out_bary[4]);
uint32_t ub_glg_locate_ex(const ub_glg *g, const float p[3], uint32_t *inout_tet_cache,
                          float out_bary[4], ub_glg_locate_info *out_info);

/* Interpolated radiance SH L2 at p (27 floats, W/(m²·sr)), with leak-control weights;
 * not windowed (see above). */
void ub_glg_sample(const ub_glg *g, const float p[3], uint32_t *inout_tet_cache,
                   float out_sh[27]);

/* Irradiance (W/m², ≥ 0) at p for unit normal n, from the windowed interpolated SH (a
 * non-unit n is normalised; a zero or non-finite n gives the mean irradiance π·Y00·L00). */
void ub_glg_query(const ub_glg *g, const float p[3], const float n[3],
                  uint32_t *inout_tet_cache, float out_rgb[3]);

/* A moving object's cursor: its tet cache and, with the compact store, the windowed rows
 * of that tet's four probes, so consecutive queries in one tet read 4 × 27 floats instead
 * of decoding and windowing the probes (the same bits as ub_glg_query); with the small
 * walk also that tet's barycentric rows, so they are not recomputed from its corners at
 * every query. Valid for one ub_glg; ub_glg_set_probes and ub_glg_mark_unblended make its
 * rows stale (a generation count). 568 bytes.
 * Initialise with ub_glg_cursor_init. Thread safety: one cursor per thread, like a tet
 * cache. */
typedef struct ub_glg_cursor {
  uint32_t tet;        /* the tet cache (as inout_tet_cache) */
  uint32_t rows_tet;   /* the tet whose rows are held, UB_GLG_NO_CACHE: none */
  uint32_t generation; /* the store's generation they are from */
  uint32_t geo_tet;    /* small walk: the well-shaped tet whose geometry geo holds, or
                          UB_GLG_NO_CACHE */
  float rows[4][28];
  double geo[13];      /* small walk: the tet's cofactor rows (3 × 3), 1 / det, corner 0 */
} ub_glg_cursor;
void ub_glg_cursor_init(ub_glg_cursor *c);
/* ub_glg_query through a cursor (any store; without the compact one, only its tet). */
void ub_glg_query_cursor(const ub_glg *g, const float p[3], const float n[3], ub_glg_cursor *c,
                         float out_rgb[3]);

/* count queries at once (points, normals: count × 3; out_rgb: count × 3), the same answers
 * as count calls of ub_glg_query. inout_tet_caches: count caches (each as above) or NULL
 * (every walk starts from the start grid). Many independent queries (particles, a frame's
 * dynamic objects) go ~2–4× faster this way than one by one: their cache misses overlap. */
void ub_glg_query_batch(const ub_glg *g, uint32_t count, const float *points,
                        const float *normals, uint32_t *inout_tet_caches, float *out_rgb);

/* Resamples the GLG at the nx × ny × nz grid points of an oriented box (the dynamic LLG
 * atlas of a moving object). Grid points span the box corner to corner:
 *   p(ix,iy,iz) = center + Σ_a s_a·half_extents[a]·axes[a], s_a = −1 + 2·i_a/(n_a − 1)
 * (s_a = 0 when n_a = 1). axes: 3 unit vectors (rows). out_sh: nx·ny·nz × 27 floats,
 * index ix + nx·(iy + ny·iz). Points are visited in serpentine order so the walk stays
 * coherent; inout_tet_cache may be NULL. Errors: UB_ERR_INVALID_ARGUMENT. */
ub_result ub_glg_resample_llg(const ub_glg *g, const float center[3], const float axes[9],
                              const float half_extents[3], uint32_t nx, uint32_t ny,
                              uint32_t nz, uint32_t *inout_tet_cache, float *out_sh);

/* Lazy windowing for a GLG initialised with float sh and sh_windowed = 1: win is the
 * writable array desc.sh pointed to (every probe windowed now, or marked stale before the
 * first query), raw the probes' raw SH
 * (probe_count × 27, finite), both borrowed and kept. Afterwards the caller changes raw
 * rows and calls ub_glg_mark_stale for them (not concurrently with queries); queries window
 * stale probes as they read them. Errors: UB_ERR_INVALID_ARGUMENT (half SH, not windowed,
 * NULLs), UB_ERR_OUT_OF_MEMORY (g unchanged). */
ub_result ub_glg_enable_lazy(ub_glg *g, float *win, const float *raw);
/* Probes [first, first + count) have new raw SH. */
void ub_glg_mark_stale(ub_glg *g, uint32_t first, uint32_t count);
/* Windows every stale probe now (e.g. before handing the whole windowed array out); safe
 * with concurrent queries (it waits for a row another query is writing back). Returns how
 * many it found stale. */
uint32_t ub_glg_refresh(const ub_glg *g);

/* Compact store only: probes [first, first + count) have new raw SH (count × 27 floats;
 * a channel with a non-finite value is stored as zero); they are marked stale. Not
 * concurrently with queries; distinct ranges may be set from different threads at once. */
void ub_glg_set_probes(ub_glg *g, uint32_t first, uint32_t count, const float *rows);

/* Compact store only, lazy blending: the probes' raw SH comes from fn (see ub_glg_row_fn)
 * for every probe marked with ub_glg_mark_unblended. Set it once, before queries. */
void ub_glg_set_row_source(ub_glg *g, ub_glg_row_fn fn, void *user);
/* Compact store only: probes [first, first + count) have new raw SH that the row source
 * gives; the store's rows are not written now. The first query (or ub_glg_probe_sh,
 * ub_glg_refresh) that reads such a probe asks the row source for its row, stores it and
 * its window (one thread writes; a query reading the probe meanwhile waits for it, ~0.1–
 * a few µs), so an update costs one word per probe and only probes something reads are
 * ever blended: the same bits as ub_glg_set_probes with those rows. Not concurrently with
 * queries; distinct ranges may be marked from different threads at once. */
void ub_glg_mark_unblended(ub_glg *g, uint32_t first, uint32_t count);
/* The same for the count probes listed (each < the probe count; any order, repeats
 * allowed): one call for a scattered set instead of one a probe. */
void ub_glg_mark_unblended_list(ub_glg *g, const uint32_t *probes, uint32_t count);

/* Probe v's SH as a query reads it: windowed = 1 the windowed row (a stale probe is
 * windowed now, a marked one blended (its row source asked) and windowed now, with either
 * value of windowed; compact store: (2^e·w_band)·h per coefficient), 0 the raw row (float
 * store: desc.sh / the lazy raw rows; half stores: decoded). Thread safe like queries. */
void ub_glg_probe_sh(const ub_glg *g, uint32_t v, int windowed, float out[27]);

/* Bytes owned by g (per-tet records, flags, hull, start grid, compact store). */
size_t ub_glg_owned_bytes(const ub_glg *g);

/* What a query reads, in bytes, borrowed and owned (the run-time's other copies of the
 * probe SH, e.g. the raw blend state, are the caller's to add). */
typedef struct ub_glg_memory {
  size_t positions;    /* kept corner positions: badly shaped tets × 52, in hull faces × 36 */
  size_t sh;           /* probes × 108 (float) or × 54 (half; + 1 with exponents; compact
                          store + 4: exponent, window, stale) */
  size_t walk_records; /* tets × 64: barycentric matrix, origin, neighbours */
  size_t tet_corners;  /* tets × 16 (borrowed tets) */
  size_t tet_flags;    /* tets × 1 */
  size_t leak;         /* tets × (4 plane index + 1 sides) + planes × 16 (+ tets × 4 vis) */
  size_t hull;         /* hull faces × 32 (their positions in .positions) */
  size_t start_grid;   /* cells × 2 + blocks of 4 × 4 × 4 cells × 4 */
  size_t total;
} ub_glg_memory;
void ub_glg_memory_usage(const ub_glg *g, ub_glg_memory *out);

#ifdef __cplusplus
}
#endif
#endif
