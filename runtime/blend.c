/* runtime/blend.c — run-time blend engine: base + Σ ω_i·S_i, grouped by combination of
 * overlapping elements (paper §3.3). See runtime/blend.h. */
#include "runtime/blend.h"

#include <assert.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "runtime/bigalloc.h"
#include "runtime/cpu.h"
#include "runtime/fpmode.h"
#include "runtime/half.h"

#if defined(__SSE2__)
#include <emmintrin.h>
#define BLEND_SSE2 1
#else
#define BLEND_SSE2 0
#endif
/* Hardware half conversion (F16C), chosen at run time: GCC/clang on x86. */
#if BLEND_SSE2 && defined(__GNUC__) && (defined(__x86_64__) || defined(__i386__))
#include <immintrin.h>
#define BLEND_F16C 1
#else
#define BLEND_F16C 0
#endif

#if defined(__GNUC__)
#define BLEND_INLINE static inline __attribute__((always_inline))
#else
#define BLEND_INLINE static inline
#endif

/* Specialised kernels exist for up to this many non-zero members; more use the generic
 * one (same operations in the same order, so the same bits). */
#define BLEND_SPECIALISED 8
/* update_begin's element lists (see ub_blend.few): their longest, and the fewest members a
 * group needs to search them instead of reading every member's flags */
#define BLEND_FEW 8
#define BLEND_FEW_MIN_K 8

/* Streaming mode (no out array): rows are blended into an L1-sized scratch of this many
 * receivers and handed to the callback. 32 rather than 64: the run-time's AHD re-encode
 * (compute) then alternates with the blend (memory) finely enough to overlap a little more
 * (ESTATE full scale all-sets update 30.4 -> 29.2 ms; 16: 29.4, 8: 32.8). */
#define BLEND_CHUNK 32

/* Half records are decoded to float (exactly) into an L1-sized scratch of this many
 * floats, a chunk of consecutive receivers at a time, then blended by the float kernels:
 * one kernel family, and the decode runs as long vector loops (F16C: 8 per instruction). */
#define BLEND_DECODE_FLOATS 2048

#define GROUP_LIST 0x80000000u /* k_mode bit: receivers stored as a list, else as runs */

/* A group: receivers sharing one combination of k elements (its members, ascending ids).
 * Its receivers, from unit_off in b->units: as runs, per run [first receiver, length]; as
 * a list, per receiver [receiver]. Its record values: member m's rows (S values each) for
 * the group's receivers in order, from row moff[member_off + m] of b->values, which holds
 * each element's rows for its groups in ascending group order, element after element (a
 * run of consecutive receivers is then one flat array per member, and a set's rows over
 * all its groups one stream: a toggle reads it straight through). No record position is
 * kept. A row is rowb bytes: stride halves or floats, or a UB_BLEND_STORE_Q8 row
 * (q8_encode). */
typedef struct blend_group {
  uint64_t unit_off;   /* in units (words) */
  uint32_t member_off; /* first of k element ids in b->members, ascending */
  uint32_t receivers;
  uint32_t units;      /* runs or receivers */
  uint32_t k_mode;     /* k | GROUP_LIST */
  uint32_t base_row;   /* UB_BLEND_OWN_BASE: the group's first row in obase */
  uint32_t ones_row;   /* UB_BLEND_ONES_SUM: its first row in ones, ONES_NONE: none */
} blend_group;

#define ONES_NONE 0xFFFFFFFFu
/* UB_BLEND_ONES_SUM keeps the all-ones sums of the groups of at least this many members:
 * full ESTATE, toggles with the others on (best of 3, one noisy afternoon): none 0.65-0.86
 * ms a room set, 8.5-9.9 a hall set; 4: 0.49-0.56 / 3.7, +43.4 MiB; 6: 0.49-0.51 / 2.9-3.3,
 * +22.5 MiB; 12: 0.58 / 3.3, +11.0 MiB. */
#define BLEND_ONES_MIN_K 6

enum { KERNEL_12, KERNEL_27, KERNEL_ANY };

typedef void (*blend_decode_fn)(const uint16_t *src, float *dst, size_t n);

struct ub_blend {
  uint32_t receiver_count, stride, wstride, element_count, group_count;
  uint32_t value_size, kernel;
  uint32_t q8;          /* UB_BLEND_STORE_Q8: rows of rowb bytes decoded by q8_decode */
  size_t rowb;          /* bytes per record row */
  blend_decode_fn decode; /* half → float, NULL for float records */
  blend_decode_fn bdecode; /* half → float, UB_BLEND_BASE_HALF's base rows */
  uint32_t touched, max_overlap, run_groups;
  uint64_t runs, memberships, unit_words;
  const float *base;     /* the caller's base, NULL with UB_BLEND_OWN_BASE */
  char *obase;           /* UB_BLEND_OWN_BASE: touched receivers' base rows, group order:
                            floats, or (UB_BLEND_BASE_HALF) halves times bscale */
  uint32_t base_size;    /* bytes per base value: 4, or 2 with UB_BLEND_BASE_HALF */
  float bscale;          /* UB_BLEND_BASE_HALF: a power of two ≥ 1, else 1 */
  float *weight;        /* element_count × 3 */
  float *wexp;          /* element_count × wstride: weight[c] at every j ≡ c (mod 3) */
  uint8_t *nonzero;     /* weight != (0, 0, 0) */
  uint8_t *dirty;
  uint32_t *dirty_list;
  uint32_t dirty_count;
  float *wupd; /* element_count × 3: each element's weight at the last update that
                * recomputed its groups (NaN before one): a weight set back to it before
                * the next update is no change (ub_blend_set_weight). Not wlast, which
                * row queries keep and which starts at the create weights (0): an element
                * no update has computed must stay a change (test_blend's base report
                * compares an engine updated at start with one that was not) */
  blend_group *groups;
  uint32_t *members;
  uint32_t *moff;    /* per group member (as members): its first row in values (rows <
                      * 2^32: validate) */
  uint32_t *units;      /* groups' receivers (blend_group) */
  void *values;         /* memberships × stride record values (desc storage), element-major,
                         * each element's in group order (blend_group) */
  uint32_t *elem_off; /* element_count + 1: groups of element e = elem_groups[off[e]…] */
  uint32_t *elem_groups;
  uint32_t *stamp; /* per group, the update epoch that collected it */
  uint32_t epoch;
  uint32_t *work;  /* group ids of one update, ascending (ub_blend_update_begin) */
  uint32_t work_count;
  uint64_t *wcost; /* group_count + 1: prefix sums of the work's costs (parts' split) */
  size_t dec_floats; /* max(BLEND_DECODE_FLOATS, max_overlap × stride), half records */
  /* Per part of an update (job_cap of them; part 0's made at create). */
  struct blend_scratch *js;
  uint32_t job_cap;
  /* AVX + F16C path (chosen at create): weight patterns. */
  int avx;
  int avx2;             /* and AVX2: 8-bit rows of stride 12 decoded in registers */
  float *wpat;           /* element_count × 32 floats, 32-byte aligned: each element's
                            weight at every lane j as ω[j mod 3] (period 24 = 3 × 8 lanes,
                            8 more for unaligned tails), kept by set_weight */
  /* UB_BLEND_ROW_QUERY: every unit (a run, or a list group's receiver) by its first
   * receiver, and the weights the rows were last computed with. */
  struct blend_unit_ref *rmap;
  uint64_t rmap_count;
  /* and, when it is no larger than rmap (receivers mostly in lists: GLG probes), each
   * receiver's unit in rmap + 1 (0: none), so a row query finds it in one read instead
   * of a binary search's chain of misses */
  uint32_t *rdir;
  float *wlast;         /* element_count × 3 */
  /* UB_BLEND_ONES_SUM: per receiver of a group with ones_row, base + Σ of its members'
   * rows (weights all 1), float, group order; per element ω ≠ (1, 1, 1), and ω − 1 as
   * wexp and wpat hold ω */
  float *ones;
  uint64_t ones_rows;
  uint8_t *notone;
  float *dwexp, *dwpat;
  float ones_w;         /* the weight the sums are kept at (desc ones_weight, 0 → 1) */
  /* ub_blend_set_reference: the reference weights (element_count × 3) and, per element,
   * whether its weight equals them; NULL without a reference */
  float *ref;
  uint8_t *atref;
  /* What update_begin found among all elements, for groups of many members: the elements
   * with ω = 0, with ω ≠ ω1 (all-ones sums) and not at the reference, ascending, when each
   * list has at most BLEND_FEW; `few` 0 otherwise, or once a weight changed since. A group
   * then finds its zero / non-one / moved members by a binary search per listed element
   * instead of reading a flag per member (a hall texel's group has 16-23 members and a
   * toggle changes one of them). */
  int few;
  uint32_t few_n[3];
  uint32_t few_e[3][BLEND_FEW];
  /* ub_blend_set_reference_rows: the touched receivers' rows at the reference, group
   * order (as obase), float; NULL: none */
  float *refrows;
  int base_report; /* ub_blend_set_base_report */
  uint32_t receiver_cost; /* ub_blend_set_receiver_cost */
  size_t engine_bytes, record_bytes;
};

const float ub_blend_at_reference[1] = {0.0f};
const float ub_blend_at_base[1] = {0.0f};

/* One part's scratch: an update's parts may run on several threads at once. */
typedef struct blend_scratch {
  /* streaming: rows[0 .. pend) hold receivers pend_first.. not yet handed to the callback
   * (pieces of consecutive receivers, adjacent groups' too, go over together); written
   * per chunk by the part's thread: first, with a cache line of padding at the end (pad)
   * so parts on other threads never share its line */
  uint32_t pend_first, pend;
  float *rows;           /* BLEND_CHUNK × stride floats, streaming mode */
  float *dec;            /* dec_floats floats: half records without F16C, 8-bit rows */
  float *bdec;           /* BLEND_CHUNK × stride floats: half base rows decoded */
  /* combinations above BLEND_SPECIALISED (max_overlap entries each) */
  uint32_t *act;
  const char **src;
  const float **rowp;
  const float **w;
  /* AVX path: the non-zero members' patterns and values (max(max_overlap, 1)) */
  const float **avx_w;
  const char **avx_src;
  const char **avx_dec; /* UB_BLEND_STORE_Q8: the members' decoded rows in dec */
  char pad[64];
} blend_scratch;

typedef struct blend_unit_ref {
  uint32_t first, len; /* receivers [first, first + len) */
  uint32_t group, pos; /* the group and the position of `first` among its receivers */
} blend_unit_ref;

/* ---- kernels ------------------------------------------------------------------------- */

/* Half → float decoders: all exact (runtime/half.h), so every one gives the same bits. */
static void decode_scalar(const uint16_t *src, float *dst, size_t n)
{
  for (size_t i = 0; i < n; i++)
    dst[i] = ub_half_to_float(src[i]);
}

#if BLEND_SSE2
/* 4 finite halves → floats: the magnitude bits moved to a float's mantissa position and
 * scaled by 2^112 (rebias 15 → 127), subnormal halves included. Exact only without DAZ
 * (half subnormals are float denormals here): updates run with FTZ/DAZ off. */
static void decode_sse2(const uint16_t *src, float *dst, size_t n)
{
  const __m128i sign_mask = _mm_set1_epi32((int)0x80000000u);
  const __m128i mag_mask = _mm_set1_epi32(0x7fff0000);
  const __m128 scale = _mm_castsi128_ps(_mm_set1_epi32(239 << 23)); /* 2^112 */
  size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    __m128i h = _mm_loadl_epi64((const __m128i *)(const void *)(src + i));
    __m128i x = _mm_unpacklo_epi16(_mm_setzero_si128(), h); /* h << 16 per lane */
    __m128i mag = _mm_srli_epi32(_mm_and_si128(x, mag_mask), 3);
    __m128 f = _mm_mul_ps(_mm_castsi128_ps(mag), scale);
    _mm_storeu_ps(dst + i, _mm_or_ps(f, _mm_castsi128_ps(_mm_and_si128(x, sign_mask))));
  }
  decode_scalar(src + i, dst + i, n - i);
}
#endif

#if BLEND_F16C
__attribute__((target("avx,f16c"))) static void decode_f16c(const uint16_t *src, float *dst,
                                                            size_t n)
{
  size_t i = 0;
  for (; i + 8 <= n; i += 8)
    _mm256_storeu_ps(dst + i,
                     _mm256_cvtph_ps(_mm_loadu_si128((const __m128i *)(const void *)(src + i))));
  for (; i + 4 <= n; i += 4)
    _mm_storeu_ps(dst + i, _mm_cvtph_ps(_mm_loadl_epi64((const __m128i *)(const void *)(src + i))));
  /* Clean upper ymm state before any SSE code runs (GCC omits it on the tail call, and
   * dirty state slows every later SSE instruction). */
  _mm256_zeroupper();
  decode_scalar(src + i, dst + i, n - i);
}
#endif

#if BLEND_F16C
static int cpu_has_f16c(void)
{
  return (ub_cpu_features() & UB_CPU_F16C) != 0;
}
#endif

static blend_decode_fn pick_decoder(int portable)
{
#if BLEND_F16C
  if (!portable && cpu_has_f16c())
    return decode_f16c;
#endif
  (void)portable;
#if BLEND_SSE2
  return decode_sse2;
#else
  return decode_scalar;
#endif
}

/* ---- UB_BLEND_STORE_Q8 rows ----------------------------------------------------------
 * Bytes 0-5: the DC values (row positions 0-2) as halves; byte 6: e, a signed exponent;
 * bytes 7 … 7 + S − 4: positions 3 … S − 1 as signed bytes q, the value q·2^e; then zeros
 * to rowb. Decoding is exact (|q| ≤ 127 and 2^e normal), so every path gets the same
 * floats. */
#define Q8_EXP_MIN (-126) /* 2^e and 2^-e stay normal floats (a row whose largest value is
                            below 2^-119 gets steps coarser than its largest / 127) */
#define Q8_EXP_MAX 121    /* 127·2^121 < FLT_MAX: any finite row fits */

size_t ub_blend_q8_row_bytes(uint32_t stride)
{
  return ((size_t)stride + 4 + 3) & ~(size_t)3;
}

static inline float q8_step(int e)
{
  union {
    uint32_t u;
    float f;
  } x = {(uint32_t)(e + 127) << 23};
  return x.f;
}

/* |y| ≤ 2^22 rounded to the nearest integer, ties to even (in the default rounding
 * mode, as lrintf; no libm call: the adds round, FLT_EVAL_METHOD 0 on x86-64). */
static inline float q8_round(float y)
{
  const float big = 12582912.0f; /* 1.5·2^23 */
  volatile float t = y + big; /* volatile: the compiler must not fold the pair away */
  return t - big;
}

/* S finite values (the first 3 within the half range) → one row; dc: the DC as halves
 * already (the first 3 values' own halves), or NULL to round them. */
static void q8_encode(const float *v, const uint16_t *dc, uint32_t S, unsigned char *row,
                      size_t rowb)
{
  memset(row, 0, rowb);
  for (int c = 0; c < 3; c++) {
    uint16_t h = dc ? dc[c] : ub_half_from_float(v[c]);
    memcpy(row + 2 * c, &h, 2);
  }
  float mx = 0.0f;
  for (uint32_t j = 3; j < S; j++)
    mx = fabsf(v[j]) > mx ? fabsf(v[j]) : mx;
  int e = 0;
  if (mx > 0.0f) {
    /* mx = m·2^x, m in [0.5, 1): mx / 2^(x−7) in [64, 128) */
    uint32_t bits;
    memcpy(&bits, &mx, 4);
    int x = (int)(bits >> 23 & 0xffu) - 126;
    if ((bits >> 23 & 0xffu) == 0) /* a float denormal */
      frexpf(mx, &x);
    e = x - 7;
    if (e < Q8_EXP_MIN)
      e = Q8_EXP_MIN;
    if (e > Q8_EXP_MAX)
      e = Q8_EXP_MAX;
    if (e < Q8_EXP_MAX && q8_round(mx / q8_step(e)) > 127.0f) /* m·128 rounded up to 128 */
      e++;
  }
  row[6] = (unsigned char)(signed char)e;
  const float inv = 1.0f / q8_step(e); /* a power of two: exact */
  for (uint32_t j = 3; j < S; j++) {
    float y = v[j] * inv; /* exact unless below the float range: then tiny */
    y = y > 127.0f ? 127.0f : y < -127.0f ? -127.0f : y;
    row[7 + j - 3] = (unsigned char)(signed char)(int)q8_round(y);
  }
}

static void q8_decode_scalar(const char *src, float *dst, size_t nrows, uint32_t S,
                             size_t rowb)
{
  for (size_t i = 0; i < nrows; i++, src += rowb, dst += S) {
    const unsigned char *row = (const unsigned char *)src;
    for (int c = 0; c < 3; c++) {
      uint16_t h;
      memcpy(&h, row + 2 * c, 2);
      dst[c] = ub_half_to_float(h);
    }
    const float st = q8_step((signed char)row[6]);
    for (uint32_t j = 3; j < S; j++)
      dst[j] = (float)(signed char)row[7 + j - 3] * st;
  }
}

void ub_blend_q8_row(uint32_t stride, const float *in, float *out)
{
  assert(in && out && stride >= 3 && stride <= UB_BLEND_MAX_STRIDE && stride % 3 == 0);
  unsigned char row[UB_BLEND_MAX_STRIDE + 8];
  const size_t rowb = ub_blend_q8_row_bytes(stride);
  q8_encode(in, NULL, stride, row, rowb);
  q8_decode_scalar((const char *)row, out, 1, stride, rowb);
}

#if BLEND_F16C
/* The same floats, 8 values per instruction: the DC's 4-lane conversion (its 4th lane,
 * garbage, is overwritten by the next store), then 8 bytes at a time. Reads stay inside
 * the row (S − 3 ≥ 8: its last 8 bytes end before rowb). */
__attribute__((target("avx,f16c"))) static void q8_decode_avx(const char *src, float *dst,
                                                               size_t nrows, uint32_t S,
                                                               size_t rowb)
{
  const uint32_t nq = S - 3, nv = nq / 8;
  for (size_t i = 0; i < nrows; i++, src += rowb, dst += S) {
    const unsigned char *row = (const unsigned char *)src;
    _mm_storeu_ps(dst, _mm_cvtph_ps(_mm_loadl_epi64((const __m128i *)(const void *)row)));
    const __m256 st = _mm256_set1_ps(q8_step((signed char)row[6]));
    for (uint32_t v = 0; v < nv; v++) {
      const __m128i q = _mm_loadl_epi64((const __m128i *)(const void *)(row + 7 + 8 * v));
      const __m256i x = _mm256_set_m128i(_mm_cvtepi8_epi32(_mm_srli_si128(q, 4)),
                                         _mm_cvtepi8_epi32(q)); /* SSE4.1: no AVX2 needed */
      _mm256_storeu_ps(dst + 3 + 8 * v, _mm256_mul_ps(_mm256_cvtepi32_ps(x), st));
    }
    for (uint32_t j = 3 + 8 * nv; j < S; j++)
      dst[j] = (float)(signed char)row[7 + j - 3] * _mm256_cvtss_f32(st);
  }
  _mm256_zeroupper();
}
#endif

/* n 8-bit rows → n × S floats, the fastest way the engine may use. */
static void q8_decode(const ub_blend *b, const char *src, float *dst, size_t nrows)
{
#if BLEND_F16C
  if (b->avx && b->stride >= 11) {
    q8_decode_avx(src, dst, nrows, b->stride, b->rowb);
    return;
  }
#endif
  q8_decode_scalar(src, dst, nrows, b->stride, b->rowb);
}

/* One receiver: o = bs + Σ_m w[m]·row[m], m in element-id order, every product rounded
 * once and added once (SIMD lanes and the scalar loop do exactly the same operations). A
 * stride that is not a multiple of 4 ends with one vector overlapping the previous one:
 * the shared lanes get the same value twice. blend_row_fixed is for compile-time k and S
 * (unrolled, accumulators in registers); blend_row_any for run-time ones. */
BLEND_INLINE void blend_row_scalar(float *restrict o, const float *restrict bs,
                                   const float *const *rows, const float *const *w,
                                   const uint32_t k, const uint32_t S)
{
  for (uint32_t j = 0; j < S; j++) {
    float acc = bs[j];
    for (uint32_t m = 0; m < k; m++) {
      float t = w[m][j] * rows[m][j];
      acc = acc + t;
    }
    o[j] = acc;
  }
}

#if BLEND_SSE2
BLEND_INLINE void blend_row_fixed(float *restrict o, const float *restrict bs,
                                  const float *const *rows, const float *const *w,
                                  const uint32_t k, const uint32_t S)
{
  enum { MAXV = UB_BLEND_MAX_STRIDE / 4 };
  const uint32_t nv = S / 4, tail = S - 4; /* tail vector used when S % 4 != 0 */
  __m128 acc[MAXV], acct = _mm_setzero_ps();
#pragma GCC unroll 12
  for (uint32_t q = 0; q < nv; q++)
    acc[q] = _mm_loadu_ps(bs + 4 * q);
  if (S % 4)
    acct = _mm_loadu_ps(bs + tail);
#pragma GCC unroll 8
  for (uint32_t m = 0; m < k; m++) {
    const float *row = rows[m], *wm = w[m];
#pragma GCC unroll 12
    for (uint32_t q = 0; q < nv; q++)
      acc[q] = _mm_add_ps(acc[q], _mm_mul_ps(_mm_load_ps(wm + 4 * q), _mm_loadu_ps(row + 4 * q)));
    if (S % 4)
      acct = _mm_add_ps(acct, _mm_mul_ps(_mm_loadu_ps(wm + tail), _mm_loadu_ps(row + tail)));
  }
#pragma GCC unroll 12
  for (uint32_t q = 0; q < nv; q++)
    _mm_storeu_ps(o + 4 * q, acc[q]);
  if (S % 4)
    _mm_storeu_ps(o + tail, acct);
}

BLEND_INLINE void blend_row_any(float *restrict o, const float *restrict bs,
                                const float *const *rows, const float *const *w,
                                const uint32_t k, const uint32_t S)
{
  if (S < 4) {
    blend_row_scalar(o, bs, rows, w, k, S);
    return;
  }
  uint32_t q = 0;
  for (; q + 4 <= S; q += 4) {
    __m128 acc = _mm_loadu_ps(bs + q);
    for (uint32_t m = 0; m < k; m++)
      acc = _mm_add_ps(acc, _mm_mul_ps(_mm_load_ps(w[m] + q), _mm_loadu_ps(rows[m] + q)));
    _mm_storeu_ps(o + q, acc);
  }
  if (S % 4) {
    const uint32_t tail = S - 4;
    __m128 acc = _mm_loadu_ps(bs + tail);
    for (uint32_t m = 0; m < k; m++)
      acc = _mm_add_ps(acc, _mm_mul_ps(_mm_loadu_ps(w[m] + tail), _mm_loadu_ps(rows[m] + tail)));
    _mm_storeu_ps(o + tail, acc);
  }
}
#else
#define blend_row_fixed blend_row_scalar
#define blend_row_any blend_row_scalar
#endif

/* Member slot m's row for the group's receiver at position pos (among the group's
 * receivers). The values are element-major: each element's rows for its groups in group
 * order (a group's in its receivers' order), so an element's rows over its groups in
 * ascending order are one stream, for run and list groups alike. */
BLEND_INLINE const char *member_rows(const ub_blend *b, const blend_group *g, size_t m,
                                     size_t pos)
{
  return (const char *)b->values + ((size_t)b->moff[g->member_off + m] + pos) * b->rowb;
}

typedef struct blend_call {
  const ub_blend *b;
  float *out;     /* NULL: streaming, rows go through s->rows to fn */
  blend_scratch *s; /* this part's */
  uint32_t qlo, qhi; /* the current group's receivers to compute: positions [qlo, qhi) */
  ub_blend_touched_fn fn;
  void *user;
  int ones; /* this group from its all-ones sums: base = its ones rows (float), members those
               with ω ≠ 1, weighted by ω − 1 */
} blend_call;

/* Streaming: hands the pending rows to the callback. */
static void stream_flush(const blend_call *c)
{
  blend_scratch *s = c->s;
  if (s->pend) {
    c->fn(c->user, s->pend_first, s->pend, s->rows);
    s->pend = 0;
  }
}

/* Streaming: where the rows of receivers first, first + 1, … go, *n lowered to what fits:
 * after the pending ones when they continue them (else those are handed over first).
 * Pieces of one group's run and of adjacent groups (the run-time's texels are ranked group
 * by group) then reach the callback as one, mostly BLEND_CHUNK receivers. */
static float *stream_slot(const blend_call *c, uint32_t first, uint32_t *n)
{
  blend_scratch *s = c->s;
  if (s->pend && first != s->pend_first + s->pend)
    stream_flush(c);
  if (!s->pend)
    s->pend_first = first;
  const uint32_t room = BLEND_CHUNK - s->pend;
  *n = *n < room ? *n : room;
  return s->rows + (size_t)s->pend * c->b->stride;
}

/* Streaming: n more rows written at stream_slot's place. */
static void stream_done(const blend_call *c, uint32_t n)
{
  c->s->pend += n;
  if (c->s->pend == BLEND_CHUNK)
    stream_flush(c);
}

/* Base rows of a group's next unit (len receivers from r): the engine's own copy (stored
 * in group order, so consecutive units are consecutive rows) or the caller's array. */
BLEND_INLINE const char *unit_base(const ub_blend *b, const char **gb, uint32_t r,
                                   uint32_t len, size_t rowb)
{
  if (*gb) { /* own base rows or all-ones sums, group order */
    const char *p = *gb;
    *gb += (size_t)len * rowb;
    return p;
  }
  return (const char *)(b->base + (size_t)r * b->stride);
}

BLEND_INLINE const char *group_base(const ub_blend *b, const blend_group *g)
{
  return b->obase ? b->obase + (size_t)g->base_row * b->stride * b->base_size : NULL;
}

/* n values of half base rows → float (exact: a half times a power of two). */
static void decode_base(const ub_blend *b, const char *src, float *dst, size_t n)
{
  b->bdecode((const uint16_t *)(const void *)src, dst, n);
  if (b->bscale != 1.0f)
    for (size_t i = 0; i < n; i++)
      dst[i] *= b->bscale;
}

/* Walks a group's units over its receivers at positions [lo, hi) (a part of an update
 * may hold a stretch of a group): per unit its first receiver r, its first position i0,
 * the stretch [s0, s1) of it inside the range and bs, the base row of receiver r + s0. A list group (one
 * receiver per unit) starts at lo directly. */
typedef struct unit_iter {
  const uint32_t *u;
  const char *gb;
  size_t rowb;   /* bytes per base row in gb */
  uint32_t un, units, lo, hi;
  size_t i0;
  int list;
} unit_iter;

BLEND_INLINE void unit_iter_init(unit_iter *it, const ub_blend *b, const blend_group *g,
                                 uint32_t lo, uint32_t hi, const int ones)
{
  it->list = (g->k_mode & GROUP_LIST) != 0;
  it->u = b->units + g->unit_off;
  it->gb = ones ? (const char *)(b->ones + (size_t)g->ones_row * b->stride) : group_base(b, g);
  it->rowb = (size_t)b->stride * (ones ? sizeof(float) : b->base_size);
  it->un = 0;
  it->units = g->units;
  it->lo = lo;
  it->hi = hi;
  it->i0 = 0;
  if (it->list && lo) {
    it->u += lo;
    it->un = lo;
    it->i0 = lo;
    if (it->gb)
      it->gb += (size_t)lo * it->rowb;
  }
}

BLEND_INLINE int unit_next(unit_iter *it, const ub_blend *b, uint32_t *r, size_t *i0,
                           const char **bs, uint32_t *s0, uint32_t *s1)
{
  while (it->un < it->units && it->i0 < it->hi) {
    const uint32_t rr = it->u[0], len = it->list ? 1 : it->u[1];
    it->u += it->list ? 1 : 2;
    it->un++;
    const char *base = unit_base(b, &it->gb, rr, len, it->rowb);
    const size_t at = it->i0;
    it->i0 += len;
    if (at + len <= it->lo)
      continue;
    *r = rr;
    *i0 = at;
    *s0 = it->lo > at ? (uint32_t)(it->lo - at) : 0;
    *s1 = it->hi - at < len ? (uint32_t)(it->hi - at) : len;
    *bs = base + (size_t)*s0 * it->rowb;
    return 1;
  }
  return 0;
}

#if BLEND_F16C
/* The AVX + F16C path: one receiver at a time, its row in 8-lane vectors (12 = 8 + 4,
 * 27 = 3 × 8 + a 4-lane vector overlapping the last one: the shared lanes get the same
 * value twice), halves converted in registers. Since S is a multiple of 3, the weight of
 * row position j is ω[j mod 3] = wp[j mod 24 …] (wp: the element's pattern, 32 lanes).
 * Per value the operations are those of blend_row_*: acc = base; acc = acc + ω·v per
 * member in id order, products and sums rounded separately (no FMA): the same bits as the
 * SSE2 and scalar kernels. */
#define BLEND_AVX __attribute__((target("avx,f16c")))
#define BLEND_AVX_INLINE static inline __attribute__((always_inline, target("avx,f16c")))

BLEND_AVX_INLINE __m256 avx_load8(const char *src, size_t j, const int half)
{
  if (half)
    return _mm256_cvtph_ps(_mm_loadu_si128((const __m128i *)(const void *)((const uint16_t *)(const void *)src + j)));
  return _mm256_loadu_ps((const float *)(const void *)src + j);
}

BLEND_AVX_INLINE __m128 avx_load4(const char *src, size_t j, const int half)
{
  if (half)
    return _mm_cvtph_ps(_mm_loadl_epi64((const __m128i *)(const void *)((const uint16_t *)(const void *)src + j)));
  return _mm_loadu_ps((const float *)(const void *)src + j);
}

/* Values ahead of the current ones each member's stream asks for (software prefetch: up
 * to 16 streams at once, more than the hardware prefetchers follow well). avx_flat asks
 * for them into L2 (prefetcht1), not L1: with up to 23 member streams a chunk ahead, the
 * lines asked into L1 crowd it. Full ESTATE, all 132 sets changed, in one process
 * alternating per update (2026-12-04): 21.1-21.8 → 19.6-20.0 ms best; distances 256-576
 * values the same; the 8-bit rows' decode ahead did not gain (kept at T0); toggles the
 * same (hall off 2.71 vs 2.69 ms). A unit of one texel (12 values) asks once per member
 * before its row: the all-sets update's 21,851 one-texel groups (of 37,578) had asked
 * nothing ahead; 17.75 → 17.09 and 26.07 → 24.86 ms (median of 50, the same process
 * alternating, 2026-12-05; toggles the same). */
#define BLEND_PF_VALUES 384

/* Base values j.. as float: floats, or (hb) halves times the scale (exact). */
BLEND_AVX_INLINE __m256 avx_base8(const char *bs, size_t j, const int hb, const __m256 sc)
{
  if (hb)
    return _mm256_mul_ps(avx_load8(bs, j, 1), sc);
  return avx_load8(bs, j, 0);
}

BLEND_AVX_INLINE __m128 avx_base4(const char *bs, size_t j, const int hb, const __m256 sc)
{
  if (hb)
    return _mm_mul_ps(avx_load4(bs, j, 1), _mm256_castps256_ps128(sc));
  return avx_load4(bs, j, 0);
}

/* o[j] = base[j] + Σ_m wp[m][j mod 24]·src_m[j], j < nf; base: bs as floats, or (hb) as
 * halves times sc; pf: prefetch the members' streams ahead (not for rows decoded into a
 * scratch). */
BLEND_AVX_INLINE void avx_flat(float *restrict o, const char *restrict bs,
                               const char *const *src, const float *const *wp,
                               const uint32_t k, const size_t nf, const int half,
                               const int hb, const __m256 sc, const int pf)
{
  size_t j = 0;
  if (pf && nf < 24) /* a lone texel row: the loop below, which asks ahead, does not run */
    for (uint32_t m = 0; m < k; m++)
      _mm_prefetch(src[m] + BLEND_PF_VALUES * (half ? 2 : 4), _MM_HINT_T1);
  for (; j + 24 <= nf; j += 24) {
    __m256 a0 = avx_base8(bs, j, hb, sc), a1 = avx_base8(bs, j + 8, hb, sc),
           a2 = avx_base8(bs, j + 16, hb, sc);
    for (uint32_t m = 0; m < k; m++) {
      const float *w = wp[m];
      if (pf)
        _mm_prefetch(src[m] + (j + BLEND_PF_VALUES) * (half ? 2 : 4), _MM_HINT_T1);
      a0 = _mm256_add_ps(a0, _mm256_mul_ps(_mm256_load_ps(w), avx_load8(src[m], j, half)));
      a1 = _mm256_add_ps(a1, _mm256_mul_ps(_mm256_load_ps(w + 8), avx_load8(src[m], j + 8, half)));
      a2 = _mm256_add_ps(a2, _mm256_mul_ps(_mm256_load_ps(w + 16), avx_load8(src[m], j + 16, half)));
    }
    _mm256_storeu_ps(o + j, a0);
    _mm256_storeu_ps(o + j + 8, a1);
    _mm256_storeu_ps(o + j + 16, a2);
  }
  for (; j + 8 <= nf; j += 8) {
    const size_t ph = j % 24;
    __m256 a = avx_base8(bs, j, hb, sc);
    for (uint32_t m = 0; m < k; m++)
      a = _mm256_add_ps(a, _mm256_mul_ps(_mm256_loadu_ps(wp[m] + ph), avx_load8(src[m], j, half)));
    _mm256_storeu_ps(o + j, a);
  }
  for (; j + 4 <= nf; j += 4) {
    const size_t ph = j % 24;
    __m128 a = avx_base4(bs, j, hb, sc);
    for (uint32_t m = 0; m < k; m++)
      a = _mm_add_ps(a, _mm_mul_ps(_mm_loadu_ps(wp[m] + ph), avx_load4(src[m], j, half)));
    _mm_storeu_ps(o + j, a);
  }
  if (j < nf && nf >= 4) {
    /* The last 1-3 values (a 27-float row alone: a list group's receiver): the 4 values
     * ending at nf, inputs only (in bounds), stored through a mask to the ones not yet
     * written (so o may even alias bs). The weight of position x is wp[m][x mod 24]: the
     * pattern has 32 lanes and period 3, so lanes ph..ph+3 (ph <= 23) are right. The same
     * operations per value as above: the same bits as the scalar kernel. */
    const size_t j0 = nf - 4, ph = j0 % 24;
    __m128 a = avx_base4(bs, j0, hb, sc);
    for (uint32_t m = 0; m < k; m++)
      a = _mm_add_ps(a, _mm_mul_ps(_mm_loadu_ps(wp[m] + ph), avx_load4(src[m], j0, half)));
    const int skip = (int)(j - j0); /* 1..3 lanes already written */
    const __m128i mask = _mm_set_epi32(-1, skip < 3 ? -1 : 0, skip < 2 ? -1 : 0, 0);
    _mm_maskstore_ps(o + j0, mask, a);
    j = nf;
  }
  for (; j < nf; j++) { /* a row of 3 alone */
    float acc = hb ? ub_half_to_float(((const uint16_t *)(const void *)bs)[j]) *
                         _mm256_cvtss_f32(sc)
                   : ((const float *)(const void *)bs)[j];
    for (uint32_t m = 0; m < k; m++) {
      float v = half ? ub_half_to_float(((const uint16_t *)(const void *)src[m])[j])
                     : ((const float *)(const void *)src[m])[j];
      float t = wp[m][j % 24] * v;
      acc = acc + t;
    }
    o[j] = acc;
  }
}

/* A group's units: member m's values for the unit's receivers are one stretch of its
 * block (see blend_group), so a run is blended as flat arrays; the callback gets the
 * pieces when BLEND_CHUNK receivers are waiting or the next piece does not continue them
 * (stream_slot; upper AVX state cleared first: it runs SSE code).
 * The whole loop is AVX code, so a list group costs no call per receiver.
 * half: 0 float records, 1 half, 2 UB_BLEND_STORE_Q8 rows (each chunk's rows decoded into
 * the decode scratch first, their lines requested a chunk ahead, then blended as floats). */
BLEND_AVX_INLINE void avx_group(const blend_call *c, const blend_group *g, const uint32_t *act,
                                const char **src, const float *const *wp, const uint32_t k,
                                const int half, const int hb)
{
  const ub_blend *b = c->b;
  const __m256 sc = _mm256_set1_ps(b->bscale);
  const size_t bsz = hb ? 2 : 4;
  const uint32_t S = b->stride;
  const size_t rowb = b->rowb;
  float *out = c->out;
  uint32_t chunk = c->fn || !out ? BLEND_CHUNK : UINT32_MAX;
  const char **dsrc = c->s->avx_dec;
  if (half == 2) {
    const size_t fit = b->dec_floats / ((size_t)k * S);
    chunk = fit < chunk ? (uint32_t)fit : chunk; /* ≥ 1: dec_floats ≥ max_overlap × S */
  }
  unit_iter it;
  unit_iter_init(&it, b, g, c->qlo, c->qhi, c->ones);
  uint32_t r, s0, s1;
  size_t i0; /* receivers of the group before this unit */
  const char *bs;
  while (unit_next(&it, b, &r, &i0, &bs, &s0, &s1)) {
    for (uint32_t m = 0; m < k; m++)
      src[m] = member_rows(b, g, act[m], i0 + s0);
    for (uint32_t i = s0; i < s1;) {
      uint32_t n = s1 - i < chunk ? s1 - i : chunk;
      float *o = out ? out + (size_t)(r + i) * S : stream_slot(c, r + i, &n);
      if (half == 2) {
        for (uint32_t m = 0; m < k; m++) {
          float *d = c->s->dec + (size_t)m * n * S;
          const size_t nb = (size_t)n * rowb;
          for (size_t off = 0; off < nb; off += 64) /* the next chunk's lines */
            _mm_prefetch(src[m] + nb + off, _MM_HINT_T0);
          q8_decode(b, src[m], d, n); /* S < 11: scalar (the AVX one writes 4 DC lanes) */
          dsrc[m] = (const char *)d;
        }
        avx_flat(o, bs + (size_t)(i - s0) * S * bsz, dsrc, wp, k, (size_t)n * S, 0, hb, sc, 0);
      } else {
        avx_flat(o, bs + (size_t)(i - s0) * S * bsz, src, wp, k, (size_t)n * S, half, hb, sc,
                 1);
      }
      if (c->fn) {
        _mm256_zeroupper();
        if (out)
          c->fn(c->user, r + i, n, o);
        else
          stream_done(c, n);
      }
      for (uint32_t m = 0; m < k; m++)
        src[m] += (size_t)n * rowb;
      i += n;
    }
  }
}

/* The six kinds: half, float or 8-bit records (h/f/q) × half or float base rows (h/f). */
#define BLEND_AVX_GROUP(name, half, hb)                                                  \
  BLEND_AVX static void name(const blend_call *c, const blend_group *g, const uint32_t *act, \
                             const char **src, const float *const *wp, uint32_t k)        \
  {                                                                                      \
    avx_group(c, g, act, src, wp, k, half, hb);                                          \
    _mm256_zeroupper();                                                                  \
  }
BLEND_AVX_GROUP(avx_group_hf, 1, 0)
BLEND_AVX_GROUP(avx_group_ff, 0, 0)
BLEND_AVX_GROUP(avx_group_hh, 1, 1)
BLEND_AVX_GROUP(avx_group_fh, 0, 1)
BLEND_AVX_GROUP(avx_group_qf, 2, 0)
BLEND_AVX_GROUP(avx_group_qh, 2, 1)
#undef BLEND_AVX_GROUP

/* UB_BLEND_STORE_Q8 rows of stride 12 (lightmap texels) or 27 (probes), AVX2: each
 * member's row decoded in registers, one receiver at a time. Value j ≥ 3 is byte j + 4:
 * lanes 0-7 = the DC halves (0-2) and bytes 7-11 (sign-extended from the 8 bytes at 4,
 * whose first three are DC bits: replaced), then 8 lanes from bytes 12, 20 (27: and the
 * last 4 values, 23-26, from bytes 27-30: lane 23 twice, the same bits both times), each
 * byte times the row's step (exact). Then as avx_flat: acc = base, acc = acc + ω·v per
 * member in id order: the bits of every other path. */
#define BLEND_AVX2 __attribute__((target("avx2,f16c")))
#define BLEND_AVX2_INLINE static inline __attribute__((always_inline, target("avx2,f16c")))

BLEND_AVX2_INLINE __m256 q8_lanes0(const unsigned char *row, const __m256 st)
{
  const __m128 dc = _mm_cvtph_ps(_mm_loadl_epi64((const __m128i *)(const void *)row));
  const __m256i q = _mm256_cvtepi8_epi32(_mm_loadl_epi64((const __m128i *)(const void *)(row + 4)));
  return _mm256_blend_ps(_mm256_mul_ps(_mm256_cvtepi32_ps(q), st), _mm256_castps128_ps256(dc),
                         0x07);
}

BLEND_AVX2_INLINE __m256 q8_lanes8(const unsigned char *row, size_t j, const __m256 st)
{
  const __m256i q = _mm256_cvtepi8_epi32(_mm_loadl_epi64((const __m128i *)(const void *)(row + j + 4)));
  return _mm256_mul_ps(_mm256_cvtepi32_ps(q), st);
}

BLEND_AVX2_INLINE __m128 q8_lanes4(const unsigned char *row, size_t j, const __m256 st)
{
  int32_t x;
  memcpy(&x, row + j + 4, 4);
  return _mm_mul_ps(_mm_cvtepi32_ps(_mm_cvtepi8_epi32(_mm_cvtsi32_si128(x))),
                    _mm256_castps256_ps128(st));
}

/* The row's values at lanes 0-7, 8-15, 16-23 (v[0..nv)) and the last 4 (t): S = 12: v[0],
 * t = 8-11; S = 27: v[0..3), t = 23-26. */
BLEND_AVX2_INLINE void q8_row_regs(const unsigned char *row, const uint32_t S, __m256 *v,
                                   __m128 *t)
{
  const __m256 st = _mm256_set1_ps(q8_step((signed char)row[6]));
  v[0] = q8_lanes0(row, st);
  if (S == 27) {
    v[1] = q8_lanes8(row, 8, st);
    v[2] = q8_lanes8(row, 16, st);
  }
  *t = q8_lanes4(row, S - 4, st);
}

/* Base values j.. (8 or 4) as float. */
BLEND_AVX2_INLINE __m256 base8(const char *bq, size_t j, const int hb, const __m256 sc)
{
  if (hb)
    return _mm256_mul_ps(
        _mm256_cvtph_ps(_mm_loadu_si128((const __m128i *)(const void *)(bq + 2 * j))), sc);
  return _mm256_loadu_ps((const float *)(const void *)bq + j);
}

BLEND_AVX2_INLINE __m128 base4(const char *bq, size_t j, const int hb, const __m256 sc)
{
  if (hb)
    return _mm_mul_ps(_mm_cvtph_ps(_mm_loadl_epi64((const __m128i *)(const void *)(bq + 2 * j))),
                      _mm256_castps256_ps128(sc));
  return _mm_loadu_ps((const float *)(const void *)bq + j);
}

BLEND_AVX2_INLINE void avx2_group_q(const blend_call *c, const blend_group *g,
                                    const uint32_t *act, const char **src,
                                    const float *const *wp, const uint32_t k, const int hb,
                                    const uint32_t S)
{
  const ub_blend *b = c->b;
  const size_t rowb = b->rowb; /* 16 or 32 */
  const uint32_t nv = S == 27 ? 3 : 1;
  const __m256 sc = _mm256_set1_ps(b->bscale);
  const size_t bsz = hb ? 2 : 4;
  float *out = c->out;
  const uint32_t chunk = c->fn || !out ? BLEND_CHUNK : UINT32_MAX;
  unit_iter it;
  unit_iter_init(&it, b, g, c->qlo, c->qhi, c->ones);
  uint32_t r, s0, s1;
  size_t i0;
  const char *bs;
  while (unit_next(&it, b, &r, &i0, &bs, &s0, &s1)) {
    for (uint32_t m = 0; m < k; m++)
      src[m] = member_rows(b, g, act[m], i0 + s0);
    for (uint32_t i = s0; i < s1;) {
      uint32_t n = s1 - i < chunk ? s1 - i : chunk;
      float *o = out ? out + (size_t)(r + i) * S : stream_slot(c, r + i, &n);
      const char *bq = bs + (size_t)(i - s0) * S * bsz;
      for (uint32_t q = 0; q < n; q++, bq += S * bsz) {
        __m256 a[3];
        for (uint32_t x = 0; x < nv; x++)
          a[x] = base8(bq, 8 * x, hb, sc);
        __m128 at = base4(bq, S - 4, hb, sc);
        for (uint32_t m = 0; m < k; m++) {
          const unsigned char *row = (const unsigned char *)src[m] + (size_t)q * rowb;
          if ((q & (S == 27 ? 1 : 3)) == 0) /* a line holds 64 / rowb rows */
            _mm_prefetch((const char *)row + BLEND_PF_VALUES * 2, _MM_HINT_T0);
          __m256 v[3];
          __m128 t;
          q8_row_regs(row, S, v, &t);
          for (uint32_t x = 0; x < nv; x++)
            a[x] = _mm256_add_ps(a[x], _mm256_mul_ps(_mm256_load_ps(wp[m] + 8 * x), v[x]));
          at = _mm_add_ps(at, _mm_mul_ps(_mm_loadu_ps(wp[m] + S - 4), t));
        }
        float *oq = o + (size_t)q * S;
        for (uint32_t x = 0; x < nv; x++)
          _mm256_storeu_ps(oq + 8 * x, a[x]);
        _mm_storeu_ps(oq + S - 4, at);
      }
      if (c->fn) {
        _mm256_zeroupper();
        if (out)
          c->fn(c->user, r + i, n, o);
        else
          stream_done(c, n);
      }
      for (uint32_t m = 0; m < k; m++)
        src[m] += (size_t)n * rowb;
      i += n;
    }
  }
}

BLEND_AVX2 static void avx2_group_q12(const blend_call *c, const blend_group *g,
                                      const uint32_t *act, const char **src,
                                      const float *const *wp, uint32_t k, int hb)
{
  if (hb)
    avx2_group_q(c, g, act, src, wp, k, 1, 12);
  else
    avx2_group_q(c, g, act, src, wp, k, 0, 12);
  _mm256_zeroupper();
}

BLEND_AVX2 static void avx2_group_q27(const blend_call *c, const blend_group *g,
                                      const uint32_t *act, const char **src,
                                      const float *const *wp, uint32_t k, int hb)
{
  if (hb)
    avx2_group_q(c, g, act, src, wp, k, 1, 27);
  else
    avx2_group_q(c, g, act, src, wp, k, 0, 27);
  _mm256_zeroupper();
}

/* ub_blend_row's sum for 8-bit rows of stride 12 or 27: out (holding the base row) +=
 * w_m·v_m over the n listed members in order, per value as the kernels. */
BLEND_AVX2 static void row_sum_q8_avx2(const float *const *w, const char *const *src,
                                       uint32_t n, float *out, uint32_t S)
{
  const uint32_t nv = S == 27 ? 3 : 1;
  __m256 a[3];
  for (uint32_t x = 0; x < nv; x++)
    a[x] = _mm256_loadu_ps(out + 8 * x);
  __m128 at = _mm_loadu_ps(out + S - 4);
  for (uint32_t m = 0; m < n; m++) {
    const float *wm = w[m]; /* ω, 3 floats */
    const __m256 w8 = _mm256_setr_ps(wm[0], wm[1], wm[2], wm[0], wm[1], wm[2], wm[0], wm[1]);
    /* lanes 8x.. start at phase 8x mod 3 = 0, 2, 1; the tail at S − 4 (8 or 23): 2 */
    const __m256 w8b = _mm256_setr_ps(wm[2], wm[0], wm[1], wm[2], wm[0], wm[1], wm[2], wm[0]);
    const __m256 w8c = _mm256_setr_ps(wm[1], wm[2], wm[0], wm[1], wm[2], wm[0], wm[1], wm[2]);
    const __m128 w4 = _mm_setr_ps(wm[2], wm[0], wm[1], wm[2]);
    __m256 v[3];
    __m128 t;
    q8_row_regs((const unsigned char *)src[m], S, v, &t);
    a[0] = _mm256_add_ps(a[0], _mm256_mul_ps(w8, v[0]));
    if (S == 27) {
      a[1] = _mm256_add_ps(a[1], _mm256_mul_ps(w8b, v[1]));
      a[2] = _mm256_add_ps(a[2], _mm256_mul_ps(w8c, v[2]));
    }
    at = _mm_add_ps(at, _mm_mul_ps(w4, t));
  }
  for (uint32_t x = 0; x < nv; x++)
    _mm256_storeu_ps(out + 8 * x, a[x]);
  _mm_storeu_ps(out + S - 4, at);
  _mm256_zeroupper();
}

static void group_blend_avx(const blend_call *c, const blend_group *g, const uint32_t *act,
                            uint32_t k)
{
  const ub_blend *b = c->b;
  const uint32_t *mem = b->members + g->member_off;
  const float **wp = c->s->avx_w;
  const float *pat = c->ones ? b->dwpat : b->wpat;
  for (uint32_t m = 0; m < k; m++)
    wp[m] = pat + 32 * (size_t)mem[act[m]];
  const int hb = !c->ones && b->base_size == 2; /* all-ones sums are float */
  if (b->q8 && b->avx2 && b->stride == 12)
    avx2_group_q12(c, g, act, c->s->avx_src, wp, k, hb);
  else if (b->q8 && b->avx2 && b->stride == 27)
    avx2_group_q27(c, g, act, c->s->avx_src, wp, k, hb);
  else if (b->q8)
    (hb ? avx_group_qh : avx_group_qf)(c, g, act, c->s->avx_src, wp, k);
  else if (b->value_size == 2)
    (hb ? avx_group_hh : avx_group_hf)(c, g, act, c->s->avx_src, wp, k);
  else
    (hb ? avx_group_fh : avx_group_ff)(c, g, act, c->s->avx_src, wp, k);
}
#endif

/* One group with k non-zero members act[0..k) (slots into the group's members). S and
 * (for k ≤ BLEND_SPECIALISED) k are compile-time constants at the fixed call sites. Half
 * rows are decoded (exactly) into the decode scratch, one receiver at a time. */
BLEND_INLINE void group_body(const blend_call *c, const blend_group *g, const uint32_t *act,
                             const uint32_t k, const uint32_t S, const int fixed)
{
  const ub_blend *b = c->b;
  const char *src_l[BLEND_SPECIALISED];
  const float *rows_l[BLEND_SPECIALISED], *w_l[BLEND_SPECIALISED];
  const char **src = k <= BLEND_SPECIALISED ? src_l : c->s->src;
  const float **rows = k <= BLEND_SPECIALISED ? rows_l : c->s->rowp;
  const float **w = k <= BLEND_SPECIALISED ? w_l : c->s->w;
  const uint32_t *mem = b->members + g->member_off;
  const size_t rowb = b->rowb;
  const blend_decode_fn decode = b->decode;
  float *out = c->out;

  /* Receivers per chunk: bounded by the decode scratch (half or 8-bit), the streaming
   * scratch and the base rows' decode scratch (half base). */
  const int hb = !c->ones && b->base_size == 2;
  uint32_t chunk = out && !hb ? UINT32_MAX : BLEND_CHUNK;
  if (decode || b->q8) {
    size_t fit = b->dec_floats / ((size_t)k * S);
    chunk = fit < chunk ? (uint32_t)fit : chunk; /* ≥ 1: dec_floats ≥ max_overlap × S */
  }
  const float *wx = c->ones ? b->dwexp : b->wexp;
  for (uint32_t m = 0; m < k; m++)
    w[m] = wx + (size_t)mem[act[m]] * b->wstride;
  unit_iter it;
  unit_iter_init(&it, b, g, c->qlo, c->qhi, c->ones);
  uint32_t r, s0, s1;
  size_t i0;
  const char *bsu;
  while (unit_next(&it, b, &r, &i0, &bsu, &s0, &s1)) {
    for (uint32_t m = 0; m < k; m++)
      src[m] = member_rows(b, g, act[m], i0 + s0);
    for (uint32_t i = s0; i < s1;) {
      uint32_t n = s1 - i < chunk ? s1 - i : chunk;
      float *o0 = out ? out + (size_t)(r + i) * S : stream_slot(c, r + i, &n), *o = o0;
      const float *bs;
      if (hb) {
        decode_base(b, bsu, c->s->bdec, (size_t)n * S);
        bs = c->s->bdec;
      } else {
        bs = (const float *)(const void *)bsu;
      }
      bsu += (size_t)n * S * (hb ? 2 : 4); /* own base rows, or float all-ones sums */
      for (uint32_t m = 0; m < k; m++) {
        if (b->q8) {
          float *dst = c->s->dec + (size_t)m * n * S;
          q8_decode(b, src[m], dst, n);
          rows[m] = dst;
        } else if (decode) {
          float *dst = c->s->dec + (size_t)m * n * S;
          decode((const uint16_t *)(const void *)src[m], dst, (size_t)n * S);
          rows[m] = dst;
        } else {
          rows[m] = (const float *)(const void *)src[m];
        }
        src[m] += (size_t)n * rowb;
      }
      for (uint32_t q = 0; q < n; q++) {
        if (fixed)
          blend_row_fixed(o, bs, rows, w, k, S);
        else
          blend_row_any(o, bs, rows, w, k, S);
        o += S;
        bs += S;
        for (uint32_t m = 0; m < k; m++)
          rows[m] += S;
      }
      if (c->fn && out)
        c->fn(c->user, r + i, n, o0);
      else if (c->fn)
        stream_done(c, n);
      i += n;
    }
  }
}

/* The kernels specialised for 1..8 non-zero members (S constant), generic above. */
BLEND_INLINE void group_switch(const blend_call *c, const blend_group *g, const uint32_t *act,
                               uint32_t k, const uint32_t S)
{
  switch (k) {
  case 1: group_body(c, g, act, 1, S, 1); break;
  case 2: group_body(c, g, act, 2, S, 1); break;
  case 3: group_body(c, g, act, 3, S, 1); break;
  case 4: group_body(c, g, act, 4, S, 1); break;
  case 5: group_body(c, g, act, 5, S, 1); break;
  case 6: group_body(c, g, act, 6, S, 1); break;
  case 7: group_body(c, g, act, 7, S, 1); break;
  case 8: group_body(c, g, act, 8, S, 1); break;
  default: group_body(c, g, act, k, S, 0); break;
  }
}

static void group_blend(const blend_call *c, const blend_group *g, const uint32_t *act,
                        uint32_t k)
{
  switch (c->b->kernel) {
  case KERNEL_12: group_switch(c, g, act, k, 12); break;
  case KERNEL_27: group_switch(c, g, act, k, 27); break;
  default: group_body(c, g, act, k, c->b->stride, 0); break;
  }
}

/* All weights 0: out = base, row copies (still one write per receiver, no read of out);
 * from the all-ones sums (c->ones), all weights 1: out = those sums. */
static void group_copy_base(const blend_call *c, const blend_group *g)
{
  const ub_blend *b = c->b;
  const uint32_t S = b->stride;
  const size_t bsz = c->ones ? sizeof(float) : b->base_size;
  unit_iter it;
  unit_iter_init(&it, b, g, c->qlo, c->qhi, c->ones);
  uint32_t r, s0, s1;
  size_t i0;
  const char *bsu;
  while (unit_next(&it, b, &r, &i0, &bsu, &s0, &s1)) {
    for (uint32_t f = r + s0, n; f < r + s1; f += n) {
      /* float base: the whole unit at once; half base: decoded a chunk at a time */
      n = bsz == 4 ? r + s1 - f : r + s1 - f < BLEND_CHUNK ? r + s1 - f : BLEND_CHUNK;
      const float *bs = (const float *)(const void *)bsu;
      if (bsz == 2) {
        decode_base(b, bsu, c->s->bdec, (size_t)n * S);
        bs = c->s->bdec;
      }
      bsu += (size_t)n * S * bsz;
      if (c->out) {
        memcpy(c->out + (size_t)f * S, bs, (size_t)n * S * sizeof(float));
        if (c->fn)
          c->fn(c->user, f, n, c->out + (size_t)f * S);
      } else if (c->fn) { /* streaming: the base rows are the result */
        for (uint32_t d = 0, m; d < n; d += m) {
          m = n - d;
          float *o = stream_slot(c, f + d, &m);
          memcpy(o, bs + (size_t)d * S, (size_t)m * S * sizeof(float));
          stream_done(c, m);
        }
      }
    }
  }
}

/* The bytes of a group's tables an update reads: its units (a receiver per list unit,
 * first + length per run) and its record. */
static inline uint64_t group_table_bytes(const blend_group *g)
{
  return (uint64_t)g->units * ((g->k_mode & GROUP_LIST) ? 1 : 2) * sizeof(uint32_t) + sizeof *g;
}

/* Whether a group with all-ones sums is cheaper from them, n1 of its members having
 * ω ≠ (1, 1, 1), nz ω ≠ 0: the bytes read, its float sum row and n1 record rows against
 * its base row and nz record rows (ties: the base). A function of the weights only, so
 * a receiver's value still depends on the current weights alone. */
static inline int ones_cheaper(const ub_blend *b, uint32_t n1, uint32_t nz)
{
  const uint64_t S = b->stride;
  return S * sizeof(float) + n1 * (uint64_t)b->rowb < S * b->base_size + nz * (uint64_t)b->rowb;
}

/* Hands the receivers [lo, hi) of group g to fn as rows `rows` (NULL: marking;
 * UB_BLEND_AT_REFERENCE), consecutive receivers together. */
static void group_report(const ub_blend *b, const blend_group *g, uint32_t lo, uint32_t hi,
                         ub_blend_touched_fn fn, void *user, const float *rows)
{
  uint32_t pf = 0, pn = 0;
  if (lo == 0 && hi == g->receivers) {
    /* a whole group (a GLG set's probes are mostly lists, a kept texel group's runs):
     * its units straight from the table, consecutive ones joined as below */
    const uint32_t *u = b->units + g->unit_off;
    const int list = (g->k_mode & GROUP_LIST) != 0;
    for (uint32_t i = 0; i < g->units; i++) {
      const uint32_t r = list ? u[i] : u[2 * i], n = list ? 1 : u[2 * i + 1];
      if (pn && pf + pn == r) {
        pn += n;
        continue;
      }
      if (pn)
        fn(user, pf, pn, rows);
      pf = r;
      pn = n;
    }
    if (pn)
      fn(user, pf, pn, rows);
    return;
  }
  unit_iter it;
  unit_iter_init(&it, b, g, lo, hi, 0);
  uint32_t r, s0, s1;
  size_t at;
  const char *bs;
  while (unit_next(&it, b, &r, &at, &bs, &s0, &s1)) {
    if (pn && pf + pn == r + s0) {
      pn += s1 - s0;
      continue;
    }
    if (pn)
      fn(user, pf, pn, rows);
    pf = r + s0;
    pn = s1 - s0;
  }
  if (pn)
    fn(user, pf, pn, rows);
}

/* The positions in mem[0..gk) (ascending element ids) of the listed elements e[0..n)
 * (ascending) that are members, ascending; returns their count. */
static inline uint32_t few_find(const uint32_t *mem, uint32_t gk, const uint32_t *e, uint32_t n,
                                uint32_t *pos)
{
  uint32_t c = 0, lo = 0;
  for (uint32_t i = 0; i < n && lo < gk; i++) {
    uint32_t a = lo, z = gk; /* first position with mem ≥ e[i] */
    while (a < z) {
      const uint32_t mid = a + (z - a) / 2;
      if (mem[mid] < e[i])
        a = mid + 1;
      else
        z = mid;
    }
    if (a < gk && mem[a] == e[i])
      pos[c++] = a++;
    lo = a;
  }
  return c;
}

/* A group's piece [qlo, qhi) counted: the part holding the group's start counts the
 * group and its tables, so the parts' stats add up to a whole update's. Returns the
 * piece's receivers. */
static uint64_t count_group(const blend_call *c, const blend_group *g, ub_blend_stats *st)
{
  const int first = c->qlo == 0;
  st->groups += first;
  st->receivers += c->qhi - c->qlo;
  st->bytes_read += first ? group_table_bytes(g) : 0;
  return c->qhi - c->qlo;
}

/* A streaming update's group piece reported to touched with rows (UB_BLEND_AT_REFERENCE
 * or UB_BLEND_AT_BASE), the pending stream handed over first, and counted. */
static uint64_t report_group(const blend_call *c, const blend_group *g, ub_blend_stats *st,
                             const float *rows)
{
  stream_flush(c);
  group_report(c->b, g, c->qlo, c->qhi, c->fn, c->user, rows);
  return count_group(c, g, st);
}

/* A streaming update's group whose members' weights are all 0, with
 * ub_blend_set_base_report on: its receivers reported as UB_BLEND_AT_BASE, not streamed.
 * 0: the caller computes it. */
static int group_at_base(const blend_call *c, const blend_group *g, ub_blend_stats *st)
{
  if (!c->b->base_report || c->out || !c->fn)
    return 0;
  st->groups_base += c->qlo == 0;
  st->receivers_base += report_group(c, g, st, UB_BLEND_AT_BASE);
  return 1;
}

static void process_group(const blend_call *c, uint32_t gi, ub_blend_stats *st)
{
  const ub_blend *b = c->b;
  const blend_group *g = &b->groups[gi];
  const uint32_t gk = g->k_mode & ~GROUP_LIST;
  const uint32_t *mem = b->members + g->member_off;
  const int few = b->few && gk >= BLEND_FEW_MIN_K;
  uint32_t fpos[BLEND_FEW];
  if (b->atref && (!c->out || b->refrows)) {
    uint32_t off = 0;
    if (few)
      off = few_find(mem, gk, b->few_e[2], b->few_n[2], fpos);
    else
      for (uint32_t m = 0; m < gk; m++)
        off += !b->atref[mem[m]];
    if (off == 0) { /* at the reference: its rows back, or the caller puts back its own */
      if (c->out) {
        const uint64_t n = c->qhi - c->qlo, row = (uint64_t)b->stride * sizeof(float);
        const size_t S = b->stride;
        const float *rr = b->refrows + (size_t)g->base_row * S;
        unit_iter it;
        unit_iter_init(&it, b, g, c->qlo, c->qhi, 0);
        uint32_t r, s0, s1;
        size_t i0;
        const char *bs;
        while (unit_next(&it, b, &r, &i0, &bs, &s0, &s1)) {
          float *o = c->out + (size_t)(r + s0) * S;
          memcpy(o, rr + (i0 + s0) * S, (size_t)(s1 - s0) * S * sizeof(float));
          if (c->fn)
            c->fn(c->user, r + s0, s1 - s0, o);
        }
        st->bytes_read += n * row;
        st->bytes_written += n * row;
        st->receivers_reference += count_group(c, g, st);
      } else {
        st->receivers_reference += report_group(c, g, st, UB_BLEND_AT_REFERENCE);
      }
      return;
    }
  }
  uint32_t act_l[BLEND_SPECIALISED];
  uint32_t *act = gk <= BLEND_SPECIALISED ? act_l : c->s->act;
  uint32_t k = 0;
  blend_call cc = *c;
  cc.ones = 0;
  if (few) { /* the same lists from update_begin's element lists */
    const uint32_t nz0 = few_find(mem, gk, b->few_e[0], b->few_n[0], fpos);
    if (nz0 == gk && group_at_base(c, g, st))
      return;
    uint32_t one[BLEND_FEW], n1 = 0;
    if (g->ones_row != ONES_NONE)
      n1 = few_find(mem, gk, b->few_e[1], b->few_n[1], one);
    if (g->ones_row != ONES_NONE && ones_cheaper(b, n1, gk - nz0)) {
      cc.ones = 1;
      for (; k < n1; k++)
        act[k] = one[k];
    } else {
      for (uint32_t m = 0, z = 0; m < gk; m++) {
        if (z < nz0 && fpos[z] == m) {
          z++;
          continue;
        }
        act[k++] = m;
      }
    }
  } else {
    for (uint32_t m = 0; m < gk; m++) { /* branch-free: the pattern is data */
      act[k] = m;
      k += b->nonzero[mem[m]];
    }
    if (k == 0 && group_at_base(c, g, st))
      return;
    if (g->ones_row != ONES_NONE) {
      uint32_t n1 = 0;
      for (uint32_t m = 0; m < gk; m++)
        n1 += b->notone[mem[m]];
      if (ones_cheaper(b, n1, k)) { /* from the all-ones sums: the members with ω ≠ 1 */
        cc.ones = 1;
        k = 0;
        for (uint32_t m = 0; m < gk; m++) {
          act[k] = m;
          k += b->notone[mem[m]];
        }
      }
    }
  }
  if (k == 0)
    group_copy_base(&cc, g);
#if BLEND_F16C
  else if (b->avx)
    group_blend_avx(&cc, g, act, k);
#endif
  else
    group_blend(&cc, g, act, k);

  const uint64_t row = (uint64_t)b->stride * sizeof(float), n = count_group(c, g, st);
  st->groups_base += c->qlo == 0 && k == 0 && !cc.ones;
  st->bytes_written += c->out ? n * row : 0;
  st->bytes_read += n * b->stride * (cc.ones ? sizeof(float) : b->base_size) +
                    (uint64_t)k * n * b->rowb;
}

static int cmp_u32(const void *a, const void *b)
{
  uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
  return (x > y) - (x < y);
}

/* A group's cost in an update, for splitting the update into parts of equal cost: an
 * estimate in units of about a CPU cycle, fitted to the per-group times of the full
 * ESTATE level's updates (this machine's TSC; every set changed, and every set toggled
 * with the others on, within ±17% per overlap count). Per receiver: 2 a row read (its
 * base row and its members' record rows, or, from its all-ones sums when update_begin
 * found at most BLEND_FEW elements away from ω1, the float sum, two rows, and at most
 * that many members' rows, whichever ones_cheaper would pick), 4 more a member stream
 * beyond 6 (many streams at once read slower), and the caller's work
 * (ub_blend_set_receiver_cost); per group 300 (its tables, the call, the callback).
 * Only where the parts are cut depends on it, never a receiver's bits. The count before
 * (rows alone, 16 a group) cut a hall set's toggle off into jobs of 0.69 and 2.34 ms (now
 * 1.54 and 1.46; a room set's 0.16 and 0.19, now 0.18 and 0.17; the jobs run one after
 * the other, full ESTATE, 2026-12-05): a hall toggle's ~20 k groups of few receivers each
 * cost 150-550 cycles apiece besides their rows, and a hall group of 16 members counted
 * 17 rows where its all-ones sum reads 2-3. */
#define BLEND_COST_GROUP 300u
/* n1: the elements away from ω1 when update_begin listed them (b->few), else
 * UINT32_MAX (too many to tell which groups hold them: every group counts its plain rows);
 * rc: ub_blend_set_receiver_cost's. */
static inline uint64_t group_cost(const blend_group *g, uint64_t n1, uint64_t rc)
{
  const uint64_t gk = g->k_mode & ~GROUP_LIST;
  uint64_t rows = gk + 1u, streams = gk;
  if (g->ones_row != ONES_NONE && 2u + n1 < rows) {
    rows = 2u + n1;
    streams = n1;
  }
  return (uint64_t)g->receivers * (2u * rows + (streams > 6u ? 4u * (streams - 6u) : 0u) + rc) +
         BLEND_COST_GROUP;
}

void ub_blend_update_begin(ub_blend *b, int all)
{
  assert(b);
  uint32_t n = 0;
  /* the changed elements: clean again, their weights now the ones the rows hold */
  for (uint32_t i = 0; i < b->dirty_count; i++) {
    const uint32_t e = b->dirty_list[i];
    b->dirty[e] = 0;
    memcpy(b->wupd + (size_t)e * 3, b->weight + (size_t)e * 3, 3 * sizeof(float));
    if (b->wlast)
      memcpy(b->wlast + (size_t)e * 3, b->weight + (size_t)e * 3, 3 * sizeof(float));
  }
  if (all)
    memcpy(b->wupd, b->weight, (size_t)b->element_count * 3 * sizeof(float));
  /* every element changed (e.g. a global dimmer): every group holds one of them, so the
   * work is every group, without stamping each element's groups (full ESTATE, all 132
   * sets: 0.9 -> 0.17 ms for the three engines) */
  if (all || (b->dirty_count == b->element_count && b->element_count)) {
    if (all && b->wlast) /* every row recomputed: with every element's weight */
      memcpy(b->wlast, b->weight, (size_t)b->element_count * 3 * sizeof(float));
    for (uint32_t g = 0; g < b->group_count; g++)
      b->work[n++] = g;
  } else if (b->dirty_count == 1) {
    /* one element changed (a set toggled): its groups, already ascending (elem_groups),
     * no stamps (a hall set's ~22k groups: 0.2 ms of stamping and scanning) */
    const uint32_t e = b->dirty_list[0];
    n = b->elem_off[e + 1] - b->elem_off[e];
    memcpy(b->work, b->elem_groups + b->elem_off[e], (size_t)n * sizeof *b->work);
  } else {
    if (++b->epoch == 0) { /* wrapped: forget every stamp */
      memset(b->stamp, 0, (size_t)b->group_count * sizeof *b->stamp);
      b->epoch = 1;
    }
    for (uint32_t i = 0; i < b->dirty_count; i++) {
      const uint32_t e = b->dirty_list[i];
      for (uint32_t j = b->elem_off[e]; j < b->elem_off[e + 1]; j++) {
        uint32_t g = b->elem_groups[j];
        if (b->stamp[g] != b->epoch) {
          b->stamp[g] = b->epoch;
          b->work[n++] = g;
        }
      }
    }
    if (n > b->group_count / 16) { /* many groups: scanning the stamps beats sorting */
      n = 0;
      for (uint32_t g = 0; g < b->group_count; g++)
        if (b->stamp[g] == b->epoch)
          b->work[n++] = g;
    } else {
      qsort(b->work, n, sizeof *b->work, cmp_u32);
    }
  }
  b->dirty_count = 0;
  b->work_count = n;
  /* the element lists process_group searches (see ub_blend.few) */
  b->few = 1;
  b->few_n[0] = b->few_n[1] = b->few_n[2] = 0;
  for (uint32_t e = 0; e < b->element_count && b->few; e++) {
    const int in[3] = {!b->nonzero[e], b->ones && b->notone[e], b->atref && !b->atref[e]};
    for (int l = 0; l < 3; l++)
      if (in[l]) {
        if (b->few_n[l] == BLEND_FEW)
          b->few = 0;
        else
          b->few_e[l][b->few_n[l]++] = e;
      }
  }
  const uint64_t n1 = b->few ? b->few_n[1] : UINT32_MAX, rc = b->receiver_cost;
  b->wcost[0] = 0;
  for (uint32_t i = 0; i < n; i++)
    b->wcost[i + 1] = b->wcost[i] + group_cost(&b->groups[b->work[i]], n1, rc);
}

/* Where part p of `parts` starts: work item *item, receiver position *pos in its group.
 * The goal is p·total/parts cost units: the item whose cost range holds it, and in it
 * the receivers before the goal (the group's constant counted at its start). Bounds grow
 * with p; they depend on the work and the part count only. */
static void part_bound(const ub_blend *b, uint32_t p, uint32_t parts, uint32_t *item,
                       uint32_t *pos)
{
  *pos = 0;
  if (p == 0 || b->work_count == 0) {
    *item = 0;
    return;
  }
  if (p >= parts) {
    *item = b->work_count;
    return;
  }
  const uint64_t goal = (uint64_t)p * b->wcost[b->work_count]; /* in cost × parts */
  uint32_t lo = 0, hi = b->work_count; /* first i with wcost[i]·parts > goal */
  while (lo < hi) {
    uint32_t mid = lo + (hi - lo) / 2;
    if (b->wcost[mid] * parts > goal)
      hi = mid;
    else
      lo = mid + 1;
  }
  const uint32_t i = lo - 1; /* wcost[0] = 0 ≤ goal < wcost[n]·parts */
  const blend_group *g = &b->groups[b->work[i]];
  const uint64_t off = (goal - b->wcost[i] * parts) / parts;
  /* the group's cost per receiver as update_begin counted it (its share less the
   * constant; a group has at least one receiver) */
  const uint64_t per = (b->wcost[i + 1] - b->wcost[i] - BLEND_COST_GROUP) / g->receivers;
  const uint64_t q = off <= BLEND_COST_GROUP ? 0 : (off - BLEND_COST_GROUP) / per;
  if (q >= g->receivers) {
    *item = i + 1;
  } else {
    *item = i;
    *pos = (uint32_t)q;
  }
}

uint32_t ub_blend_part_first(const ub_blend *b, uint32_t part, uint32_t parts)
{
  assert(b && parts >= 1 && part <= parts);
  uint32_t item, pos;
  part_bound(b, part, parts, &item, &pos);
  return item;
}

/* Part `part` of `parts` of the update begun: work items [i0, end), item i0 from its
 * receiver position q0, item i1 up to q1 (when a group is cut there). */
typedef struct part_span {
  uint32_t i0, q0, i1, q1, end;
} part_span;

static part_span part_span_of(const ub_blend *b, uint32_t part, uint32_t parts)
{
  part_span p;
  part_bound(b, part, parts, &p.i0, &p.q0);
  part_bound(b, part + 1, parts, &p.i1, &p.q1);
  p.end = p.i1 + (p.q1 > 0);
  if (p.end > b->work_count)
    p.end = b->work_count;
  return p;
}

/* The receiver positions [*lo, *hi) of work item i (group g) inside part p. */
static inline void part_item(const part_span *p, uint32_t i, const blend_group *g, uint32_t *lo,
                             uint32_t *hi)
{
  *lo = i == p->i0 ? p->q0 : 0;
  *hi = i == p->i1 ? p->q1 : g->receivers;
}

void ub_blend_update_part(const ub_blend *b, uint32_t part, uint32_t parts,
                          ub_blend_touched_fn touched, void *user, float *out_values,
                          ub_blend_stats *out_stats)
{
  assert(b && (out_values || touched) && parts >= 1 && part < parts && parts <= b->job_cap);
  ub_blend_stats st;
  memset(&st, 0, sizeof st);
  blend_call c = {b, out_values, &b->js[part], 0, 0, touched, user, 0};
  const part_span p = part_span_of(b, part, parts);
  unsigned csr = ub_fp_mode_enter();
  for (uint32_t i = p.i0; i < p.end; i++) {
    part_item(&p, i, &b->groups[b->work[i]], &c.qlo, &c.qhi);
    if (c.qlo < c.qhi)
      process_group(&c, b->work[i], &st);
  }
  if (touched && !out_values)
    stream_flush(&c);
  ub_fp_mode_leave(csr);
  if (out_stats)
    *out_stats = st;
}

void ub_blend_mark_part(const ub_blend *b, uint32_t part, uint32_t parts,
                        ub_blend_touched_fn touched, void *user, ub_blend_stats *out_stats)
{
  ub_blend_mark_part_ex(b, part, parts, touched, NULL, user, out_stats);
}

void ub_blend_mark_part_ex(const ub_blend *b, uint32_t part, uint32_t parts,
                           ub_blend_touched_fn touched, ub_blend_listed_fn listed, void *user,
                           ub_blend_stats *out_stats)
{
  assert(b && touched && parts >= 1 && part < parts && parts <= b->job_cap);
  ub_blend_stats st;
  memset(&st, 0, sizeof st);
  const part_span p = part_span_of(b, part, parts);
  for (uint32_t i = p.i0; i < p.end; i++) {
    const blend_group *g = &b->groups[b->work[i]];
    uint32_t lo, hi;
    part_item(&p, i, g, &lo, &hi);
    if (lo >= hi)
      continue;
    if (listed && (g->k_mode & GROUP_LIST)) /* unit i of a list is receiver i of the group */
      listed(user, b->units + g->unit_off + lo, hi - lo);
    else
      group_report(b, g, lo, hi, touched, user, NULL);
    st.groups += lo == 0;
    st.receivers += hi - lo;
    st.bytes_read += lo == 0 ? group_table_bytes(g) : 0;
  }
  if (out_stats)
    *out_stats = st;
}

void ub_blend_update(ub_blend *b, ub_blend_touched_fn touched, void *user, float *out_values,
                     ub_blend_stats *out_stats)
{
  ub_blend_update_begin(b, 0);
  ub_blend_update_part(b, 0, 1, touched, user, out_values, out_stats);
}

void ub_blend_update_all(ub_blend *b, ub_blend_touched_fn touched, void *user,
                         float *out_values, ub_blend_stats *out_stats)
{
  ub_blend_update_begin(b, 1);
  ub_blend_update_part(b, 0, 1, touched, user, out_values, out_stats);
}

/* ---- weights ----------------------------------------------------------------------- */

static int finite_f(float x)
{
  uint32_t u;
  memcpy(&u, &x, sizeof u);
  return (u & 0x7f800000u) != 0x7f800000u;
}

/* An element's weight v (RGB) spread over its rows of ex (wstride floats, v[j mod 3]) and,
 * when there is one, pat (32 floats): the forms the kernels read ω (wexp, wpat) and
 * ω − ω1 (dwexp, dwpat) in. */
static void weight_expand(const ub_blend *b, uint32_t element, const float v[3], float *ex,
                          float *pat)
{
  float *we = ex + (size_t)element * b->wstride;
  for (uint32_t j = 0; j < b->wstride; j++)
    we[j] = v[j % 3];
  if (pat)
    for (int j = 0; j < 32; j++)
      pat[32 * (size_t)element + j] = v[j % 3];
}

ub_result ub_blend_set_weight(ub_blend *b, uint32_t element, const float rgb[3])
{
  assert(b && rgb);
  if (element >= b->element_count || !finite_f(rgb[0]) || !finite_f(rgb[1]) ||
      !finite_f(rgb[2]))
    return UB_ERR_INVALID_ARGUMENT;
  float *w = b->weight + (size_t)element * 3;
  if (w[0] == rgb[0] && w[1] == rgb[1] && w[2] == rgb[2])
    return UB_OK;
  for (int c = 0; c < 3; c++)
    w[c] = rgb[c] == 0.0f ? 0.0f : rgb[c]; /* -0 → +0: the same state, the same bits */
  weight_expand(b, element, w, b->wexp, b->wpat);
  b->few = 0;
  b->nonzero[element] = w[0] != 0.0f || w[1] != 0.0f || w[2] != 0.0f;
  if (b->atref) {
    const float *rf = b->ref + (size_t)element * 3;
    b->atref[element] = w[0] == rf[0] && w[1] == rf[1] && w[2] == rf[2];
  }
  if (b->ones) { /* ω − ω1, rounded once per channel, as ub_blend_row computes it */
    const float o = b->ones_w;
    b->notone[element] = w[0] != o || w[1] != o || w[2] != o;
    const float dw[3] = {w[0] - o, w[1] - o, w[2] - o};
    weight_expand(b, element, dw, b->dwexp, b->dwpat);
  }
  /* back at the weight its groups were last computed with: no change (a light switched
   * off and on again before the update costs nothing) */
  const float *u = b->wupd + (size_t)element * 3;
  const int back = w[0] == u[0] && w[1] == u[1] && w[2] == u[2];
  if (back && b->dirty[element]) {
    uint32_t i = 0;
    while (b->dirty_list[i] != element)
      i++;
    b->dirty_list[i] = b->dirty_list[--b->dirty_count];
    b->dirty[element] = 0;
  } else if (!back && !b->dirty[element]) {
    b->dirty[element] = 1;
    b->dirty_list[b->dirty_count++] = element;
  }
  return UB_OK;
}

int ub_blend_pending(const ub_blend *b)
{
  assert(b);
  return b->dirty_count != 0;
}

int ub_blend_element_dirty(const ub_blend *b, uint32_t element)
{
  assert(b);
  return element < b->element_count && b->dirty[element];
}

/* The current weights as the reference (ref, atref); refrows untouched. */
static ub_result take_reference(ub_blend *b)
{
  if (b->dirty_count)
    return UB_ERR_INVALID_ARGUMENT;
  const size_t E = b->element_count ? b->element_count : 1;
  if (!b->ref) {
    float *rf = malloc(E * 3 * sizeof *rf);
    uint8_t *at = malloc(E);
    if (!rf || !at) {
      free(rf);
      free(at);
      return UB_ERR_OUT_OF_MEMORY;
    }
    b->ref = rf;
    b->atref = at;
    b->engine_bytes += E * (3 * sizeof *rf + 1);
  }
  memcpy(b->ref, b->weight, (size_t)b->element_count * 3 * sizeof *b->ref);
  memset(b->atref, 1, E);
  b->few = 0;
  return UB_OK;
}

ub_result ub_blend_set_reference_rows(ub_blend *b, const float *out_values)
{
  assert(b && out_values);
  if (b->dirty_count || !b->obase)
    return UB_ERR_INVALID_ARGUMENT;
  const size_t S = b->stride;
  int fresh = !b->refrows;
  if (fresh) {
    b->refrows = ub_big_alloc((size_t)(b->touched ? b->touched : 1) * S * sizeof(float));
    if (!b->refrows)
      return UB_ERR_OUT_OF_MEMORY;
  }
  ub_result r = take_reference(b);
  if (r != UB_OK) {
    if (fresh) {
      free(b->refrows);
      b->refrows = NULL;
    }
    return r;
  }
  if (fresh)
    b->engine_bytes += (size_t)b->touched * S * sizeof(float);
  for (uint32_t gi = 0; gi < b->group_count; gi++) {
    const blend_group *g = &b->groups[gi];
    float *rr = b->refrows + (size_t)g->base_row * S;
    unit_iter it;
    unit_iter_init(&it, b, g, 0, g->receivers, 0);
    uint32_t rc, s0, s1;
    size_t i0;
    const char *bs;
    while (unit_next(&it, b, &rc, &i0, &bs, &s0, &s1))
      memcpy(rr + (i0 + s0) * S, out_values + (size_t)(rc + s0) * S,
             (size_t)(s1 - s0) * S * sizeof(float));
  }
  return UB_OK;
}

void ub_blend_set_base_report(ub_blend *b, int on)
{
  assert(b);
  b->base_report = on != 0;
}

void ub_blend_set_receiver_cost(ub_blend *b, uint32_t cost)
{
  assert(b);
  b->receiver_cost = cost < 1000 ? cost : 1000;
}

ub_result ub_blend_set_reference(ub_blend *b)
{
  assert(b);
  ub_result r = take_reference(b);
  if (r == UB_OK && b->refrows) { /* rows of an earlier reference: stale now */
    b->engine_bytes -= (size_t)b->touched * b->stride * sizeof(float);
    free(b->refrows);
    b->refrows = NULL;
  }
  return r;
}

void ub_blend_weight(const ub_blend *b, uint32_t element, float out_rgb[3])
{
  assert(b && out_rgb);
  for (int c = 0; c < 3; c++)
    out_rgb[c] = element < b->element_count ? b->weight[(size_t)element * 3 + c] : 0.0f;
}

/* ---- info, free ------------------------------------------------------------------------ */

void ub_blend_get_info(const ub_blend *b, ub_blend_info *out_info)
{
  assert(b && out_info);
  ub_blend_info in;
  memset(&in, 0, sizeof in);
  in.receiver_count = b->receiver_count;
  in.stride = b->stride;
  in.element_count = b->element_count;
  in.touched_receivers = b->touched;
  in.max_overlap = b->max_overlap;
  in.group_count = b->group_count;
  in.run_groups = b->run_groups;
  in.runs = b->runs;
  in.memberships = b->memberships;
  in.engine_bytes = b->engine_bytes;
  in.base_scale = b->bscale;
  in.record_bytes = b->record_bytes;
  in.row_bytes = (uint32_t)b->rowb;
  *out_info = in;
}

size_t ub_blend_memory_bytes(const ub_blend *b)
{
  return b ? b->engine_bytes : 0;
}

/* malloc(n * size) with overflow check; counts what the engine keeps in *acc. */
static void *alloc_n(size_t n, size_t size, size_t *acc)
{
  if (size && n > SIZE_MAX / size)
    return NULL;
  size_t bytes = n * size;
  void *p = ub_big_alloc(bytes);
  if (p && acc)
    *acc += bytes;
  return p;
}

static void scratch_free(blend_scratch *s)
{
  free(s->rows);
  free(s->dec);
  free(s->bdec);
  free(s->act);
  free((void *)s->src);
  free((void *)s->rowp);
  free((void *)s->w);
  free((void *)s->avx_w);
  free((void *)s->avx_src);
  free((void *)s->avx_dec);
  memset(s, 0, sizeof *s);
}

/* One part's scratch; its bytes added to *acc. 0 when out of memory (s freed). */
static int scratch_alloc(const ub_blend *b, blend_scratch *s, size_t *acc)
{
  memset(s, 0, sizeof *s);
  const size_t sk = b->max_overlap > BLEND_SPECIALISED ? b->max_overlap : 1;
  const size_t na = b->max_overlap ? b->max_overlap : 1;
  size_t bytes = 0;
  s->rows = alloc_n((size_t)BLEND_CHUNK * b->stride, sizeof(float), &bytes);
  s->act = alloc_n(sk, sizeof(uint32_t), &bytes);
  s->src = alloc_n(sk, sizeof(char *), &bytes);
  s->rowp = alloc_n(sk, sizeof(float *), &bytes);
  s->w = alloc_n(sk, sizeof(float *), &bytes);
  int ok = s->rows && s->act && s->src && s->rowp && s->w;
  if (b->value_size == 2 || b->q8) {
    s->dec = alloc_n(b->dec_floats, sizeof(float), &bytes);
    ok = ok && s->dec;
  }
  if (b->base_size == 2) {
    s->bdec = alloc_n((size_t)BLEND_CHUNK * b->stride, sizeof(float), &bytes);
    ok = ok && s->bdec;
  }
  if (b->avx) {
    s->avx_w = alloc_n(na, sizeof(float *), &bytes);
    s->avx_src = alloc_n(na, sizeof(char *), &bytes);
    s->avx_dec = alloc_n(na, sizeof(char *), &bytes);
    ok = ok && s->avx_w && s->avx_src && s->avx_dec;
  }
  if (!ok) {
    scratch_free(s);
    return 0;
  }
  if (acc)
    *acc += bytes;
  return 1;
}

ub_result ub_blend_reserve_parts(ub_blend *b, uint32_t parts)
{
  assert(b);
  if (parts == 0 || parts > UB_BLEND_MAX_PARTS)
    return UB_ERR_INVALID_ARGUMENT;
  if (parts <= b->job_cap)
    return UB_OK;
  blend_scratch *js = realloc(b->js, (size_t)parts * sizeof *js);
  if (!js)
    return UB_ERR_OUT_OF_MEMORY;
  b->js = js;
  while (b->job_cap < parts) {
    if (!scratch_alloc(b, &b->js[b->job_cap], &b->engine_bytes))
      return UB_ERR_OUT_OF_MEMORY;
    b->engine_bytes += sizeof *js;
    b->job_cap++;
  }
  return UB_OK;
}

void ub_blend_free(ub_blend *b)
{
  if (!b)
    return;
  free(b->weight);
  free(b->wexp);
  free(b->nonzero);
  free(b->dirty);
  free(b->dirty_list);
  free(b->wupd);
  free(b->groups);
  free(b->obase);
  free(b->members);
  free(b->moff);
  free(b->units);
  free(b->values);
  free(b->elem_off);
  free(b->elem_groups);
  free(b->stamp);
  free(b->work);
  free(b->wcost);
  for (uint32_t j = 0; b->js && j < b->job_cap; j++)
    scratch_free(&b->js[j]);
  free(b->js);
  free(b->wpat);
  free(b->ones);
  free(b->notone);
  free(b->dwexp);
  free(b->dwpat);
  free(b->rmap);
  free(b->rdir);
  free(b->wlast);
  free(b->ref);
  free(b->atref);
  free(b->refrows);
  free(b);
}

/* ---- create ------------------------------------------------------------------------ */


static void *calloc_n(size_t n, size_t size, size_t *acc)
{
  void *p = ub_big_calloc(n, size);
  if (p && acc)
    *acc += n * size;
  return p;
}

static uint32_t combo_hash(const uint32_t *e, uint32_t k)
{
  uint64_t h = 0x9E3779B97F4A7C15ull ^ k;
  for (uint32_t i = 0; i < k; i++) {
    h = (h ^ e[i]) * 0xff51afd7ed558ccdull;
    h ^= h >> 32;
  }
  return (uint32_t)h;
}

static const char *desc_name(const ub_blend_desc *d)
{
  return d->name ? d->name : "(unnamed)";
}

static ub_result validate(const ub_blend_desc *d, const ub_log *log, uint64_t *out_memberships)
{
  const char *nm = desc_name(d);
  if ((d->receiver_count && !d->base) || (d->element_count && !d->elements)) {
    ub_log_printf(log, UB_LOG_ERROR, "blend %s: NULL base or elements", nm);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (d->stride < 3 || d->stride > UB_BLEND_MAX_STRIDE || d->stride % 3) {
    ub_log_printf(log, UB_LOG_ERROR, "blend %s: stride %u is not a multiple of 3 in 3..%d", nm,
                  d->stride, UB_BLEND_MAX_STRIDE);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if ((d->storage != UB_BLEND_FLOAT32 && d->storage != UB_BLEND_FLOAT16) ||
      ((d->flags & UB_BLEND_STORE_HALF) && d->storage != UB_BLEND_FLOAT32) ||
      ((d->flags & UB_BLEND_STORE_HALF) && (d->flags & UB_BLEND_STORE_Q8))) {
    ub_log_printf(log, UB_LOG_ERROR, "blend %s: unknown storage %d (UB_BLEND_STORE_HALF "
                  "takes float records, and not with UB_BLEND_STORE_Q8)", nm, (int)d->storage);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if ((d->flags & (UB_BLEND_BASE_HALF | UB_BLEND_ONES_SUM)) && !(d->flags & UB_BLEND_OWN_BASE)) {
    ub_log_printf(log, UB_LOG_ERROR, "blend %s: UB_BLEND_BASE_HALF and UB_BLEND_ONES_SUM need "
                  "UB_BLEND_OWN_BASE", nm);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (!finite_f(d->ones_weight)) {
    ub_log_printf(log, UB_LOG_ERROR, "blend %s: ones_weight is not finite", nm);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if ((uint64_t)d->receiver_count * d->stride > SIZE_MAX / sizeof(float)) {
    ub_log_printf(log, UB_LOG_ERROR, "blend %s: %u receivers are too many", nm,
                  d->receiver_count);
    return UB_ERR_OUT_OF_MEMORY;
  }
  size_t nb = (size_t)d->receiver_count * d->stride;
  for (size_t i = 0; i < nb; i++)
    if (!finite_f(d->base[i])) {
      ub_log_printf(log, UB_LOG_ERROR, "blend %s: base value %zu (receiver %zu) is not finite",
                    nm, i % d->stride, i / d->stride);
      return UB_ERR_INVALID_DATA;
    }
  uint64_t total = 0;
  for (uint32_t e = 0; e < d->element_count; e++) {
    const ub_blend_record *r = &d->elements[e];
    if (r->count && (!r->receivers || !r->values)) {
      ub_log_printf(log, UB_LOG_ERROR, "blend %s: element %u: NULL receivers or values", nm, e);
      return UB_ERR_INVALID_ARGUMENT;
    }
    for (uint32_t i = 0; i < r->count; i++) {
      uint32_t x = r->receivers[i];
      if (x >= d->receiver_count) {
        ub_log_printf(log, UB_LOG_ERROR,
                      "blend %s: element %u: receiver index %u at position %u is out of "
                      "range (%u receivers)", nm, e, x, i, d->receiver_count);
        return UB_ERR_INVALID_DATA;
      }
      if (i && x <= r->receivers[i - 1]) {
        ub_log_printf(log, UB_LOG_ERROR,
                      "blend %s: element %u: receiver index %u at position %u is not above "
                      "the previous one (%u): indices must be sorted and unique", nm, e, x, i,
                      r->receivers[i - 1]);
        return UB_ERR_INVALID_DATA;
      }
    }
    size_t nv = (size_t)r->count * d->stride;
    const int to_half = (d->flags & UB_BLEND_STORE_HALF) != 0;
    const int q8 = (d->flags & UB_BLEND_STORE_Q8) != 0;
    for (size_t i = 0; i < nv; i++) {
      /* rounded to half: the whole row (STORE_HALF), the DC (STORE_Q8) */
      const int rh = to_half || (q8 && i % d->stride < 3);
      int ok = d->storage == UB_BLEND_FLOAT16
                   ? ub_half_is_finite(((const uint16_t *)r->values)[i])
               : rh ? fabsf(((const float *)r->values)[i]) < 65520.0f /* rounds to finite
                                                                            half */
                    : finite_f(((const float *)r->values)[i]);
      if (!ok) {
        ub_log_printf(log, UB_LOG_ERROR,
                      "blend %s: element %u: value %zu of receiver %u (position %zu) is not "
                      "finite", nm, e, i % d->stride, r->receivers[i / d->stride],
                      i / d->stride);
        return UB_ERR_INVALID_DATA;
      }
    }
    total += r->count;
  }
  if (total >= UINT32_MAX) {
    ub_log_printf(log, UB_LOG_ERROR, "blend %s: %llu element-receiver pairs are too many", nm,
                  (unsigned long long)total);
    return UB_ERR_OUT_OF_MEMORY;
  }
  *out_memberships = total;
  return UB_OK;
}

/* Temporaries of create. */
typedef struct build_tmp {
  uint32_t *off;      /* receiver_count + 1: memberships of receiver r = [off[r], off[r+1]) */
  uint32_t *m_elem;   /* per membership: element id (ascending within a receiver) */
  uint32_t *touched;  /* touched receivers, ascending */
  uint32_t *gid;      /* per touched receiver: its group */
  uint32_t *g_k, *g_moff, *g_hash, *g_n, *g_start, *g_units;
  uint32_t *members;  /* capacity: memberships */
  uint32_t *table;    /* hash: group id + 1, 0 = empty */
  uint32_t *order;    /* touched receivers sorted by group */
  uint32_t *r_gid, *r_at; /* receiver_count: a touched receiver's group, its place in it */
} build_tmp;

static void build_tmp_free(build_tmp *t)
{
  free(t->off);
  free(t->m_elem);
  free(t->touched);
  free(t->gid);
  free(t->g_k);
  free(t->g_moff);
  free(t->g_hash);
  free(t->g_n);
  free(t->g_start);
  free(t->g_units);
  free(t->members);
  free(t->table);
  free(t->order);
  free(t->r_gid);
  free(t->r_at);
}

static ub_result build(ub_blend *b, const ub_blend_desc *d, build_tmp *t,
                       void (*values_done)(void *user, uint32_t element), void *user)
{
  const uint32_t R = d->receiver_count, E = d->element_count;
  const uint64_t M = b->memberships;
  size_t *acc = &b->engine_bytes;

  /* 1. Per receiver, its elements (ascending id, as elements are visited in order). */
  t->off = calloc_n((size_t)R + 1, sizeof(uint32_t), NULL);
  t->m_elem = alloc_n(M, sizeof(uint32_t), NULL);
  if (!t->off || !t->m_elem)
    return UB_ERR_OUT_OF_MEMORY;
  for (uint32_t e = 0; e < E; e++)
    for (uint32_t i = 0; i < d->elements[e].count; i++)
      t->off[d->elements[e].receivers[i] + 1]++;
  uint32_t T = 0, maxk = 0;
  for (uint32_t r = 0; r < R; r++) {
    uint32_t k = t->off[r + 1];
    T += k != 0;
    maxk = k > maxk ? k : maxk;
    t->off[r + 1] += t->off[r];
  }
  for (uint32_t e = 0; e < E; e++)
    for (uint32_t i = 0; i < d->elements[e].count; i++) {
      uint32_t r = d->elements[e].receivers[i], at = t->off[r]++;
      t->m_elem[at] = e;
    }
  for (uint32_t r = R; r > 0; r--) /* the fill advanced off[r] to off[r+1]: shift back */
    t->off[r] = t->off[r - 1];
  t->off[0] = 0;
  b->touched = T;
  b->max_overlap = maxk;

  /* 2. Groups by combination (hash of the sorted element list), in order of first
   * receiver, so group order is receiver order. */
  t->touched = alloc_n(T, sizeof(uint32_t), NULL);
  t->gid = alloc_n(T, sizeof(uint32_t), NULL);
  t->g_k = alloc_n(T, sizeof(uint32_t), NULL);
  t->g_moff = alloc_n(T, sizeof(uint32_t), NULL);
  t->g_hash = alloc_n(T, sizeof(uint32_t), NULL);
  t->g_n = calloc_n(T, sizeof(uint32_t), NULL);
  t->members = alloc_n(M, sizeof(uint32_t), NULL);
  size_t cap = 16;
  while (cap < (size_t)T * 2)
    cap *= 2;
  t->table = calloc_n(cap, sizeof(uint32_t), NULL);
  if (!t->touched || !t->gid || !t->g_k || !t->g_moff || !t->g_hash || !t->g_n ||
      !t->members || !t->table)
    return UB_ERR_OUT_OF_MEMORY;
  uint32_t G = 0, nmem = 0, ti = 0;
  for (uint32_t r = 0; r < R; r++) {
    uint32_t k = t->off[r + 1] - t->off[r];
    if (!k)
      continue;
    const uint32_t *el = t->m_elem + t->off[r];
    uint32_t h = combo_hash(el, k);
    size_t s = h & (cap - 1);
    uint32_t g = UINT32_MAX;
    for (;; s = (s + 1) & (cap - 1)) {
      uint32_t v = t->table[s];
      if (!v)
        break;
      v--;
      if (t->g_hash[v] == h && t->g_k[v] == k &&
          !memcmp(t->members + t->g_moff[v], el, k * sizeof(uint32_t))) {
        g = v;
        break;
      }
    }
    if (g == UINT32_MAX) {
      g = G++;
      t->table[s] = g + 1;
      t->g_k[g] = k;
      t->g_hash[g] = h;
      t->g_moff[g] = nmem;
      memcpy(t->members + nmem, el, k * sizeof(uint32_t));
      nmem += k;
    }
    t->g_n[g]++;
    t->touched[ti] = r;
    t->gid[ti++] = g;
  }
  b->group_count = G;

  /* 3. Receivers of each group, ascending (stable counting sort by group). */
  t->g_start = alloc_n((size_t)G + 1, sizeof(uint32_t), NULL);
  t->g_units = alloc_n(G, sizeof(uint32_t), NULL);
  t->order = alloc_n(T, sizeof(uint32_t), NULL);
  if (!t->g_start || !t->g_units || !t->order)
    return UB_ERR_OUT_OF_MEMORY;
  t->g_start[0] = 0;
  for (uint32_t g = 0; g < G; g++)
    t->g_start[g + 1] = t->g_start[g] + t->g_n[g];
  for (uint32_t i = 0; i < T; i++)
    t->order[t->g_start[t->gid[i]]++] = t->touched[i];
  for (uint32_t g = G; g > 0; g--)
    t->g_start[g] = t->g_start[g - 1];
  t->g_start[0] = 0;

  /* 4. Storage per group: runs or list, whichever is smaller. */
  b->groups = alloc_n(G, sizeof(blend_group), acc);
  b->members = alloc_n(nmem, sizeof(uint32_t), acc);
  if (!b->groups || !b->members)
    return UB_ERR_OUT_OF_MEMORY;
  memcpy(b->members, t->members, (size_t)nmem * sizeof(uint32_t));
  uint64_t words = 0, vals = 0; /* rows */
  for (uint32_t g = 0; g < G; g++) {
    const uint32_t *rs = t->order + t->g_start[g];
    uint32_t n = t->g_n[g], k = t->g_k[g], runs = 1;
    for (uint32_t i = 1; i < n; i++)
      runs += rs[i] != rs[i - 1] + 1;
    int list = n < 2 * (uint64_t)runs; /* one word per receiver vs two per run */
    blend_group *bg = &b->groups[g];
    bg->unit_off = words;
    bg->member_off = t->g_moff[g];
    bg->receivers = n;
    bg->units = list ? n : runs;
    bg->k_mode = k | (list ? GROUP_LIST : 0);
    bg->base_row = 0;
    bg->ones_row = ONES_NONE;
    words += list ? (uint64_t)n : 2 * (uint64_t)runs;
    vals += (uint64_t)n * k;
    if (!list) {
      b->run_groups++;
      b->runs += runs;
    }
  }
  assert(vals == M);
  b->unit_words = words;
  b->units = alloc_n(words, sizeof(uint32_t), acc);
  b->values = alloc_n(vals, b->rowb, NULL); /* counted as record_bytes */
  b->moff = alloc_n(nmem ? nmem : 1, sizeof(uint32_t), acc);
  if (!b->units || !b->values || !b->moff)
    return UB_ERR_OUT_OF_MEMORY;
  { /* element-major rows: element e's from Σ of the earlier elements' counts, its groups
     * in ascending order (each of its receivers is in one of them) */
    uint32_t *cur = alloc_n((size_t)E + 1, sizeof(uint32_t), NULL);
    if (!cur)
      return UB_ERR_OUT_OF_MEMORY;
    cur[0] = 0;
    for (uint32_t e = 0; e < E; e++)
      cur[e + 1] = cur[e] + d->elements[e].count;
    for (uint32_t g = 0; g < G; g++) {
      const blend_group *bg = &b->groups[g];
      for (uint32_t m = 0; m < (bg->k_mode & ~GROUP_LIST); m++) {
        const uint32_t e = b->members[bg->member_off + m];
        b->moff[bg->member_off + m] = cur[e];
        cur[e] += bg->receivers;
      }
    }
    free(cur);
  }
  const size_t rowb = b->rowb;
  /* UB_BLEND_STORE_HALF: float records kept as half; UB_BLEND_STORE_Q8: either kind kept
   * as 8-bit rows. */
  const int to_half = d->storage == UB_BLEND_FLOAT32 && b->value_size == 2 && !b->q8;
  const size_t srcb = (size_t)b->stride * (d->storage == UB_BLEND_FLOAT16 ? 2 : 4);
  for (uint32_t g = 0; g < G; g++) {
    const blend_group *bg = &b->groups[g];
    const uint32_t *rs = t->order + t->g_start[g];
    uint32_t n = bg->receivers;
    uint32_t *w = b->units + bg->unit_off;
    for (uint32_t i = 0; i < n;) {
      uint32_t len = 1;
      if (!(bg->k_mode & GROUP_LIST))
        while (i + len < n && rs[i + len] == rs[i] + len)
          len++;
      *w++ = rs[i];
      if (!(bg->k_mode & GROUP_LIST))
        *w++ = len;
      i += len;
    }
    assert(w == b->units + bg->unit_off + bg->units * ((bg->k_mode & GROUP_LIST) ? 1u : 2u));
  }
  /* The values, element by element (values_done may free each one's after): member m's
   * row for a group's receiver at place i is row moff[member_off + m] + i (members =
   * ascending element ids, as m_elem lists them per receiver). A receiver's group and
   * place in it: t->gid (by touched rank, in receiver order) as r_gid, and r_at. */
  t->r_gid = alloc_n(R ? R : 1, sizeof(uint32_t), NULL);
  t->r_at = alloc_n(R ? R : 1, sizeof(uint32_t), NULL);
  if (!t->r_gid || !t->r_at)
    return UB_ERR_OUT_OF_MEMORY;
  for (uint32_t g = 0; g < G; g++)
    for (uint32_t i = 0; i < b->groups[g].receivers; i++)
      t->r_at[t->order[t->g_start[g] + i]] = i;
  for (uint32_t ti = 0; ti < T; ti++)
    t->r_gid[t->touched[ti]] = t->gid[ti];
  for (uint32_t e = 0; e < E; e++) {
    const ub_blend_record *er = &d->elements[e];
    for (uint32_t pos = 0; pos < er->count; pos++) {
      const uint32_t r = er->receivers[pos], g = t->r_gid[r], i = t->r_at[r];
      const blend_group *bg = &b->groups[g];
      uint32_t m = 0;
      while (t->m_elem[t->off[r] + m] != e)
        m++;
      assert(m < (bg->k_mode & ~GROUP_LIST));
      char *v = (char *)b->values + ((size_t)b->moff[bg->member_off + m] + i) * rowb;
      const char *src = (const char *)er->values + (size_t)pos * srcb;
      if (b->q8) {
        float f[UB_BLEND_MAX_STRIDE];
        const uint16_t *h = d->storage == UB_BLEND_FLOAT16 ? (const uint16_t *)(const void *)src
                                                           : NULL;
        if (h)
          for (uint32_t j = 0; j < b->stride; j++)
            f[j] = ub_half_to_float(h[j]);
        else
          memcpy(f, src, (size_t)b->stride * sizeof(float));
        q8_encode(f, h, b->stride, (unsigned char *)v, rowb);
      } else if (to_half) {
        const float *f = (const float *)(const void *)src;
        uint16_t *h = (uint16_t *)(void *)v;
        for (uint32_t j = 0; j < b->stride; j++)
          h[j] = ub_half_from_float(f[j]);
      } else {
        memcpy(v, src, rowb);
      }
    }
    if (values_done)
      values_done(user, e);
  }

  /* 4b. UB_BLEND_OWN_BASE: the touched receivers' base rows, in group order. */
  if (d->flags & UB_BLEND_OWN_BASE) {
    const uint32_t S = b->stride;
    b->obase = alloc_n((size_t)T * S, b->base_size, acc);
    if (!b->obase)
      return UB_ERR_OUT_OF_MEMORY;
    if (b->base_size == 2) { /* the scale: the touched rows' largest |value| ≤ 32768 */
      float mx = 0.0f;
      for (uint32_t i = 0; i < T; i++)
        for (uint32_t j = 0; j < S; j++) { /* finite (validated): a compare, no libm call */
          const float v = fabsf(d->base[(size_t)t->order[i] * S + j]);
          mx = v > mx ? v : mx;
        }
      while (mx / b->bscale > 32768.0f)
        b->bscale *= 2.0f;
    }
    uint32_t row = 0;
    for (uint32_t g = 0; g < G; g++) {
      b->groups[g].base_row = row;
      const uint32_t *rs = t->order + t->g_start[g];
      for (uint32_t i = 0; i < t->g_n[g]; i++, row++) {
        const float *src = d->base + (size_t)rs[i] * S;
        if (b->base_size == 2) {
          uint16_t *h = (uint16_t *)(void *)b->obase + (size_t)row * S;
          for (uint32_t j = 0; j < S; j++) /* exact division: a power of two */
            h[j] = ub_half_from_float(src[j] / b->bscale);
        } else {
          memcpy(b->obase + (size_t)row * S * sizeof(float), src, (size_t)S * sizeof(float));
        }
      }
    }
  }

  /* 5. Element → groups holding it (ascending group id). */
  b->elem_off = calloc_n((size_t)E + 1, sizeof(uint32_t), acc);
  b->elem_groups = alloc_n(nmem, sizeof(uint32_t), acc);
  if (!b->elem_off || !b->elem_groups)
    return UB_ERR_OUT_OF_MEMORY;
  for (uint32_t i = 0; i < nmem; i++)
    b->elem_off[b->members[i] + 1]++;
  for (uint32_t e = 0; e < E; e++)
    b->elem_off[e + 1] += b->elem_off[e];
  for (uint32_t g = 0; g < G; g++) {
    const blend_group *bg = &b->groups[g];
    for (uint32_t m = 0; m < (bg->k_mode & ~GROUP_LIST); m++)
      b->elem_groups[b->elem_off[b->members[bg->member_off + m]]++] = g;
  }
  for (uint32_t e = E; e > 0; e--)
    b->elem_off[e] = b->elem_off[e - 1];
  b->elem_off[0] = 0;

  /* 6. Update state and scratch. */
  b->stamp = calloc_n(G, sizeof(uint32_t), acc);
  b->work = alloc_n(G, sizeof(uint32_t), acc);
  b->wcost = alloc_n((size_t)G + 1, sizeof(uint64_t), acc);
  if (!b->stamp || !b->work || !b->wcost)
    return UB_ERR_OUT_OF_MEMORY;
  b->wcost[0] = 0;
  b->dec_floats = (size_t)maxk * b->stride > BLEND_DECODE_FLOATS
                      ? (size_t)maxk * b->stride : BLEND_DECODE_FLOATS;
#if BLEND_F16C
  if (b->avx) {
    size_t ne = E ? E : 1;
    b->wpat = aligned_alloc(32, ne * 32 * sizeof(float));
    if (!b->wpat)
      return UB_ERR_OUT_OF_MEMORY;
    memset(b->wpat, 0, ne * 32 * sizeof(float)); /* every weight starts at 0 */
    *acc += ne * 32 * sizeof(float);
  }
#endif
  /* part 0's scratch (a plain update's) */
  b->js = alloc_n(1, sizeof *b->js, acc);
  if (!b->js || !scratch_alloc(b, &b->js[0], acc))
    return UB_ERR_OUT_OF_MEMORY;
  b->job_cap = 1;
  return UB_OK;
}

static int unit_ref_cmp(const void *pa, const void *pb)
{
  const blend_unit_ref *a = pa, *b = pb;
  return a->first < b->first ? -1 : a->first > b->first;
}

/* rmap: every unit of every group, sorted by first receiver (units never overlap); wlast:
 * the weights at create (all 0). */
static ub_result build_rmap(ub_blend *b)
{
  uint64_t n = 0;
  for (uint32_t g = 0; g < b->group_count; g++)
    n += b->groups[g].units;
  b->rmap = alloc_n((size_t)n, sizeof *b->rmap, &b->engine_bytes);
  b->wlast = calloc_n((size_t)b->element_count * 3, sizeof(float), &b->engine_bytes);
  if (!b->rmap || !b->wlast)
    return UB_ERR_OUT_OF_MEMORY;
  uint64_t k = 0;
  for (uint32_t g = 0; g < b->group_count; g++) {
    const blend_group *bg = &b->groups[g];
    const int list = (bg->k_mode & GROUP_LIST) != 0;
    const uint32_t *u = b->units + bg->unit_off;
    uint32_t pos = 0;
    for (uint32_t i = 0; i < bg->units; i++) {
      blend_unit_ref *e = &b->rmap[k++];
      e->first = u[0];
      e->len = list ? 1 : u[1];
      e->group = g;
      e->pos = pos;
      pos += e->len;
      u += list ? 1 : 2;
    }
  }
  qsort(b->rmap, (size_t)n, sizeof *b->rmap, unit_ref_cmp);
  b->rmap_count = n;
  if ((uint64_t)b->receiver_count * sizeof *b->rdir <= n * sizeof *b->rmap && n < UINT32_MAX) {
    b->rdir = calloc_n(b->receiver_count, sizeof *b->rdir, &b->engine_bytes);
    if (!b->rdir)
      return UB_ERR_OUT_OF_MEMORY;
    for (uint64_t i = 0; i < n; i++)
      for (uint32_t j = 0; j < b->rmap[i].len; j++)
        b->rdir[b->rmap[i].first + j] = (uint32_t)i + 1;
  }
  return UB_OK;
}

#if BLEND_F16C
/* out[j] = out[j] + Σ_m ω_m[j mod 3]·v_m[j] over the n half rows src[m] (S values each),
 * members in order, each term rounded then added as in the scalar loop (F16C converts
 * exactly): the same bits. The sums stay in registers across the members (S a
 * compile-time constant: 8 lanes at a time, the last S mod 8 values as scalars, no read
 * past a row). */
BLEND_AVX_INLINE void row_sum_avx_s(const float *const *w, const char *const *src, uint32_t n,
                                    float *out, const uint32_t S)
{
  __m256 acc[6];
  float tail[8];
  const uint32_t nv = S / 8;
  for (uint32_t v = 0; v < nv; v++)
    acc[v] = _mm256_loadu_ps(out + 8 * v);
  for (uint32_t j = 8 * nv; j < S; j++)
    tail[j - 8 * nv] = out[j];
  for (uint32_t m = 0; m < n; m++) {
    const float *wm = w[m];
    const uint16_t *h = (const uint16_t *)(const void *)src[m];
    const __m256 p[3] = {_mm256_setr_ps(wm[0], wm[1], wm[2], wm[0], wm[1], wm[2], wm[0], wm[1]),
                         _mm256_setr_ps(wm[2], wm[0], wm[1], wm[2], wm[0], wm[1], wm[2], wm[0]),
                         _mm256_setr_ps(wm[1], wm[2], wm[0], wm[1], wm[2], wm[0], wm[1], wm[2])};
    for (uint32_t v = 0; v < nv; v++) {
      __m256 x = _mm256_cvtph_ps(_mm_loadu_si128((const __m128i *)(const void *)(h + 8 * v)));
      acc[v] = _mm256_add_ps(acc[v], _mm256_mul_ps(p[v % 3], x));
    }
    for (uint32_t j = 8 * nv; j < S; j++) {
      float t = wm[j % 3] * ub_half_to_float(h[j]);
      tail[j - 8 * nv] = tail[j - 8 * nv] + t;
    }
  }
  for (uint32_t v = 0; v < nv; v++)
    _mm256_storeu_ps(out + 8 * v, acc[v]);
  for (uint32_t j = 8 * nv; j < S; j++)
    out[j] = tail[j - 8 * nv];
}

BLEND_AVX static void row_sum_avx(const float *const *w, const char *const *src, uint32_t n,
                                  float *out, uint32_t S)
{
  switch (S) {
  case 12: row_sum_avx_s(w, src, n, out, 12); break;
  case 27: row_sum_avx_s(w, src, n, out, 27); break;
  default: row_sum_avx_s(w, src, n, out, S); break;
  }
}
#endif

int ub_blend_row(const ub_blend *b, uint32_t r, float *out_row)
{
  assert(b && out_row);
  if (!b->rmap || r >= b->receiver_count)
    return 0;
  const uint32_t S = b->stride;
  uint64_t lo = 0, hi = b->rmap_count; /* first unit starting after r */
  if (b->rdir)
    lo = hi = b->rdir[r]; /* its unit + 1, 0: none */
  while (lo < hi) {
    uint64_t mid = (lo + hi) / 2;
    if (b->rmap[mid].first <= r)
      lo = mid + 1;
    else
      hi = mid;
  }
  const blend_unit_ref *e = lo ? &b->rmap[lo - 1] : NULL;
  if (!e || r - e->first >= e->len) { /* no element touches r */
    if (!b->base)
      return 0;
    memcpy(out_row, b->base + (size_t)r * S, S * sizeof(float));
    return 1;
  }
  const blend_group *g = &b->groups[e->group];
  const uint32_t pos = e->pos + (r - e->first), gk = g->k_mode & ~GROUP_LIST;
  const char *bsu = b->obase ? b->obase + ((size_t)g->base_row + pos) * S * b->base_size
                             : (const char *)(b->base + (size_t)r * S);
  const size_t vs = b->value_size, rowb = b->rowb;
  const uint32_t *mem = b->members + g->member_off;
  /* As the kernels: the base row, then the members in id order, those with a non-zero
   * weight only, each term ω[j mod 3]·v rounded to float, then added (C11 evaluates float
   * in float here: FLT_EVAL_METHOD 0 on x86-64, and the build does not contract to FMA),
   * with FTZ/DAZ off as during an update (the caller's mode is restored). */
  /* the non-zero members (up to ROW_LISTED of them listed): their rows, one stream each
   * and far apart, requested together so their misses overlap */
  /* UB_BLEND_ONES_SUM: the update's choice for this group under these weights
   * (process_group): from its all-ones sums, the members with ω ≠ ω1 weighted by ω − ω1
   * (ω1 = ones_w, 1 unless the desc said otherwise) */
  int ones = 0;
  const float o1 = b->ones_w;
  if (g->ones_row != ONES_NONE) {
    uint32_t n1 = 0, nz = 0;
    for (uint32_t m = 0; m < gk; m++) {
      const float *w = b->wlast + (size_t)mem[m] * 3;
      nz += w[0] != 0.0f || w[1] != 0.0f || w[2] != 0.0f;
      n1 += w[0] != o1 || w[1] != o1 || w[2] != o1;
    }
    ones = ones_cheaper(b, n1, nz);
  }
  enum { ROW_LISTED = BLEND_SPECIALISED * 4 };
  const float *wl[ROW_LISTED];
  const char *sl[ROW_LISTED];
  float dwl[ROW_LISTED][3];
  uint32_t nl = 0;
  for (uint32_t m = 0; m < gk && gk <= ROW_LISTED; m++) {
    const float *w = b->wlast + (size_t)mem[m] * 3;
    if (ones ? w[0] == o1 && w[1] == o1 && w[2] == o1
             : w[0] == 0.0f && w[1] == 0.0f && w[2] == 0.0f)
      continue;
    if (ones) {
      for (int c = 0; c < 3; c++)
        dwl[nl][c] = w[c] - o1; /* as set_weight's patterns */
      w = dwl[nl];
    }
    wl[nl] = w;
    sl[nl] = member_rows(b, g, m, pos);
    __builtin_prefetch(sl[nl]);
    __builtin_prefetch(sl[nl] + rowb - 1);
    nl++;
  }
  unsigned csr = ub_fp_mode_enter();
  if (ones)
    memcpy(out_row, b->ones + ((size_t)g->ones_row + pos) * S, S * sizeof(float));
  else if (b->base_size == 2)
    decode_base(b, bsu, out_row, S);
  else
    memcpy(out_row, bsu, S * sizeof(float));
#if BLEND_F16C
  if (b->avx2 && b->q8 && (S == 12 || S == 27) && gk <= ROW_LISTED) {
    row_sum_q8_avx2(wl, sl, nl, out_row, S);
    ub_fp_mode_leave(csr);
    return 1;
  }
  if (b->avx && vs == 2 && !b->q8 && gk <= ROW_LISTED) {
    row_sum_avx(wl, sl, nl, out_row, S);
    ub_fp_mode_leave(csr);
    return 1;
  }
#endif
  for (uint32_t m = 0; m < gk; m++) {
    const float *w = b->wlast + (size_t)mem[m] * 3;
    if (ones ? w[0] == o1 && w[1] == o1 && w[2] == o1
             : w[0] == 0.0f && w[1] == 0.0f && w[2] == 0.0f)
      continue;
    float dw[3];
    if (ones) {
      for (int c = 0; c < 3; c++)
        dw[c] = w[c] - o1;
      w = dw;
    }
    const char *src = member_rows(b, g, m, pos);
    if (b->q8) {
      float v[UB_BLEND_MAX_STRIDE];
      q8_decode(b, src, v, 1);
      for (uint32_t j = 0; j < S; j++) {
        float t = w[j % 3] * v[j];
        out_row[j] = out_row[j] + t;
      }
      continue;
    }
    for (uint32_t j = 0; j < S; j++) {
      float v = vs == 2 ? ub_half_to_float(((const uint16_t *)(const void *)src)[j])
                        : ((const float *)(const void *)src)[j];
      float t = w[j % 3] * v;
      out_row[j] = out_row[j] + t;
    }
  }
  ub_fp_mode_leave(csr);
  return 1;
}

/* UB_BLEND_ONES_SUM: the all-ones sums of the groups of BLEND_ONES_MIN_K or more members,
 * base + Σ rows as the engine holds them (decoded exactly), summed in double and rounded
 * once; every element's ω − 1 patterns at ω = 0. */
static ub_result build_ones(ub_blend *b)
{
  const uint32_t S = b->stride, E = b->element_count;
  uint64_t rows = 0;
  for (uint32_t g = 0; g < b->group_count; g++) {
    blend_group *bg = &b->groups[g];
    bg->ones_row = ONES_NONE;
    if ((bg->k_mode & ~GROUP_LIST) >= BLEND_ONES_MIN_K) {
      bg->ones_row = (uint32_t)rows; /* rows ≤ touched receivers < 2^32 */
      rows += bg->receivers;
    }
  }
  b->ones_rows = rows;
  size_t *acc = &b->engine_bytes;
  b->ones = alloc_n((size_t)(rows ? rows : 1) * S, sizeof(float), acc);
  b->notone = alloc_n(E ? E : 1, 1, acc);
  size_t wbytes = (size_t)(E ? E : 1) * b->wstride * sizeof(float);
  b->dwexp = aligned_alloc(16, wbytes);
  if (!b->ones || !b->notone || !b->dwexp)
    return UB_ERR_OUT_OF_MEMORY;
  *acc += wbytes;
  memset(b->notone, 1, E ? E : 1); /* every weight starts at 0: ω − ω1 = −ω1 */
  for (size_t j = 0; j < wbytes / sizeof(float); j++)
    b->dwexp[j] = 0.0f - b->ones_w;
  if (b->wpat) {
    const size_t pb = (size_t)(E ? E : 1) * 32 * sizeof(float);
    b->dwpat = aligned_alloc(32, pb);
    if (!b->dwpat)
      return UB_ERR_OUT_OF_MEMORY;
    *acc += pb;
    for (size_t j = 0; j < pb / sizeof(float); j++)
      b->dwpat[j] = 0.0f - b->ones_w;
  }
  unsigned csr = ub_fp_mode_enter(); /* exact decoding needs DAZ off */
  float v[UB_BLEND_MAX_STRIDE];
  double sum[UB_BLEND_MAX_STRIDE];
  for (uint32_t g = 0; g < b->group_count; g++) {
    const blend_group *bg = &b->groups[g];
    if (bg->ones_row == ONES_NONE)
      continue;
    const size_t gk = bg->k_mode & ~GROUP_LIST;
    for (uint32_t i = 0; i < bg->receivers; i++) {
      const char *bs = b->obase + ((size_t)bg->base_row + i) * S * b->base_size;
      if (b->base_size == 2)
        decode_base(b, bs, v, S);
      else
        memcpy(v, bs, (size_t)S * sizeof(float));
      for (uint32_t j = 0; j < S; j++)
        sum[j] = v[j];
      for (size_t m = 0; m < gk; m++) {
        const char *src = member_rows(b, bg, m, i);
        if (b->q8)
          q8_decode(b, src, v, 1);
        else if (b->value_size == 2)
          b->decode((const uint16_t *)(const void *)src, v, S); /* exact: any decoder */
        else
          memcpy(v, src, (size_t)S * sizeof(float));
        for (uint32_t j = 0; j < S; j++)
          sum[j] += (double)b->ones_w * v[j];
      }
      float *o = b->ones + ((size_t)bg->ones_row + i) * S;
      for (uint32_t j = 0; j < S; j++)
        o[j] = (float)sum[j];
    }
  }
  ub_fp_mode_leave(csr);
  return UB_OK;
}

ub_result ub_blend_create(const ub_blend_desc *desc, const ub_log *log, float *out_values,
                          ub_blend **out_blend)
{
  return ub_blend_create_ex(desc, log, out_values, NULL, NULL, out_blend);
}

ub_result ub_blend_create_ex(const ub_blend_desc *desc, const ub_log *log, float *out_values,
                             void (*values_done)(void *user, uint32_t element), void *user,
                             ub_blend **out_blend)
{
  if (!desc || !out_blend)
    return UB_ERR_INVALID_ARGUMENT;
  uint64_t memberships = 0;
  ub_result res = validate(desc, log, &memberships);
  if (res != UB_OK)
    return res;

  const uint32_t E = desc->element_count, S = desc->stride;
  ub_blend *b = calloc(1, sizeof *b);
  if (!b)
    goto oom;
  b->engine_bytes = sizeof *b;
  b->receiver_count = desc->receiver_count;
  b->stride = S;
  b->wstride = (S + 3) & ~3u;
  b->element_count = E;
  b->value_size = desc->storage == UB_BLEND_FLOAT16 || (desc->flags & UB_BLEND_STORE_HALF) ? 2 : 4;
  b->q8 = (desc->flags & UB_BLEND_STORE_Q8) != 0;
  b->rowb = b->q8 ? ub_blend_q8_row_bytes(S) : (size_t)S * b->value_size;
  b->kernel = S == 12 ? KERNEL_12 : S == 27 ? KERNEL_27 : KERNEL_ANY;
  b->decode = b->value_size == 2 && !b->q8 ? pick_decoder((desc->flags & UB_BLEND_PORTABLE) != 0) : NULL;
#if BLEND_F16C
  {
    const unsigned cpu = ub_cpu_features(); /* one CPUID for both */
    b->avx = !(desc->flags & UB_BLEND_PORTABLE) && (cpu & UB_CPU_F16C) != 0;
    b->avx2 = b->avx && !(desc->flags & UB_BLEND_NO_AVX2) && (cpu & UB_CPU_AVX2) != 0;
  }
#endif
  b->base = desc->base;
  b->base_size = (desc->flags & UB_BLEND_BASE_HALF) ? 2 : 4;
  b->bscale = 1.0f;
  b->bdecode = b->base_size == 2 ? pick_decoder((desc->flags & UB_BLEND_PORTABLE) != 0) : NULL;
  b->memberships = memberships;
  b->record_bytes = memberships * (uint64_t)b->rowb;
  b->weight = calloc_n((size_t)E * 3, sizeof(float), &b->engine_bytes);
  /* 16-byte aligned weight rows (aligned_alloc wants a multiple of the alignment). */
  size_t wbytes = (size_t)E * b->wstride * sizeof(float);
  b->wexp = aligned_alloc(16, wbytes ? wbytes : 16);
  if (b->wexp) {
    memset(b->wexp, 0, wbytes);
    b->engine_bytes += wbytes;
  }
  b->nonzero = calloc_n(E, 1, &b->engine_bytes);
  b->dirty = calloc_n(E, 1, &b->engine_bytes);
  b->dirty_list = alloc_n(E, sizeof(uint32_t), &b->engine_bytes);
  b->wupd = alloc_n((size_t)E * 3, sizeof(float), &b->engine_bytes);
  if (!b->weight || !b->wexp || !b->nonzero || !b->dirty || !b->dirty_list || !b->wupd)
    goto oom;
  for (size_t i = 0; i < (size_t)E * 3; i++)
    b->wupd[i] = NAN;

  build_tmp t;
  memset(&t, 0, sizeof t);
  res = build(b, desc, &t, values_done, user);
  build_tmp_free(&t);
  if (res != UB_OK)
    goto oom;

  if ((desc->flags & UB_BLEND_ROW_QUERY) && build_rmap(b) != UB_OK)
    goto oom;
  if (desc->flags & UB_BLEND_ONES_SUM) {
    b->ones_w = desc->ones_weight == 0.0f ? 1.0f : desc->ones_weight;
    if (build_ones(b) != UB_OK)
      goto oom;
  } else {
    for (uint32_t g = 0; g < b->group_count; g++)
      b->groups[g].ones_row = ONES_NONE;
  }
  if (out_values && desc->receiver_count)
    memcpy(out_values, desc->base, (size_t)desc->receiver_count * S * sizeof(float));
  if (out_values && b->base_size == 2) { /* the touched rows as the engine holds them */
    blend_call c = {b, out_values, &b->js[0], 0, 0, NULL, NULL, 0};
    unsigned csr = ub_fp_mode_enter(); /* exact decoding needs DAZ off */
    for (uint32_t g = 0; g < b->group_count; g++) {
      c.qhi = b->groups[g].receivers;
      group_copy_base(&c, &b->groups[g]);
    }
    ub_fp_mode_leave(csr);
  }
  if (desc->flags & UB_BLEND_OWN_BASE)
    b->base = NULL; /* never read again: the caller may free it */
  *out_blend = b;
  return UB_OK;

oom:
  ub_log_printf(log, UB_LOG_ERROR, "blend %s: out of memory building the groups",
                desc_name(desc));
  ub_blend_free(b);
  return UB_ERR_OUT_OF_MEMORY;
}
