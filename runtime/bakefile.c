/* runtime/bakefile.c — .ubk writer and validating reader (layout: docs/FORMAT.md).
 *
 * Writer: validates the in-memory bake file, streams the sections to PATH.tmp (header
 * and section table are written last, once every section's size and CRC is known), then
 * renames PATH.tmp to PATH. Reader: treats the bytes as hostile; every field is read
 * through a bounds-checked cursor, every count is checked against the section size before
 * anything is allocated, and the parsed result goes through the same validator as the
 * writer's input, so a file the writer accepts is a file the reader accepts and back.
 */
#include "ubake/bakefile.h"
#include "ubake/llg.h"

#include <assert.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>
#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

#include "runtime/bigalloc.h"
#include "runtime/cpu.h"
#include "runtime/crc32.h"
#include "runtime/half.h"
#include "runtime/texel_links.h"
#include "runtime/texel_sh.h"

#define UB_UBK_HEADER_SIZE 16u
#define UB_UBK_ENTRY_SIZE 32u
#define UB_UBK_FLAG_REQUIRED 1u
#define UB_UBK_ATLAS_MAX_DIM 16384u
#define UB_UBK_META_SIZE 72u
#define UB_UBK_MAX_FILE_SIZE ((uint64_t)4 << 30) /* ub_bakefile_read refuses larger files */

/* Fuzz builds (-DFUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION, the libFuzzer/OSS-Fuzz
 * convention) skip CRC mismatches so the fuzzer reaches the section parsers: a hostile
 * file can always carry correct CRCs, so the parsers must hold without them. */
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
#define UB_UBK_CHECK_CRC 0
#else
#define UB_UBK_CHECK_CRC 1
#endif

static const uint8_t ub_ubk_magic[4] = {'U', 'B', 'K', 0};

/* META, GEOM, ATLS are mandatory; GLGP (global light grid) and DLSR (dynamic light set
 * records) are optional: a reader without them still has the base lighting. */
enum { UB_SEC_META = 0, UB_SEC_GEOM, UB_SEC_ATLS, UB_SEC_MANDATORY, UB_SEC_GLGP = UB_SEC_MANDATORY,
       UB_SEC_DLSR, UB_SEC_LITE, UB_SEC_LLGM, UB_SEC_ELEM, UB_SEC_TRIR, UB_SEC_TXLK,
       UB_SEC_KNOWN };
static const char ub_sec_tags[UB_SEC_KNOWN][5] = {"META", "GEOM", "ATLS", "GLGP", "DLSR", "LITE",
                                                  "LLGM", "ELEM", "TRIR", "TXLK"};
#define UB_LLGM_MODEL_HEADER 144 /* name[64], centre, axes, half, dims, V, T */
#define UB_LLGM_MODEL_HEADER_SHARED 184 /* + shared-from, rotation[9] (flags bit 0) */
#define UB_LLGM_FLAG_SHARED 1u
#define UB_LLGM_MAX_DIM 64u
#define UB_LLGM_MAX_SELF 65504.0f /* the half range */
#define UB_LITE_SIZE 60 /* bytes per light */
/* Record header (sections DLSR and ELEM): name[64], kind, parent[2], light count, mean
 * intensity, texels, GLG probes, LLG probes. */
#define UB_REC_HEADER 96
#define UB_GLG_SH_FLOATS 27 /* SH L2 × RGB */
#define UB_GLG_NO_PLANE_INDEX 0xffffffffu

/* ---------------------------------------------------------------------------------- */
/* Little-endian encoding, independent of the host's byte order.                       */

static void le_put32(uint8_t *p, uint32_t v)
{
  p[0] = (uint8_t)v;
  p[1] = (uint8_t)(v >> 8);
  p[2] = (uint8_t)(v >> 16);
  p[3] = (uint8_t)(v >> 24);
}

static void le_put64(uint8_t *p, uint64_t v)
{
  le_put32(p, (uint32_t)v);
  le_put32(p + 4, (uint32_t)(v >> 32));
}

static uint32_t le_get32(const uint8_t *p)
{
  return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static uint64_t le_get64(const uint8_t *p)
{
  return (uint64_t)le_get32(p) | (uint64_t)le_get32(p + 4) << 32;
}

static uint16_t le_get16(const uint8_t *p)
{
  return (uint16_t)(p[0] | p[1] << 8);
}

static uint32_t float_bits(float f)
{
  uint32_t u;
  memcpy(&u, &f, sizeof u);
  return u;
}

static float bits_float(uint32_t u)
{
  float f;
  memcpy(&f, &u, sizeof f);
  return f;
}

static uint64_t align8(uint64_t x)
{
  return (x + 7u) & ~(uint64_t)7u;
}

/* ---------------------------------------------------------------------------------- */
/* Messages: "NAME: section TAG: what".                                                */

#if defined(__GNUC__)
__attribute__((format(printf, 4, 5)))
#endif
static void ubk_error(const ub_log *log, const char *name, const char *where, const char *fmt,
                      ...)
{
  if (!log || !log->fn)
    return;
  char msg[512];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg, sizeof msg, fmt, ap);
  va_end(ap);
  ub_log_printf(log, UB_LOG_ERROR, "%s: %s: %s", name ? name : "(memory)", where, msg);
}

/* ---------------------------------------------------------------------------------- */
/* Validation of an in-memory bake file: shared by the writer (its input) and the reader */
/* (its output).                                                                       */

static int all_finite(const float *v, size_t n, size_t *out_bad)
{
  for (size_t i = 0; i < n; i++)
    if (!isfinite(v[i])) {
      *out_bad = i;
      return 0;
    }
  return 1;
}

static ub_result validate_glg(const ub_bakefile *bf, const char *name, const ub_log *log)
{
  static const char *where = "section GLGP";
  size_t bad;
  uint32_t p = bf->glg_probe_count, t = bf->glg_tet_count, k = bf->glg_plane_count;
  assert(t == 0 || bf->glg_tets); /* glg_plane_of may be NULL: no planes */
  /* a run-time's bake file (ub_runtime_bakefile) keeps neither: the GLG holds its own */
  if (t && !bf->glg_neigh) {
    ubk_error(log, name, where, "%u tetrahedra without their neighbours", t);
    return UB_ERR_INVALID_ARGUMENT;
  }
  if (p && (!bf->glg_positions || !bf->glg_sh)) {
    ubk_error(log, name, where, "%u probes without their positions or SH", p);
    return UB_ERR_INVALID_ARGUMENT;
  }
  assert(k == 0 || bf->glg_planes);
  if (p == 0 && (t || k)) {
    ubk_error(log, name, where, "%u tetrahedra and %u planes but no probes", t, k);
    return UB_ERR_INVALID_DATA;
  }
  if (!all_finite(bf->glg_positions, (size_t)p * 3, &bad)) {
    ubk_error(log, name, where, "probe %zu has a non-finite position", bad / 3);
    return UB_ERR_INVALID_DATA;
  }
  if (!all_finite(bf->glg_sh, (size_t)p * UB_GLG_SH_FLOATS, &bad)) {
    ubk_error(log, name, where, "probe %zu has a non-finite SH", bad / UB_GLG_SH_FLOATS);
    return UB_ERR_INVALID_DATA;
  }
  if (!all_finite(bf->glg_planes, (size_t)k * 4, &bad)) {
    ubk_error(log, name, where, "plane %zu is not finite", bad / 4);
    return UB_ERR_INVALID_DATA;
  }
  for (uint32_t i = 0; i < t; i++) {
    const uint32_t *c = &bf->glg_tets[(size_t)i * 4];
    for (int j = 0; j < 4; j++) {
      if (c[j] >= p) {
        ubk_error(log, name, where, "tetrahedron %u: corner %u >= probe count %u", i, c[j], p);
        return UB_ERR_INVALID_DATA;
      }
      for (int m = 0; m < j; m++)
        if (c[m] == c[j]) {
          ubk_error(log, name, where, "tetrahedron %u: corner %u repeated", i, c[j]);
          return UB_ERR_INVALID_DATA;
        }
      int32_t nb = bf->glg_neigh[(size_t)i * 4 + j];
      if (nb < -1 || (nb >= 0 && (uint32_t)nb >= t) || (nb >= 0 && (uint32_t)nb == i)) {
        ubk_error(log, name, where, "tetrahedron %u: neighbour %d not -1 or another "
                  "tetrahedron in [0, %u)", i, (int)nb, t);
        return UB_ERR_INVALID_DATA;
      }
    }
    uint32_t pl = bf->glg_plane_of ? bf->glg_plane_of[i] : UB_GLG_NO_PLANE_INDEX;
    if (pl != UB_GLG_NO_PLANE_INDEX && pl >= k) {
      ubk_error(log, name, where, "tetrahedron %u: plane %u >= plane count %u", i, pl, k);
      return UB_ERR_INVALID_DATA;
    }
  }
  return UB_OK;
}

uint64_t ub_bakefile_atlas_pixels(const ub_bakefile *bf)
{
  uint64_t pixels = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++)
    pixels += (uint64_t)bf->atlases[a].width * bf->atlases[a].height;
  return pixels;
}

const float *ub_bakefile_pixel_normal(const ub_bakefile *bf, uint64_t p)
{
  uint64_t first = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    uint64_t n = (uint64_t)bf->atlases[a].width * bf->atlases[a].height;
    if (p < first + n)
      return bf->atlases[a].normal ? bf->atlases[a].normal + 3 * (size_t)(p - first) : NULL;
    first += n;
  }
  return NULL;
}

uint64_t ub_bakefile_llg_probes(const ub_bakefile *bf)
{
  uint64_t n = 0;
  for (uint32_t m = 0; m < bf->llg_count; m++)
    n += (uint64_t)bf->llgs[m].dims[0] * bf->llgs[m].dims[1] * bf->llgs[m].dims[2];
  return n;
}

static int sorted_below(const uint32_t *idx, uint32_t n, uint64_t limit, uint32_t *at)
{
  for (uint32_t i = 0; i < n; i++)
    if (idx[i] >= limit || (i && idx[i] <= idx[i - 1])) {
      *at = i;
      return 0;
    }
  return 1;
}

/* Records of sections DLSR (elem = 0) and ELEM (elem = 1). */
/* n halves all finite. */
static int halves_finite(const uint16_t *v, size_t n)
{
  for (size_t i = 0; i < n; i++)
    if ((v[i] & 0x7c00u) == 0x7c00u)
      return 0;
  return 1;
}

static ub_result validate_records(const ub_bakefile *bf, int elem, const char *name,
                                  const ub_log *log)
{
  const char *where = elem ? "section ELEM" : "section DLSR";
  const ub_bakefile_record *recs = elem ? bf->elems : bf->dls;
  uint32_t count = elem ? bf->elem_count : bf->dls_count;
  uint64_t pixels = ub_bakefile_atlas_pixels(bf);
  uint64_t llg_probes = ub_bakefile_llg_probes(bf);
  uint32_t prev_kind = 0;
  for (uint32_t d = 0; d < count; d++) {
    const ub_bakefile_record *r = &recs[d];
    size_t bad;
    uint32_t at = 0;
    if (memchr(r->name, 0, sizeof r->name) == NULL || !r->name[0]) {
      ubk_error(log, name, where, "record %u: name empty or not NUL-terminated", d);
      return UB_ERR_INVALID_DATA;
    }
    uint32_t self = elem ? bf->dls_count + d : d;
    if (!elem ? r->kind != UB_ELEMENT_DLS
              : (r->kind < UB_ELEMENT_DOOR || r->kind > UB_ELEMENT_COMBO || r->kind < prev_kind)) {
      ubk_error(log, name, where, "record %u (%s): kind %u invalid or out of order", d, r->name,
                r->kind);
      return UB_ERR_INVALID_DATA;
    }
    prev_kind = r->kind;
    for (int k = 0; k < 2; k++) {
      int32_t p = r->parent[k];
      int ok;
      if (r->kind != UB_ELEMENT_COMBO) {
        ok = p == -1;
      } else {
        /* A parent is a set or an earlier non-combination element. */
        ok = p >= 0 && (uint32_t)p < self &&
             ((uint32_t)p < bf->dls_count || bf->elems[p - (int32_t)bf->dls_count].kind !=
                                                 UB_ELEMENT_COMBO);
      }
      if (!ok || (k == 1 && r->kind == UB_ELEMENT_COMBO && p == r->parent[0])) {
        ubk_error(log, name, where, "record %u (%s): parent %d invalid", d, r->name, (int)p);
        return UB_ERR_INVALID_DATA;
      }
    }
    for (uint32_t e = 0; e < d; e++)
      if (recs[e].kind == r->kind && !strcmp(recs[e].name, r->name)) {
        ubk_error(log, name, where, "record %u: name '%s' used twice", d, r->name);
        return UB_ERR_INVALID_DATA;
      }
    /* a run-time's bake file keeps counts without the arrays (the blends hold them) */
    if ((r->texel_count && (!r->texel_index || !(r->texel_sh || r->texel_sh_half))) ||
        (r->probe_count && (!r->probe_index || !(r->probe_sh || r->probe_sh_half))) ||
        (r->llg_probe_count && (!r->llg_probe_index || !(r->llg_probe_sh || r->llg_probe_sh_half)))) {
      ubk_error(log, name, where, "record %u (%s): receivers or values missing", d, r->name);
      return UB_ERR_INVALID_ARGUMENT;
    }
    if (!isfinite(r->mean_intensity) || r->mean_intensity < 0.0f) {
      ubk_error(log, name, where, "record %u (%s): mean intensity not finite and >= 0", d, r->name);
      return UB_ERR_INVALID_DATA;
    }
    if (!sorted_below(r->texel_index, r->texel_count, pixels, &at)) {
      ubk_error(log, name, where, "record %u (%s): texel index %u at %u not increasing or >= "
                "%llu atlas pixels", d, r->name, r->texel_index[at], at,
                (unsigned long long)pixels);
      return UB_ERR_INVALID_DATA;
    }
    if (!sorted_below(r->probe_index, r->probe_count, bf->glg_probe_count, &at)) {
      ubk_error(log, name, where, "record %u (%s): probe index %u at %u not increasing or >= %u "
                "probes", d, r->name, r->probe_index[at], at, bf->glg_probe_count);
      return UB_ERR_INVALID_DATA;
    }
    if (!sorted_below(r->llg_probe_index, r->llg_probe_count, llg_probes, &at)) {
      ubk_error(log, name, where, "record %u (%s): LLG probe index %u at %u not increasing or "
                ">= %llu LLG probes", d, r->name, r->llg_probe_index[at], at,
                (unsigned long long)llg_probes);
      return UB_ERR_INVALID_DATA;
    }
    if ((r->texel_sh && !all_finite(r->texel_sh, (size_t)r->texel_count * UB_SH1_FLOATS, &bad)) ||
        (r->probe_sh && !all_finite(r->probe_sh, (size_t)r->probe_count * UB_GLG_SH_FLOATS, &bad)) ||
        (r->llg_probe_sh &&
         !all_finite(r->llg_probe_sh, (size_t)r->llg_probe_count * UB_GLG_SH_FLOATS, &bad)) ||
        (r->texel_sh_half &&
         !halves_finite(r->texel_sh_half, (size_t)r->texel_count * UB_SH1_FLOATS)) ||
        (r->probe_sh_half &&
         !halves_finite(r->probe_sh_half, (size_t)r->probe_count * UB_GLG_SH_FLOATS)) ||
        (r->llg_probe_sh_half &&
         !halves_finite(r->llg_probe_sh_half, (size_t)r->llg_probe_count * UB_GLG_SH_FLOATS))) {
      ubk_error(log, name, where, "record %u (%s): non-finite SH", d, r->name);
      return UB_ERR_INVALID_DATA;
    }
  }
  return UB_OK;
}

static ub_result validate_lights(const ub_bakefile *bf, const char *name, const ub_log *log)
{
  for (uint32_t l = 0; l < bf->light_count; l++) {
    const ub_bakefile_light *L = &bf->lights[l];
    size_t bad;
    if (L->type > 2 || L->cls > 1 || L->dls < -1 ||
        (L->dls >= 0 && (uint32_t)L->dls >= bf->dls_count)) {
      ubk_error(log, name, "section LITE", "light %u: type %u, class %u or set %d out of range",
                l, L->type, L->cls, (int)L->dls);
      return UB_ERR_INVALID_DATA;
    }
    if (!all_finite(L->position, 3, &bad) || !all_finite(L->direction, 3, &bad) ||
        !all_finite(L->intensity, 3, &bad) || !isfinite(L->range) || !isfinite(L->cos_inner) ||
        !isfinite(L->cos_outer) || L->range < 0.0f) {
      ubk_error(log, name, "section LITE", "light %u: non-finite or negative value", l);
      return UB_ERR_INVALID_DATA;
    }
  }
  return UB_OK;
}

static ub_result validate_llg(const ub_bakefile *bf, const char *name, const ub_log *log)
{
  static const char *where = "section LLGM";
  for (uint32_t i = 0; i < bf->llg_count; i++) {
    const ub_bakefile_llg *m = &bf->llgs[i];
    size_t bad;
    if (memchr(m->name, 0, sizeof m->name) == NULL) {
      ubk_error(log, name, where, "model %u: name is not NUL-terminated", i);
      return UB_ERR_INVALID_DATA;
    }
    uint64_t np = 1;
    for (int a = 0; a < 3; a++) {
      if (m->dims[a] < 2 || m->dims[a] > UB_LLGM_MAX_DIM) {
        ubk_error(log, name, where, "model %u (%s): grid %ux%ux%u not in [2, %u] per axis", i,
                  m->name, m->dims[0], m->dims[1], m->dims[2], UB_LLGM_MAX_DIM);
        return UB_ERR_INVALID_DATA;
      }
      np *= m->dims[a];
    }
    assert(m->probe_sh && (m->vertex_count == 0 || (m->positions && m->normals && m->vis &&
                                                    m->self)));
    assert(m->triangle_count == 0 || m->indices);
    int box_ok = all_finite(m->center, 3, &bad) && all_finite(m->axes, 9, &bad) &&
                 all_finite(m->half, 3, &bad);
    for (int a = 0; box_ok && a < 3; a++) {
      if (!(m->half[a] > 0.0f) || m->half[a] > 1e6f)
        box_ok = 0;
      for (int b = 0; b <= a; b++) {
        double d = 0.0;
        for (int k = 0; k < 3; k++)
          d += (double)m->axes[3 * a + k] * m->axes[3 * b + k];
        if (fabs(d - (a == b ? 1.0 : 0.0)) > 1e-3)
          box_ok = 0;
      }
    }
    if (!box_ok) {
      ubk_error(log, name, where, "model %u (%s): box not finite, axes not orthonormal or a "
                "half extent not in (0, 1e6]", i, m->name);
      return UB_ERR_INVALID_DATA;
    }
    if (!all_finite(m->probe_sh, (size_t)np * UB_GLG_SH_FLOATS, &bad)) {
      ubk_error(log, name, where, "model %u (%s): probe %zu has a non-finite SH", i, m->name,
                bad / UB_GLG_SH_FLOATS);
      return UB_ERR_INVALID_DATA;
    }
    size_t v = m->vertex_count;
    if (!all_finite(m->positions, v * 3, &bad) || !all_finite(m->normals, v * 3, &bad) ||
        !all_finite(m->vis, v * 9, &bad)) {
      ubk_error(log, name, where, "model %u (%s): vertex data not finite", i, m->name);
      return UB_ERR_INVALID_DATA;
    }
    for (size_t k = 0; k < v * 3; k++)
      if (!(m->self[k] >= 0.0f && m->self[k] <= UB_LLGM_MAX_SELF)) {
        ubk_error(log, name, where, "model %u (%s): vertex %zu: self irradiance not in "
                  "[0, %g]", i, m->name, k / 3, (double)UB_LLGM_MAX_SELF);
        return UB_ERR_INVALID_DATA;
      }
    for (size_t k = 0; k < (size_t)m->triangle_count * 3; k++)
      if (m->indices[k] >= m->vertex_count) {
        ubk_error(log, name, where, "model %u (%s): triangle %zu: index %u >= vertex count %u",
                  i, m->name, k / 3, m->indices[k], m->vertex_count);
        return UB_ERR_INVALID_DATA;
      }
    if (m->vis_shared_from) {
      uint32_t src = m->vis_shared_from - 1;
      int rot_ok = src < i && bf->llgs[src].vis_shared_from == 0 &&
                   bf->llgs[src].vertex_count == m->vertex_count &&
                   all_finite(m->vis_rotation, 9, &bad);
      for (int a = 0; rot_ok && a < 3; a++)
        for (int b = 0; b <= a; b++) {
          double d = 0.0;
          for (int k = 0; k < 3; k++)
            d += (double)m->vis_rotation[3 * a + k] * m->vis_rotation[3 * b + k];
          if (fabs(d - (a == b ? 1.0 : 0.0)) > 1e-3)
            rot_ok = 0;
        }
      if (!rot_ok) {
        ubk_error(log, name, where, "model %u (%s): shares the self-visibility of model %u, "
                  "which is not an earlier model with its own and %u vertices, or the "
                  "rotation is not orthonormal", i, m->name, src, m->vertex_count);
        return UB_ERR_INVALID_DATA;
      }
    }
  }
  return UB_OK;
}

static ub_result validate(const ub_bakefile *bf, const char *name, const ub_log *log)
{
  size_t bad;

  /* Caller bugs: arrays missing for non-zero counts. */
  assert(bf->vertex_count == 0 || bf->positions);
  assert(bf->triangle_count == 0 ||
         (bf->indices && bf->tri_atlas && bf->tri_uv && bf->tri_albedo));
  assert(bf->atlas_count == 0 || bf->atlases);

  if (!memchr(bf->level_name, 0, sizeof bf->level_name)) {
    ubk_error(log, name, "section META", "level name is not NUL-terminated within %zu bytes",
              sizeof bf->level_name);
    return UB_ERR_INVALID_DATA;
  }

  if (!all_finite(bf->positions, (size_t)bf->vertex_count * 3, &bad)) {
    ubk_error(log, name, "section GEOM", "vertex %zu has a non-finite position", bad / 3);
    return UB_ERR_INVALID_DATA;
  }
  for (size_t i = 0; i < (size_t)bf->triangle_count * 3; i++)
    if (bf->indices[i] >= bf->vertex_count) {
      ubk_error(log, name, "section GEOM", "triangle %zu: index %u >= vertex count %u", i / 3,
                bf->indices[i], bf->vertex_count);
      return UB_ERR_INVALID_DATA;
    }
  for (size_t t = 0; t < bf->triangle_count; t++)
    if (bf->tri_atlas[t] < -1 || (bf->tri_atlas[t] >= 0 &&
                                  (uint32_t)bf->tri_atlas[t] >= bf->atlas_count)) {
      ubk_error(log, name, "section GEOM", "triangle %zu: atlas %d not in [-1, %u)", t,
                (int)bf->tri_atlas[t], bf->atlas_count);
      return UB_ERR_INVALID_DATA;
    }
  if (!all_finite(bf->tri_uv, (size_t)bf->triangle_count * 6, &bad)) {
    ubk_error(log, name, "section GEOM", "triangle %zu has a non-finite lightmap UV", bad / 6);
    return UB_ERR_INVALID_DATA;
  }
  if (!all_finite(bf->tri_albedo, (size_t)bf->triangle_count * 3, &bad)) {
    ubk_error(log, name, "section GEOM", "triangle %zu has a non-finite albedo", bad / 3);
    return UB_ERR_INVALID_DATA;
  }

  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    if (at->width < 1 || at->width > UB_UBK_ATLAS_MAX_DIM || at->height < 1 ||
        at->height > UB_UBK_ATLAS_MAX_DIM) {
      ubk_error(log, name, "section ATLS", "atlas %u: size %ux%u not in [1, %u]", a, at->width,
                at->height, UB_UBK_ATLAS_MAX_DIM);
      return UB_ERR_INVALID_DATA;
    }
    if (!at->sh || !at->coverage || !at->normal) { /* e.g. a run-time's bake file */
      ubk_error(log, name, "section ATLS", "atlas %u: SH, coverage or normals missing", a);
      return UB_ERR_INVALID_ARGUMENT;
    }
    size_t texels = (size_t)at->width * at->height;
    for (size_t i = 0; i < texels; i++)
      if (at->coverage[i] > 2) {
        ubk_error(log, name, "section ATLS", "atlas %u: texel (%zu, %zu): coverage %u not in "
                  "{0, 1, 2}", a, i % at->width, i / at->width, at->coverage[i]);
        return UB_ERR_INVALID_DATA;
      }
    for (size_t i = 0; at->link && i < texels; i++)
      if (at->link[i] > (UB_LINK_X | UB_LINK_Y)) {
        ubk_error(log, name, "section TXLK", "atlas %u: texel (%zu, %zu): link %u not in [0, 3]",
                  a, i % at->width, i / at->width, at->link[i]);
        return UB_ERR_INVALID_DATA;
      }
    if (!all_finite(at->sh, texels * UB_SH1_FLOATS, &bad)) {
      bad /= UB_SH1_FLOATS;
      ubk_error(log, name, "section ATLS", "atlas %u: texel (%zu, %zu): non-finite SH", a,
                bad % at->width, bad / at->width);
      return UB_ERR_INVALID_DATA;
    }
    if (!all_finite(at->normal, texels * 3, &bad)) {
      bad /= 3;
      ubk_error(log, name, "section ATLS", "atlas %u: texel (%zu, %zu): non-finite normal", a,
                bad % at->width, bad / at->width);
      return UB_ERR_INVALID_DATA;
    }
  }
  ub_result r = validate_glg(bf, name, log);
  if (r == UB_OK)
    r = validate_records(bf, 0, name, log);
  if (r == UB_OK)
    r = validate_records(bf, 1, name, log);
  for (uint32_t t = 0; r == UB_OK && bf->tri_role && t < bf->triangle_count; t++) {
    uint32_t role = bf->tri_role[t] >> 24, e = bf->tri_role[t] & 0xFFFFFFu;
    uint32_t want = role == UB_TRI_ROLE_OBJECT ? UB_ELEMENT_OBJECT : UB_ELEMENT_DOOR;
    if (bf->tri_role[t] && (role < UB_TRI_ROLE_DOOR_CLOSED || role > UB_TRI_ROLE_OBJECT ||
                            e >= bf->elem_count || bf->elems[e].kind != want)) {
      ubk_error(log, name, "section TRIR", "triangle %u: role %u of element %u invalid", t,
                role, e);
      r = UB_ERR_INVALID_DATA;
    }
  }
  if (r == UB_OK)
    r = validate_lights(bf, name, log);
  return r == UB_OK ? validate_llg(bf, name, log) : r;
}

/* ---------------------------------------------------------------------------------- */
/* Writer.                                                                             */

typedef struct ubk_section_entry {
  char tag[4];
  uint32_t flags;
  uint64_t offset, size;
  uint32_t crc;
} ubk_section_entry;

typedef struct ubk_writer {
  FILE *f;
  int err;          /* first errno, 0 = fine */
  uint64_t pos;     /* bytes emitted so far (file offset of the next byte) */
  uint32_t crc;     /* running CRC of the current section's payload, up to buf[crc_from] */
  uint64_t clamped; /* half values clamped to ±UB_HALF_MAX */
  int crc_on;       /* the bytes from buf[crc_from] on belong to the section's payload */
  const float *un;  /* pack_normals() of the bake file written */
  size_t crc_from;
  size_t n;
  uint8_t buf[1 << 16];
} ubk_writer;

/* The CRC runs over the buffer's stretches when they end (a flush, a section's end, bytes
 * outside the payload), not per value: per value it was a sixth of a bake's write stage. */
static void crc_sync(ubk_writer *w)
{
  if (w->crc_on && w->n > w->crc_from)
    w->crc = ub_crc32_update(w->crc, w->buf + w->crc_from, w->n - w->crc_from);
  w->crc_from = w->n;
}

static void wr_flush(ubk_writer *w)
{
  crc_sync(w);
  w->crc_from = 0;
  if (w->n && !w->err) {
    errno = 0;
    if (fwrite(w->buf, 1, w->n, w->f) != w->n)
      w->err = errno ? errno : EIO;
  }
  w->n = 0;
}

/* in_crc: the bytes belong to the current section's payload. */
static void wr_bytes(ubk_writer *w, const void *data, size_t size, int in_crc)
{
  const uint8_t *p = (const uint8_t *)data;
  if (in_crc != w->crc_on) {
    crc_sync(w);
    w->crc_on = in_crc;
  }
  w->pos += size;
  while (size) {
    size_t k = sizeof w->buf - w->n;
    if (k > size)
      k = size;
    memcpy(w->buf + w->n, p, k);
    w->n += k;
    p += k;
    size -= k;
    if (w->n == sizeof w->buf)
      wr_flush(w);
  }
}

static inline void wr_u32(ubk_writer *w, uint32_t v)
{
  if (w->crc_on && sizeof w->buf - w->n >= 4) { /* straight into the buffer */
    le_put32(w->buf + w->n, v);
    w->n += 4;
    w->pos += 4;
    if (w->n == sizeof w->buf)
      wr_flush(w);
    return;
  }
  uint8_t b[4];
  le_put32(b, v);
  wr_bytes(w, b, 4, 1);
}

static void wr_f32(ubk_writer *w, float v)
{
  wr_u32(w, float_bits(v));
}

static inline void wr_half(ubk_writer *w, float v)
{
  if (v > UB_HALF_MAX) {
    v = UB_HALF_MAX;
    w->clamped++;
  } else if (v < -UB_HALF_MAX) {
    v = -UB_HALF_MAX;
    w->clamped++;
  }
  uint16_t h = ub_half_from_float(v);
  uint8_t b[2] = {(uint8_t)h, (uint8_t)(h >> 8)};
  if (w->crc_on && sizeof w->buf - w->n >= 2) { /* straight into the buffer */
    memcpy(w->buf + w->n, b, 2);
    w->n += 2;
    w->pos += 2;
    if (w->n == sizeof w->buf)
      wr_flush(w);
    return;
  }
  wr_bytes(w, b, 2, 1);
}

static void wr_zeros(ubk_writer *w, size_t n, int in_crc)
{
  static const uint8_t zeros[8];
  while (n) {
    size_t k = n < sizeof zeros ? n : sizeof zeros;
    wr_bytes(w, zeros, k, in_crc);
    n -= k;
  }
}

static void wr_begin(ubk_writer *w, ubk_section_entry *e, const char tag[4], uint32_t flags)
{
  wr_zeros(w, (size_t)(align8(w->pos) - w->pos), 0);
  memcpy(e->tag, tag, 4);
  e->flags = flags;
  e->offset = w->pos;
  crc_sync(w);
  w->crc = 0;
}

static void wr_end(ubk_writer *w, ubk_section_entry *e)
{
  crc_sync(w);
  e->size = w->pos - e->offset;
  e->crc = w->crc;
}

static void wr_meta(ubk_writer *w, const ub_bakefile *bf)
{
  uint8_t name[64] = {0};
  /* Bytes after the NUL are written as zeros, whatever the struct holds. */
  size_t len = strlen(bf->level_name);
  memcpy(name, bf->level_name, len);
  wr_bytes(w, name, sizeof name, 1);
  wr_u32(w, bf->seed);
  wr_u32(w, bf->bounces);
}

static void wr_geom(ubk_writer *w, const ub_bakefile *bf)
{
  wr_u32(w, bf->vertex_count);
  wr_u32(w, bf->triangle_count);
  size_t t = bf->triangle_count;
  for (size_t i = 0; i < (size_t)bf->vertex_count * 3; i++)
    wr_f32(w, bf->positions[i]);
  for (size_t i = 0; i < t * 3; i++)
    wr_u32(w, bf->indices[i]);
  for (size_t i = 0; i < t; i++)
    wr_u32(w, (uint32_t)bf->tri_atlas[i]);
  for (size_t i = 0; i < t * 6; i++)
    wr_f32(w, bf->tri_uv[i]);
  for (size_t i = 0; i < t * 3; i++)
    wr_f32(w, bf->tri_albedo[i]);
}

/* Texel SH storage (runtime/texel_sh.h): I_z replaces L00 where the texel has a normal.
 * The normal that counts is the one the reader will see: the stored normal rounded to
 * half; I_z itself is evaluated with the baker's float normal (where it is exact).
 * out: the unit normal to pack with, out[0] NaN where the texel keeps L00. */
static void pack_normal(const float normal[3], float out[3])
{
  float nr[3], un_read[3];
  for (int k = 0; k < 3; k++)
    nr[k] = ub_half_to_float(ub_half_from_float(normal[k]));
  if (!ub_texel_normal(nr, un_read) || !ub_texel_normal(normal, out))
    out[0] = NAN;
}

/* pack_normal of every pixel of the atlases taken in order (global pixel p at 3·p), once
 * per write: the ATLS scale and data and each record's scale and data all pack with it
 * (per texel it was a sixth of the writer's time). NULL when out of memory. */
static float *pack_normals(const ub_bakefile *bf)
{
  float *un = malloc((size_t)ub_bakefile_atlas_pixels(bf) * 3 * sizeof(float) + 1);
  if (!un)
    return NULL;
  size_t p = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    size_t n = (size_t)at->width * at->height;
    for (size_t i = 0; i < n; i++, p++)
      pack_normal(at->normal + 3 * i, un + 3 * p);
  }
  return un;
}

static inline void texel_pack(float sh[UB_SH1_FLOATS], const float un[3])
{
  if (!isnan(un[0]))
    ub_texel_sh_pack(sh, un);
}

/* The power of two ≥ 1 that brings mx within the half range with margin (≤ 32768). */
static float pow2_scale(double mx)
{
  float scale = 1.0f;
  while (mx / scale > 32768.0 && scale < 1e30f)
    scale *= 2.0f;
  return scale;
}

static double max_abs(const float *v, size_t n)
{
  double mx = 0.0;
  for (size_t i = 0; i < n; i++) {
    double a = fabs((double)v[i]);
    mx = a > mx ? a : mx; /* (as fmax: a NaN is passed over) */
  }
  return mx;
}

/* Power-of-two scale that keeps every stored texel SH value (in its stored form) within
 * the half range with margin: 1 unless the level is brighter than ~32768 W/m² (a sun in
 * W/m² with a bright sky). Exact: a power of two changes no mantissa bit. */
static float atls_scale(const ubk_writer *w, const ub_bakefile *bf)
{
  double mx = 0.0;
  size_t p = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    size_t texels = (size_t)at->width * at->height;
    for (size_t i = 0; i < texels; i++, p++) {
      float sh[UB_SH1_FLOATS];
      memcpy(sh, at->sh + i * UB_SH1_FLOATS, sizeof sh);
      texel_pack(sh, w->un + 3 * p);
      mx = fmax(mx, max_abs(sh, UB_SH1_FLOATS));
    }
  }
  return pow2_scale(mx);
}

static void wr_atls(ubk_writer *w, const ub_bakefile *bf)
{
  float scale = atls_scale(w, bf);
  wr_u32(w, bf->atlas_count);
  wr_f32(w, scale == 1.0f ? 0.0f : scale); /* SH scale (0 = 1) */
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    wr_u32(w, bf->atlases[a].width);
    wr_u32(w, bf->atlases[a].height);
  }
  size_t p = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    const ub_bakefile_atlas *at = &bf->atlases[a];
    size_t texels = (size_t)at->width * at->height;
    for (size_t i = 0; i < texels; i++) {
      float sh[UB_SH1_FLOATS];
      memcpy(sh, at->sh + i * UB_SH1_FLOATS, sizeof sh);
      texel_pack(sh, w->un + 3 * (p + i));
      for (int k = 0; k < UB_SH1_FLOATS; k++)
        wr_half(w, sh[k] / scale);
    }
    p += texels;
    for (size_t i = 0; i < texels * 3; i++)
      wr_half(w, at->normal[i]);
    wr_bytes(w, at->coverage, texels, 1);
    uint64_t block = (uint64_t)texels * 31u;
    wr_zeros(w, (size_t)(align8(block) - block), 1);
  }
}

static void wr_glgp(ubk_writer *w, const ub_bakefile *bf)
{
  uint32_t p = bf->glg_probe_count, t = bf->glg_tet_count, k = bf->glg_plane_count;
  wr_u32(w, p);
  wr_u32(w, t);
  wr_u32(w, k);
  float scale = pow2_scale(max_abs(bf->glg_sh, (size_t)p * UB_GLG_SH_FLOATS));
  wr_f32(w, scale == 1.0f ? 0.0f : scale); /* SH scale (0 = 1) */
  for (size_t i = 0; i < (size_t)p * 3; i++)
    wr_f32(w, bf->glg_positions[i]);
  for (size_t i = 0; i < (size_t)t * 4; i++)
    wr_u32(w, bf->glg_tets[i]);
  for (size_t i = 0; i < (size_t)t * 4; i++)
    wr_u32(w, (uint32_t)bf->glg_neigh[i]);
  for (size_t i = 0; i < (size_t)k * 4; i++)
    wr_f32(w, bf->glg_planes[i]);
  for (size_t i = 0; i < t; i++)
    wr_u32(w, bf->glg_plane_of ? bf->glg_plane_of[i] : UB_GLG_NO_PLANE_INDEX);
  for (size_t i = 0; i < (size_t)p * UB_GLG_SH_FLOATS; i++)
    wr_half(w, bf->glg_sh[i] / scale);
}

static uint64_t record_block(const ub_bakefile_record *r)
{
  return 28u * (uint64_t)r->texel_count + 58u * (uint64_t)r->probe_count +
         58u * (uint64_t)r->llg_probe_count;
}

/* Sections DLSR and ELEM: a count, the record headers, then each record's indices and
 * half-precision SH (texel SH in the I_z-packed form, as ATLS). */
static void wr_records(ubk_writer *w, const ub_bakefile_record *recs,
                       uint32_t count)
{
  double mx = 0.0;
  for (uint32_t d = 0; d < count; d++) {
    const ub_bakefile_record *r = &recs[d];
    for (uint32_t i = 0; i < r->texel_count; i++) {
      float sh[UB_SH1_FLOATS];
      memcpy(sh, r->texel_sh + (size_t)i * UB_SH1_FLOATS, sizeof sh);
      texel_pack(sh, w->un + 3 * (size_t)r->texel_index[i]);
      mx = fmax(mx, max_abs(sh, UB_SH1_FLOATS));
    }
    mx = fmax(mx, max_abs(r->probe_sh, (size_t)r->probe_count * UB_GLG_SH_FLOATS));
    mx = fmax(mx, max_abs(r->llg_probe_sh, (size_t)r->llg_probe_count * UB_GLG_SH_FLOATS));
  }
  float scale = pow2_scale(mx);
  wr_u32(w, count);
  wr_f32(w, scale == 1.0f ? 0.0f : scale); /* SH scale (0 = 1) */
  for (uint32_t d = 0; d < count; d++) {
    const ub_bakefile_record *r = &recs[d];
    uint8_t name[64];
    memset(name, 0, sizeof name);
    size_t len = strnlen(r->name, sizeof name - 1);
    memcpy(name, r->name, len);
    wr_bytes(w, name, sizeof name, 1);
    wr_u32(w, r->kind);
    wr_u32(w, (uint32_t)r->parent[0]);
    wr_u32(w, (uint32_t)r->parent[1]);
    wr_u32(w, r->light_count);
    wr_f32(w, r->mean_intensity);
    wr_u32(w, r->texel_count);
    wr_u32(w, r->probe_count);
    wr_u32(w, r->llg_probe_count);
  }
  for (uint32_t d = 0; d < count; d++) {
    const ub_bakefile_record *r = &recs[d];
    for (uint32_t i = 0; i < r->texel_count; i++)
      wr_u32(w, r->texel_index[i]);
    for (uint32_t i = 0; i < r->probe_count; i++)
      wr_u32(w, r->probe_index[i]);
    for (uint32_t i = 0; i < r->llg_probe_count; i++)
      wr_u32(w, r->llg_probe_index[i]);
    for (uint32_t i = 0; i < r->texel_count; i++) {
      float sh[UB_SH1_FLOATS];
      memcpy(sh, r->texel_sh + (size_t)i * UB_SH1_FLOATS, sizeof sh);
      texel_pack(sh, w->un + 3 * (size_t)r->texel_index[i]);
      for (int k = 0; k < UB_SH1_FLOATS; k++)
        wr_half(w, sh[k] / scale);
    }
    for (size_t i = 0; i < (size_t)r->probe_count * UB_GLG_SH_FLOATS; i++)
      wr_half(w, r->probe_sh[i] / scale);
    for (size_t i = 0; i < (size_t)r->llg_probe_count * UB_GLG_SH_FLOATS; i++)
      wr_half(w, r->llg_probe_sh[i] / scale);
    uint64_t block = record_block(r);
    wr_zeros(w, (size_t)(align8(block) - block), 1);
  }
}

static void wr_lite(ubk_writer *w, const ub_bakefile *bf)
{
  wr_u32(w, bf->light_count);
  wr_u32(w, 0); /* reserved */
  for (uint32_t l = 0; l < bf->light_count; l++) {
    const ub_bakefile_light *L = &bf->lights[l];
    wr_u32(w, L->type);
    wr_u32(w, L->cls);
    wr_u32(w, (uint32_t)L->dls);
    for (int k = 0; k < 3; k++)
      wr_f32(w, L->position[k]);
    for (int k = 0; k < 3; k++)
      wr_f32(w, L->direction[k]);
    for (int k = 0; k < 3; k++)
      wr_f32(w, L->intensity[k]);
    wr_f32(w, L->range);
    wr_f32(w, L->cos_inner);
    wr_f32(w, L->cos_outer);
  }
  uint64_t block = 8u + (uint64_t)UB_LITE_SIZE * bf->light_count;
  wr_zeros(w, (size_t)(align8(block) - block), 1);
}

/* own_vis: the model stores its self-visibility (not shared from an earlier instance). */
static uint64_t llgm_block_size(uint64_t np, uint64_t nv, uint64_t nt, int own_vis)
{
  return (own_vis ? 48u : 30u) * nv + 12u * nt + 2u * UB_GLG_SH_FLOATS * np;
}

static void wr_llgm(ubk_writer *w, const ub_bakefile *bf)
{
  /* The shared layout only when some model shares: files without instances keep the
   * original layout byte for byte. */
  uint32_t flags = 0;
  for (uint32_t i = 0; i < bf->llg_count; i++)
    if (bf->llgs[i].vis_shared_from)
      flags = UB_LLGM_FLAG_SHARED;
  wr_u32(w, bf->llg_count);
  wr_u32(w, flags);
  for (uint32_t i = 0; i < bf->llg_count; i++) {
    const ub_bakefile_llg *m = &bf->llgs[i];
    uint8_t name[64];
    memset(name, 0, sizeof name);
    memcpy(name, m->name, strnlen(m->name, sizeof name - 1));
    wr_bytes(w, name, sizeof name, 1);
    for (int k = 0; k < 3; k++)
      wr_f32(w, m->center[k]);
    for (int k = 0; k < 9; k++)
      wr_f32(w, m->axes[k]);
    for (int k = 0; k < 3; k++)
      wr_f32(w, m->half[k]);
    for (int k = 0; k < 3; k++)
      wr_u32(w, m->dims[k]);
    wr_u32(w, m->vertex_count);
    wr_u32(w, m->triangle_count);
    if (flags & UB_LLGM_FLAG_SHARED) {
      wr_u32(w, m->vis_shared_from);
      for (int k = 0; k < 9; k++)
        wr_f32(w, m->vis_shared_from ? m->vis_rotation[k] : (k % 4 == 0 ? 1.0f : 0.0f));
    }
  }
  for (uint32_t i = 0; i < bf->llg_count; i++) {
    const ub_bakefile_llg *m = &bf->llgs[i];
    size_t np = (size_t)m->dims[0] * m->dims[1] * m->dims[2], nv = m->vertex_count;
    for (size_t k = 0; k < nv * 3; k++)
      wr_f32(w, m->positions[k]);
    for (size_t k = 0; k < nv * 3; k++)
      wr_f32(w, m->normals[k]);
    for (size_t k = 0; k < (size_t)m->triangle_count * 3; k++)
      wr_u32(w, m->indices[k]);
    for (size_t k = 0; k < np * UB_GLG_SH_FLOATS; k++)
      wr_half(w, m->probe_sh[k]);
    for (size_t k = 0; !m->vis_shared_from && k < nv * 9; k++)
      wr_half(w, m->vis[k]);
    for (size_t k = 0; k < nv * 3; k++)
      wr_half(w, m->self[k]);
    uint64_t block = llgm_block_size(np, nv, m->triangle_count, !m->vis_shared_from);
    wr_zeros(w, (size_t)(align8(block) - block), 1);
  }
}

ub_result ub_bakefile_write(const ub_bakefile *bf, const char *path, const ub_log *log)
{
  return ub_bakefile_write_ex(bf, path, log, NULL);
}

ub_result ub_bakefile_write_ex(const ub_bakefile *bf, const char *path, const ub_log *log,
                               uint64_t *out_clamped)
{
  assert(bf && path);
  if (out_clamped)
    *out_clamped = 0;
  for (uint32_t e = 0; e < bf->dls_count + bf->elem_count; e++) {
    const ub_bakefile_record *rc = e < bf->dls_count ? &bf->dls[e] : &bf->elems[e - bf->dls_count];
    if ((rc->texel_count && !rc->texel_sh) || (rc->probe_count && !rc->probe_sh) ||
        (rc->llg_probe_count && !rc->llg_probe_sh)) {
      ubk_error(log, path, "write", "record %s: no float values (read as halves, or a "
                "run-time's bake file)", rc->name);
      return UB_ERR_INVALID_ARGUMENT;
    }
  }
  ub_result r = validate(bf, path, log);
  if (r != UB_OK)
    return r;

  size_t plen = strlen(path);
  char *tmp = malloc(plen + 5);
  ubk_writer *w = calloc(1, sizeof *w);
  float *un = pack_normals(bf);
  if (!tmp || !w || !un) {
    free(tmp);
    free(w);
    free(un);
    ubk_error(log, path, "write", "out of memory");
    return UB_ERR_OUT_OF_MEMORY;
  }
  memcpy(tmp, path, plen);
  memcpy(tmp + plen, ".tmp", 5);

  w->un = un;
  w->f = fopen(tmp, "wb");
  if (!w->f) {
    ubk_error(log, path, "write", "cannot create %s: %s", tmp, strerror(errno));
    free(tmp);
    free(w);
    free(un);
    return UB_ERR_IO;
  }

  /* Placeholder header and table; rewritten at the end with the real sizes and CRCs. */
  ubk_section_entry sec[UB_SEC_KNOWN];
  memset(sec, 0, sizeof sec);
  uint8_t head[UB_UBK_HEADER_SIZE + UB_SEC_KNOWN * UB_UBK_ENTRY_SIZE];
  memset(head, 0, sizeof head);
  /* Sections in file order: the mandatory ones, then the optional ones present. */
  int order[UB_SEC_KNOWN], sections = 0;
  for (int k = 0; k < UB_SEC_MANDATORY; k++)
    order[sections++] = k;
  if (bf->glg_probe_count)
    order[sections++] = UB_SEC_GLGP;
  if (bf->dls_count)
    order[sections++] = UB_SEC_DLSR;
  if (bf->light_count)
    order[sections++] = UB_SEC_LITE;
  if (bf->llg_count)
    order[sections++] = UB_SEC_LLGM;
  if (bf->elem_count)
    order[sections++] = UB_SEC_ELEM;
  if (bf->tri_role)
    order[sections++] = UB_SEC_TRIR;
  int links = 0;
  for (uint32_t a = 0; a < bf->atlas_count; a++)
    links |= bf->atlases[a].link != NULL;
  if (links)
    order[sections++] = UB_SEC_TXLK;
  size_t head_size = UB_UBK_HEADER_SIZE + (size_t)sections * UB_UBK_ENTRY_SIZE;
  wr_bytes(w, head, head_size, 0);

  wr_begin(w, &sec[UB_SEC_META], ub_sec_tags[UB_SEC_META], UB_UBK_FLAG_REQUIRED);
  wr_meta(w, bf);
  wr_end(w, &sec[UB_SEC_META]);
  wr_begin(w, &sec[UB_SEC_GEOM], ub_sec_tags[UB_SEC_GEOM], UB_UBK_FLAG_REQUIRED);
  wr_geom(w, bf);
  wr_end(w, &sec[UB_SEC_GEOM]);
  wr_begin(w, &sec[UB_SEC_ATLS], ub_sec_tags[UB_SEC_ATLS], UB_UBK_FLAG_REQUIRED);
  wr_atls(w, bf);
  wr_end(w, &sec[UB_SEC_ATLS]);
  if (bf->glg_probe_count) {
    wr_begin(w, &sec[UB_SEC_GLGP], ub_sec_tags[UB_SEC_GLGP], 0);
    wr_glgp(w, bf);
    wr_end(w, &sec[UB_SEC_GLGP]);
  }
  if (bf->dls_count) {
    wr_begin(w, &sec[UB_SEC_DLSR], ub_sec_tags[UB_SEC_DLSR], 0);
    wr_records(w, bf->dls, bf->dls_count);
    wr_end(w, &sec[UB_SEC_DLSR]);
  }
  if (bf->light_count) {
    wr_begin(w, &sec[UB_SEC_LITE], ub_sec_tags[UB_SEC_LITE], 0);
    wr_lite(w, bf);
    wr_end(w, &sec[UB_SEC_LITE]);
  }
  if (bf->llg_count) {
    wr_begin(w, &sec[UB_SEC_LLGM], ub_sec_tags[UB_SEC_LLGM], 0);
    wr_llgm(w, bf);
    wr_end(w, &sec[UB_SEC_LLGM]);
  }
  if (bf->elem_count) {
    wr_begin(w, &sec[UB_SEC_ELEM], ub_sec_tags[UB_SEC_ELEM], 0);
    wr_records(w, bf->elems, bf->elem_count);
    wr_end(w, &sec[UB_SEC_ELEM]);
  }
  if (bf->tri_role) {
    wr_begin(w, &sec[UB_SEC_TRIR], ub_sec_tags[UB_SEC_TRIR], 0);
    wr_u32(w, bf->triangle_count);
    wr_u32(w, 0); /* reserved */
    for (uint32_t t = 0; t < bf->triangle_count; t++)
      wr_u32(w, bf->tri_role[t]);
    wr_zeros(w, (size_t)(align8(4u * (uint64_t)bf->triangle_count) -
                         4u * (uint64_t)bf->triangle_count), 1);
    wr_end(w, &sec[UB_SEC_TRIR]);
  }
  if (links) {
    /* atlas count, reserved, then each atlas's W×H link bytes (0 where it has none) */
    wr_begin(w, &sec[UB_SEC_TXLK], ub_sec_tags[UB_SEC_TXLK], 0);
    wr_u32(w, bf->atlas_count);
    wr_u32(w, 0);
    uint64_t total = 0;
    for (uint32_t a = 0; a < bf->atlas_count; a++) {
      const ub_bakefile_atlas *at = &bf->atlases[a];
      size_t npx = (size_t)at->width * at->height;
      if (at->link)
        wr_bytes(w, at->link, npx, 1);
      else
        wr_zeros(w, npx, 1);
      total += npx;
    }
    wr_zeros(w, (size_t)(align8(total) - total), 1);
    wr_end(w, &sec[UB_SEC_TXLK]);
  }
  wr_flush(w);
  free(un);
  w->un = NULL;

  memcpy(head, ub_ubk_magic, 4);
  le_put32(head + 4, UB_BAKEFILE_VERSION);
  le_put32(head + 8, (uint32_t)sections);
  for (int i = 0; i < sections; i++) {
    uint8_t *e = head + UB_UBK_HEADER_SIZE + (size_t)i * UB_UBK_ENTRY_SIZE;
    const ubk_section_entry *se = &sec[order[i]];
    memcpy(e, se->tag, 4);
    le_put32(e + 4, se->flags);
    le_put64(e + 8, se->offset);
    le_put64(e + 16, se->size);
    le_put32(e + 24, se->crc);
    le_put32(e + 28, 0);
  }
  uint32_t hcrc = ub_crc32_update(0, head, 12);
  hcrc = ub_crc32_update(hcrc, head + UB_UBK_HEADER_SIZE, head_size - UB_UBK_HEADER_SIZE);
  le_put32(head + 12, hcrc);

  if (!w->err && fseek(w->f, 0, SEEK_SET) != 0)
    w->err = errno ? errno : EIO;
  if (!w->err && fwrite(head, 1, head_size, w->f) != head_size)
    w->err = errno ? errno : EIO;
  if (!w->err && fflush(w->f) != 0)
    w->err = errno ? errno : EIO;
  if (fclose(w->f) != 0 && !w->err)
    w->err = errno ? errno : EIO;
  if (!w->err && rename(tmp, path) != 0) {
    int e = errno ? errno : EIO;
    remove(tmp);
    ubk_error(log, path, "write", "cannot rename %s to %s: %s", tmp, path, strerror(e));
    free(tmp);
    free(w);
    return UB_ERR_IO;
  }
  if (w->err) {
    remove(tmp);
    ubk_error(log, path, "write", "cannot write %s: %s", tmp, strerror(w->err));
    free(tmp);
    free(w);
    return UB_ERR_IO;
  }
  if (w->clamped && log)
    ub_log_printf(log, UB_LOG_WARNING, "%s: %llu half value(s) beyond the half range clamped "
                  "to +-%g (LLG probes or self-inter-reflection, or light beyond what "
                  "a level holds)", path,
                  (unsigned long long)w->clamped, (double)UB_HALF_MAX);
  if (out_clamped)
    *out_clamped = w->clamped;
  free(tmp);
  free(w);
  return UB_OK;
}

/* ---------------------------------------------------------------------------------- */
/* Reader.                                                                             */

/* Where a file's bytes come from: the caller's memory, or an open file read where they
 * are needed (pread), so a load never holds the whole file: each section is read when it
 * is parsed and freed after, and the records (DLSR, ELEM: most of a file with dynamic
 * light sets) stream through a buffer. */
typedef struct ubk_src {
  const uint8_t *mem; /* NULL: read from fd */
  int fd;
  uint64_t size;
  int err; /* a read failed: its errno, or -1 when the file ended early (it changed) */
} ubk_src;

static int src_read(ubk_src *s, uint64_t off, void *dst, size_t n)
{
  if (s->mem) {
    memcpy(dst, s->mem + off, n);
    return 1;
  }
  uint8_t *o = dst;
  while (n) {
    ssize_t got = pread(s->fd, o, n, (off_t)off);
    if (got < 0 && errno == EINTR)
      continue;
    if (got <= 0) {
      s->err = got < 0 ? (errno ? errno : EIO) : -1;
      return 0;
    }
    o += got;
    off += (uint64_t)got;
    n -= (size_t)got;
  }
  return 1;
}

/* The reader's temporary buffers (a section, the records' stream, a chunk) are mapped
 * pages of their own, not malloc's: freeing a large malloc block raises glibc's mmap
 * threshold to its size, and the many record arrays allocated after it then came from the
 * heap, whose freed holes stayed resident (+98 MiB after loading the full ESTATE file).
 * A buffer is preceded by its mapped size. */
static void *tmp_alloc(size_t n)
{
  if (n > SIZE_MAX - 64)
    return NULL;
  size_t len = n + 64;
  void *m = mmap(NULL, len, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (m == MAP_FAILED)
    return NULL;
#if defined(MADV_HUGEPAGE)
  if (len >= UB_BIG_ALLOC_MIN) /* (runtime/bigalloc.h) */
    madvise(m, len, MADV_HUGEPAGE);
#endif
  memcpy(m, &len, sizeof len);
  return (uint8_t *)m + 64;
}

static void tmp_free(void *p)
{
  if (!p)
    return;
  uint8_t *m = (uint8_t *)p - 64;
  size_t len;
  memcpy(&len, m, sizeof len);
  munmap(m, len);
}

/* n bytes at off: a pointer into the memory, or a buffer read from the file that *owned
 * holds (tmp_free it). NULL: out of memory, or the read failed (s->err). */
static const uint8_t *src_view(ubk_src *s, uint64_t off, uint64_t n, uint8_t **owned)
{
  *owned = NULL;
  if (s->mem)
    return s->mem + off;
  if (n > SIZE_MAX - 1)
    return NULL;
  uint8_t *b = tmp_alloc((size_t)n + 1);
  if (!b)
    return NULL;
  if (!src_read(s, off, b, (size_t)n)) {
    tmp_free(b);
    return NULL;
  }
  *owned = b;
  return b;
}

/* Reads of a file go through this many bytes at a time where the bytes are not kept. */
#define UBK_CHUNK ((size_t)1 << 20)

/* The CRC of n bytes at off (a file: read a chunk at a time). 0: the read failed. */
static int src_crc(ubk_src *s, uint64_t off, uint64_t n, uint8_t *chunk, uint32_t *out)
{
  if (s->mem) {
    *out = ub_crc32_update(0, s->mem + off, (size_t)n);
    return 1;
  }
  uint32_t crc = 0;
  while (n) {
    size_t k = n < UBK_CHUNK ? (size_t)n : UBK_CHUNK;
    if (!src_read(s, off, chunk, k))
      return 0;
    crc = ub_crc32_update(crc, chunk, k);
    off += k;
    n -= k;
  }
  *out = crc;
  return 1;
}

/* Streams a section's bytes [next, end) through buf (cap bytes) for a cursor. */
typedef struct ubk_stream {
  ubk_src *src;
  uint64_t next, end;
  uint8_t *buf;
  size_t cap;
} ubk_stream;

/* Bounds-checked view of a section payload: every read checks `left` first. A streaming
 * cursor (s) refills p from the file as it goes; a read wider than its buffer fails. */
typedef struct ubk_cursor {
  const uint8_t *p;
  size_t left; /* bytes at p */
  ubk_stream *s;
} ubk_cursor;

/* At least n bytes at c->p (a streaming cursor reads more); 0: the payload has fewer. */
static int cur_need(ubk_cursor *c, size_t n)
{
  if (c->left >= n)
    return 1;
  ubk_stream *s = c->s;
  if (!s || n > s->cap || n - c->left > s->end - s->next)
    return 0;
  memmove(s->buf, c->p, c->left);
  size_t want = s->cap - c->left;
  if (want > s->end - s->next)
    want = (size_t)(s->end - s->next);
  if (!src_read(s->src, s->next, s->buf + c->left, want))
    return 0;
  s->next += want;
  c->p = s->buf;
  c->left += want;
  return 1;
}

static int cur_take(ubk_cursor *c, size_t n, const uint8_t **out)
{
  if (!cur_need(c, n))
    return 0;
  *out = c->p;
  c->p += n;
  c->left -= n;
  return 1;
}

static int cur_u32(ubk_cursor *c, uint32_t *out)
{
  uint8_t b[4];
  const uint8_t *p;
  if (!cur_take(c, 4, &p))
    return 0;
  memcpy(b, p, 4);
  *out = le_get32(b);
  return 1;
}

static int cur_f32s(ubk_cursor *c, float *out, size_t n)
{
  const uint8_t *p;
  if (n > SIZE_MAX / 4 || !cur_take(c, n * 4, &p))
    return 0;
  for (size_t i = 0; i < n; i++) {
    uint8_t b[4];
    memcpy(b, p + i * 4, 4);
    out[i] = bits_float(le_get32(b));
  }
  return 1;
}

static int cur_u32s(ubk_cursor *c, uint32_t *out, size_t n)
{
  const uint8_t *p;
  if (n > SIZE_MAX / 4 || !cur_take(c, n * 4, &p))
    return 0;
  for (size_t i = 0; i < n; i++) {
    uint8_t b[4];
    memcpy(b, p + i * 4, 4);
    out[i] = le_get32(b);
  }
  return 1;
}

#if defined(__x86_64__) && defined(__GNUC__)
/* Halves (little-endian, as on x86) to floats 8 at a time with F16C: the same values as
 * ub_half_to_float (every finite half is a normal float or zero; VCVTPH2PS ignores DAZ)
 * except that a signalling NaN comes out quiet rather than with its payload (no writer
 * makes one); the scalar loop was 10% of loading a 460 MB bake file.
 * Returns the values done. */
__attribute__((target("avx,f16c"))) static size_t halves_f16c(const uint8_t *p, float *out,
                                                               size_t n)
{
  size_t i = 0;
  for (; i + 8 <= n; i += 8)
    _mm256_storeu_ps(out + i,
                     _mm256_cvtph_ps(_mm_loadu_si128((const __m128i *)(const void *)(p + 2 * i))));
  _mm256_zeroupper();
  return i;
}

#endif

static int cur_halves(ubk_cursor *c, float *out, size_t n)
{
  const uint8_t *p;
  if (n > SIZE_MAX / 2 || !cur_take(c, n * 2, &p))
    return 0;
  size_t i = 0;
#if defined(__x86_64__) && defined(__GNUC__)
  const unsigned need = UB_CPU_AVX | UB_CPU_F16C;
  if ((ub_cpu_features_cached() & need) == need)
    i = halves_f16c(p, out, n);
#endif
  for (; i < n; i++) {
    uint8_t b[2];
    memcpy(b, p + i * 2, 2);
    out[i] = ub_half_to_float(le_get16(b));
  }
  return 1;
}

/* n halves as they are (little-endian in the file). */
static int cur_halves_raw(ubk_cursor *c, uint16_t *out, size_t n)
{
  const uint8_t *p;
  if (n > SIZE_MAX / 2 || !cur_take(c, n * 2, &p))
    return 0;
  for (size_t i = 0; i < n; i++)
    out[i] = le_get16(p + i * 2);
  return 1;
}

/* calloc of count × size with the product overflow-checked (large ones on huge pages:
 * runtime/bigalloc.h). */
static void *calloc_array(uint64_t count, size_t size)
{
  if (count == 0)
    return NULL;
  if (count > SIZE_MAX / size)
    return NULL;
  return ub_big_calloc((size_t)count, size);
}

typedef struct ubk_reader {
  const char *name;
  const ub_log *log;
  unsigned flags; /* UB_BAKEFILE_RECORD_HALVES */
} ubk_reader;

static ub_result parse_meta(const ubk_reader *rd, const uint8_t *p, uint64_t size,
                            ub_bakefile *bf)
{
  if (size != UB_UBK_META_SIZE) {
    ubk_error(rd->log, rd->name, "section META", "size %llu, expected %u",
              (unsigned long long)size, UB_UBK_META_SIZE);
    return UB_ERR_INVALID_DATA;
  }
  ubk_cursor c = {p, (size_t)size, NULL};
  const uint8_t *name;
  cur_take(&c, 64, &name);
  const uint8_t *nul = memchr(name, 0, 64);
  if (!nul) {
    ubk_error(rd->log, rd->name, "section META", "level name is not NUL-terminated");
    return UB_ERR_INVALID_DATA;
  }
  memcpy(bf->level_name, name, (size_t)(nul - name));
  cur_u32(&c, &bf->seed);
  cur_u32(&c, &bf->bounces);
  return UB_OK;
}

static ub_result parse_geom(const ubk_reader *rd, const uint8_t *p, uint64_t size,
                            ub_bakefile *bf)
{
  ubk_cursor c = {p, (size_t)size, NULL};
  uint32_t v, t;
  if (!cur_u32(&c, &v) || !cur_u32(&c, &t)) {
    ubk_error(rd->log, rd->name, "section GEOM", "size %llu too small for the counts",
              (unsigned long long)size);
    return UB_ERR_INVALID_DATA;
  }
  /* u32 counts: this cannot overflow 64 bits. */
  uint64_t expect = 8u + 12u * (uint64_t)v + 52u * (uint64_t)t;
  if (expect != size) {
    ubk_error(rd->log, rd->name, "section GEOM", "size %llu does not match %u vertices and "
              "%u triangles (%llu bytes)", (unsigned long long)size, v, t,
              (unsigned long long)expect);
    return UB_ERR_INVALID_DATA;
  }
  /* From here each array is bounded by the section size, which is bounded by the input. */
  bf->positions = calloc_array((uint64_t)v * 3, sizeof(float));
  bf->indices = calloc_array((uint64_t)t * 3, sizeof(uint32_t));
  bf->tri_atlas = calloc_array(t, sizeof(int32_t));
  bf->tri_uv = calloc_array((uint64_t)t * 6, sizeof(float));
  bf->tri_albedo = calloc_array((uint64_t)t * 3, sizeof(float));
  if ((v && !bf->positions) ||
      (t && (!bf->indices || !bf->tri_atlas || !bf->tri_uv || !bf->tri_albedo))) {
    ubk_error(rd->log, rd->name, "section GEOM", "out of memory");
    return UB_ERR_OUT_OF_MEMORY;
  }
  bf->vertex_count = v;
  bf->triangle_count = t;
  int ok = cur_f32s(&c, bf->positions, (size_t)v * 3) &&
           cur_u32s(&c, bf->indices, (size_t)t * 3) &&
           cur_u32s(&c, (uint32_t *)bf->tri_atlas, t) &&
           cur_f32s(&c, bf->tri_uv, (size_t)t * 6) &&
           cur_f32s(&c, bf->tri_albedo, (size_t)t * 3);
  assert(ok && c.left == 0); /* guaranteed by the exact size check above */
  (void)ok;
  return UB_OK;
}

static ub_result parse_atls(const ubk_reader *rd, const uint8_t *p, uint64_t size,
                            ub_bakefile *bf)
{
  ubk_cursor c = {p, (size_t)size, NULL};
  uint32_t count;
  float scale;
  if (!cur_u32(&c, &count) || !cur_f32s(&c, &scale, 1)) {
    ubk_error(rd->log, rd->name, "section ATLS", "size %llu too small for the atlas count",
              (unsigned long long)size);
    return UB_ERR_INVALID_DATA;
  }
  if (scale == 0.0f)
    scale = 1.0f;
  if (!isfinite(scale) || scale < 1.0f) {
    ubk_error(rd->log, rd->name, "section ATLS", "SH scale %g is not finite and >= 1",
              (double)scale);
    return UB_ERR_INVALID_DATA;
  }
  if (count > c.left / 8) {
    ubk_error(rd->log, rd->name, "section ATLS", "atlas count %u does not fit in %llu bytes",
              count, (unsigned long long)size);
    return UB_ERR_INVALID_DATA;
  }
  /* Directory first: sizes and the total are checked before any texel array exists. */
  ubk_cursor dir = c;
  c.p += (size_t)count * 8;
  c.left -= (size_t)count * 8;
  uint64_t total = 0;
  for (uint32_t a = 0; a < count; a++) {
    uint32_t w = 0, h = 0;
    cur_u32(&dir, &w);
    cur_u32(&dir, &h);
    if (w < 1 || w > UB_UBK_ATLAS_MAX_DIM || h < 1 || h > UB_UBK_ATLAS_MAX_DIM) {
      ubk_error(rd->log, rd->name, "section ATLS", "atlas %u: size %ux%u not in [1, %u]", a, w,
                h, UB_UBK_ATLAS_MAX_DIM);
      return UB_ERR_INVALID_DATA;
    }
    total += align8((uint64_t)w * h * 31u);
    if (total > c.left) {
      ubk_error(rd->log, rd->name, "section ATLS", "atlas %u (%ux%u) runs past the end of the "
                "section (%llu bytes)", a, w, h, (unsigned long long)size);
      return UB_ERR_INVALID_DATA;
    }
  }
  if (total != c.left) {
    ubk_error(rd->log, rd->name, "section ATLS", "%llu trailing bytes after the last atlas",
              (unsigned long long)(c.left - total));
    return UB_ERR_INVALID_DATA;
  }
  if (count) {
    bf->atlases = calloc_array(count, sizeof *bf->atlases);
    if (!bf->atlases) {
      ubk_error(rd->log, rd->name, "section ATLS", "out of memory");
      return UB_ERR_OUT_OF_MEMORY;
    }
  }
  bf->atlas_count = count; /* ub_bakefile_free frees what was allocated so far */
  dir.p = p + 8;
  dir.left = (size_t)count * 8;
  for (uint32_t a = 0; a < count; a++) {
    ub_bakefile_atlas *at = &bf->atlases[a];
    cur_u32(&dir, &at->width);
    cur_u32(&dir, &at->height);
    size_t texels = (size_t)at->width * at->height;
    at->sh = calloc_array((uint64_t)texels * UB_SH1_FLOATS, sizeof(float));
    at->normal = calloc_array((uint64_t)texels * 3, sizeof(float));
    at->coverage = calloc_array(texels, 1);
    if (!at->sh || !at->normal || !at->coverage) {
      ubk_error(rd->log, rd->name, "section ATLS", "atlas %u: out of memory", a);
      return UB_ERR_OUT_OF_MEMORY;
    }
    const uint8_t *cov, *pad;
    uint64_t block = (uint64_t)texels * 31u;
    int ok = cur_halves(&c, at->sh, texels * UB_SH1_FLOATS) &&
             cur_halves(&c, at->normal, texels * 3) && cur_take(&c, texels, &cov) &&
             cur_take(&c, (size_t)(align8(block) - block), &pad);
    assert(ok); /* guaranteed by the size walk above */
    (void)ok;
    memcpy(at->coverage, cov, texels);
    if (scale != 1.0f)
      for (size_t i = 0; i < texels * UB_SH1_FLOATS; i++)
        at->sh[i] *= scale;
    for (size_t i = 0; i < texels; i++) {
      float un[3];
      if (ub_texel_normal(at->normal + 3 * i, un))
        ub_texel_sh_unpack(at->sh + i * UB_SH1_FLOATS, un);
    }
  }
  return UB_OK;
}

/* A section's SH scale field: 0 means 1; else a finite power of two ≥ 1 (any finite value
 * ≥ 1 is accepted: the data is multiplied by it). Returns 0 (error logged) otherwise. */
static int check_scale(const ubk_reader *rd, const char *where, float *scale)
{
  if (*scale == 0.0f)
    *scale = 1.0f;
  if (!isfinite(*scale) || *scale < 1.0f) {
    ubk_error(rd->log, rd->name, where, "SH scale %g is not finite and >= 1", (double)*scale);
    return 0;
  }
  return 1;
}

static void apply_scale(float *v, size_t n, float scale)
{
  if (scale != 1.0f)
    for (size_t i = 0; i < n; i++)
      v[i] *= scale;
}

static ub_result parse_glgp(const ubk_reader *rd, const uint8_t *p, uint64_t size,
                            ub_bakefile *bf)
{
  ubk_cursor c = {p, (size_t)size, NULL};
  uint32_t np, nt, nk;
  float scale;
  if (!cur_u32(&c, &np) || !cur_u32(&c, &nt) || !cur_u32(&c, &nk) || !cur_f32s(&c, &scale, 1)) {
    ubk_error(rd->log, rd->name, "section GLGP", "size %llu too small for the counts",
              (unsigned long long)size);
    return UB_ERR_INVALID_DATA;
  }
  /* u32 counts: this cannot overflow 64 bits. */
  uint64_t expect = 16u + (12u + 2u * UB_GLG_SH_FLOATS) * (uint64_t)np + 36u * (uint64_t)nt +
                    16u * (uint64_t)nk;
  if (expect != size) {
    ubk_error(rd->log, rd->name, "section GLGP", "size %llu does not match %u probes, %u "
              "tetrahedra and %u planes (%llu bytes)", (unsigned long long)size, np, nt, nk,
              (unsigned long long)expect);
    return UB_ERR_INVALID_DATA;
  }
  bf->glg_positions = calloc_array((uint64_t)np * 3, sizeof(float));
  bf->glg_sh = calloc_array((uint64_t)np * UB_GLG_SH_FLOATS, sizeof(float));
  bf->glg_tets = calloc_array((uint64_t)nt * 4, sizeof(uint32_t));
  bf->glg_neigh = calloc_array((uint64_t)nt * 4, sizeof(int32_t));
  bf->glg_planes = calloc_array((uint64_t)nk * 4, sizeof(float));
  bf->glg_plane_of = calloc_array(nt, sizeof(uint32_t));
  if ((np && (!bf->glg_positions || !bf->glg_sh)) ||
      (nt && (!bf->glg_tets || !bf->glg_neigh || !bf->glg_plane_of)) || (nk && !bf->glg_planes)) {
    ubk_error(rd->log, rd->name, "section GLGP", "out of memory");
    return UB_ERR_OUT_OF_MEMORY;
  }
  bf->glg_probe_count = np;
  bf->glg_tet_count = nt;
  bf->glg_plane_count = nk;
  int ok = cur_f32s(&c, bf->glg_positions, (size_t)np * 3) &&
           cur_u32s(&c, bf->glg_tets, (size_t)nt * 4) &&
           cur_u32s(&c, (uint32_t *)bf->glg_neigh, (size_t)nt * 4) &&
           cur_f32s(&c, bf->glg_planes, (size_t)nk * 4) &&
           cur_u32s(&c, bf->glg_plane_of, nt) &&
           cur_halves(&c, bf->glg_sh, (size_t)np * UB_GLG_SH_FLOATS);
  assert(ok && c.left == 0); /* guaranteed by the exact size check above */
  (void)ok;
  if (!check_scale(rd, "section GLGP", &scale))
    return UB_ERR_INVALID_DATA;
  apply_scale(bf->glg_sh, (size_t)np * UB_GLG_SH_FLOATS, scale);
  return UB_OK;
}

/* A read of the file failed while parsing `where` (src->err), or memory ran out. */
static ub_result src_error(const ubk_reader *rd, const ubk_src *src, const char *where)
{
  if (!src->err) {
    ubk_error(rd->log, rd->name, where, "out of memory");
    return UB_ERR_OUT_OF_MEMORY;
  }
  ubk_error(rd->log, rd->name, where, "%s",
            src->err > 0 ? strerror(src->err) : "file changed while reading");
  return UB_ERR_IO;
}

/* The records section at off (size bytes) of src: its count and headers are read first, the
 * values then stream (a file: through a buffer of a few MiB, never the whole section). */
static ub_result parse_records(const ubk_reader *rd, ubk_src *src, uint64_t off, uint64_t size,
                               const char *where, ub_bakefile_record **out_recs,
                               uint32_t *out_count)
{
  uint8_t h8[8];
  if (size < 8) {
    ubk_error(rd->log, rd->name, where, "size %llu too small for the count",
              (unsigned long long)size);
    return UB_ERR_INVALID_DATA;
  }
  if (!src_read(src, off, h8, 8))
    return src_error(rd, src, where);
  ubk_cursor c = {h8, 8, NULL};
  uint32_t ns = 0;
  float scale = 0.0f; /* both read: 8 bytes are there (GCC -O3 cannot see it past assert) */
  int ok = cur_u32(&c, &ns) && cur_f32s(&c, &scale, 1);
  assert(ok);
  if (!check_scale(rd, where, &scale))
    return UB_ERR_INVALID_DATA;
  if ((uint64_t)ns * UB_REC_HEADER > size - 8) {
    ubk_error(rd->log, rd->name, where, "%u records do not fit in %llu bytes", ns,
              (unsigned long long)size);
    return UB_ERR_INVALID_DATA;
  }
  const uint64_t head = (uint64_t)ns * UB_REC_HEADER;
  uint8_t *owned;
  const uint8_t *p = src_view(src, off + 8, head, &owned);
  if (!p)
    return src_error(rd, src, where);
  /* Walk the headers to check the exact size before allocating anything big; the widest
   * array sizes the stream's buffer. */
  uint64_t expect = 8u + head, widest = 0;
  for (uint32_t d = 0; d < ns; d++) {
    const uint8_t *h = p + (size_t)d * UB_REC_HEADER;
    uint64_t tc = le_get32(h + 84), pc = le_get32(h + 88), lc = le_get32(h + 92);
    expect += align8(28u * tc + 58u * pc + 58u * lc);
    uint64_t w = 24u * tc > 54u * (pc > lc ? pc : lc) ? 24u * tc : 54u * (pc > lc ? pc : lc);
    widest = w > widest ? w : widest;
    if (expect > size)
      break;
  }
  if (expect != size) {
    ubk_error(rd->log, rd->name, where, "size %llu does not match its %u records' counts",
              (unsigned long long)size, ns);
    tmp_free(owned);
    return UB_ERR_INVALID_DATA;
  }
  ub_bakefile_record *recs = calloc_array(ns, sizeof *recs);
  if (ns && !recs) {
    ubk_error(rd->log, rd->name, where, "out of memory");
    tmp_free(owned);
    return UB_ERR_OUT_OF_MEMORY;
  }
  *out_recs = recs;
  *out_count = ns;
  c = (ubk_cursor){p, (size_t)head, NULL};
  for (uint32_t d = 0; d < ns; d++) {
    ub_bakefile_record *r = &recs[d];
    const uint8_t *nm;
    uint32_t p0, p1;
    ok = cur_take(&c, 64, &nm);
    assert(ok);
    memcpy(r->name, nm, 64);
    ok = cur_u32(&c, &r->kind) && cur_u32(&c, &p0) && cur_u32(&c, &p1) &&
         cur_u32(&c, &r->light_count) && cur_f32s(&c, &r->mean_intensity, 1) &&
         cur_u32(&c, &r->texel_count) && cur_u32(&c, &r->probe_count) &&
         cur_u32(&c, &r->llg_probe_count);
    assert(ok);
    (void)ok;
    r->parent[0] = (int32_t)p0;
    r->parent[1] = (int32_t)p1;
  }
  tmp_free(owned);
  /* the values: in memory as they are, from a file through the stream's buffer */
  ubk_stream st = {src, off + 8 + head, off + size, NULL, 0};
  if (src->mem) {
    c = (ubk_cursor){src->mem + st.next, (size_t)(size - 8 - head), NULL};
  } else {
    /* an eighth of the file, at most 4 MiB (a small file refills it too: the tests' files
     * go through the refill), at least the widest array */
    uint64_t cap = src->size / 8 < 4 * UBK_CHUNK ? src->size / 8 : 4 * UBK_CHUNK;
    st.cap = (size_t)(widest + 64 > cap ? widest + 64 : cap);
    st.buf = tmp_alloc(st.cap);
    if (!st.buf)
      return src_error(rd, src, where);
    c = (ubk_cursor){st.buf, 0, &st};
  }
  ub_result res = UB_OK;
  for (uint32_t d = 0; d < ns && res == UB_OK; d++) {
    ub_bakefile_record *r = &recs[d];
    r->texel_index = calloc_array(r->texel_count, sizeof(uint32_t));
    r->probe_index = calloc_array(r->probe_count, sizeof(uint32_t));
    r->llg_probe_index = calloc_array(r->llg_probe_count, sizeof(uint32_t));
    const size_t nt = (size_t)r->texel_count * UB_SH1_FLOATS,
                 np = (size_t)r->probe_count * UB_GLG_SH_FLOATS,
                 nl = (size_t)r->llg_probe_count * UB_GLG_SH_FLOATS;
    const int halves = (rd->flags & UB_BAKEFILE_RECORD_HALVES) != 0;
    if (halves) {
      r->texel_sh_half = calloc_array(nt, sizeof(uint16_t));
      r->probe_sh_half = calloc_array(np, sizeof(uint16_t));
      r->llg_probe_sh_half = calloc_array(nl, sizeof(uint16_t));
      r->sh_half_scale = scale;
    } else {
      r->texel_sh = calloc_array(nt, sizeof(float));
      r->probe_sh = calloc_array(np, sizeof(float));
      r->llg_probe_sh = calloc_array(nl, sizeof(float));
    }
    if ((r->texel_count && (!r->texel_index || !(halves ? (void *)r->texel_sh_half : (void *)r->texel_sh))) ||
        (r->probe_count && (!r->probe_index || !(halves ? (void *)r->probe_sh_half : (void *)r->probe_sh))) ||
        (r->llg_probe_count &&
         (!r->llg_probe_index || !(halves ? (void *)r->llg_probe_sh_half : (void *)r->llg_probe_sh)))) {
      ubk_error(rd->log, rd->name, where, "out of memory");
      res = UB_ERR_OUT_OF_MEMORY;
      break;
    }
    uint64_t block = record_block(r);
    const uint8_t *pad;
    ok = cur_u32s(&c, r->texel_index, r->texel_count) &&
         cur_u32s(&c, r->probe_index, r->probe_count) &&
         cur_u32s(&c, r->llg_probe_index, r->llg_probe_count) &&
         (halves ? cur_halves_raw(&c, r->texel_sh_half, nt) &&
                       cur_halves_raw(&c, r->probe_sh_half, np) &&
                       cur_halves_raw(&c, r->llg_probe_sh_half, nl)
                 : cur_halves(&c, r->texel_sh, nt) && cur_halves(&c, r->probe_sh, np) &&
                       cur_halves(&c, r->llg_probe_sh, nl)) &&
         cur_take(&c, (size_t)(align8(block) - block), &pad);
    /* the exact size walk above guarantees the bytes; only a file read can fail */
    assert(ok || src->err);
    if (!ok && !src->err) { /* a read wider than the stream's buffer: a reader bug */
      ubk_error(rd->log, rd->name, where, "record %u: read past the stream's buffer", d);
      res = UB_ERR_INVALID_DATA;
      break;
    }
    if (!ok) {
      res = src_error(rd, src, where);
      break;
    }
    if (!halves) {
      apply_scale(r->texel_sh, nt, scale);
      apply_scale(r->probe_sh, np, scale);
      apply_scale(r->llg_probe_sh, nl, scale);
    }
  }
  tmp_free(st.buf);
  return res;
}

/* After ATLS and the records are parsed: the records' texel SH back from the I_z form.
 * Indices out of range are left for validate() to report. */
static void unpack_record_texels(ub_bakefile *bf, ub_bakefile_record *recs, uint32_t count)
{
  uint64_t pixels = ub_bakefile_atlas_pixels(bf);
  for (uint32_t d = 0; d < count; d++) {
    ub_bakefile_record *r = &recs[d];
    for (uint32_t i = 0; r->texel_sh && i < r->texel_count; i++) {
      if (r->texel_index[i] >= pixels)
        continue;
      const float *n = ub_bakefile_pixel_normal(bf, r->texel_index[i]);
      float un[3];
      if (n && ub_texel_normal(n, un))
        ub_texel_sh_unpack(r->texel_sh + (size_t)i * UB_SH1_FLOATS, un);
    }
  }
}

static ub_result parse_lite(const ubk_reader *rd, const uint8_t *p, uint64_t size,
                            ub_bakefile *bf)
{
  ubk_cursor c = {p, (size_t)size, NULL};
  uint32_t n, reserved;
  if (!cur_u32(&c, &n) || !cur_u32(&c, &reserved) ||
      align8(8u + (uint64_t)UB_LITE_SIZE * n) != size) {
    ubk_error(rd->log, rd->name, "section LITE", "size %llu does not match its light count",
              (unsigned long long)size);
    return UB_ERR_INVALID_DATA;
  }
  bf->lights = calloc_array(n, sizeof *bf->lights);
  if (n && !bf->lights) {
    ubk_error(rd->log, rd->name, "section LITE", "out of memory");
    return UB_ERR_OUT_OF_MEMORY;
  }
  bf->light_count = n;
  for (uint32_t l = 0; l < n; l++) {
    ub_bakefile_light *L = &bf->lights[l];
    uint32_t dls;
    int ok = cur_u32(&c, &L->type) && cur_u32(&c, &L->cls) && cur_u32(&c, &dls) &&
             cur_f32s(&c, L->position, 3) && cur_f32s(&c, L->direction, 3) &&
             cur_f32s(&c, L->intensity, 3) && cur_f32s(&c, &L->range, 1) &&
             cur_f32s(&c, &L->cos_inner, 1) && cur_f32s(&c, &L->cos_outer, 1);
    assert(ok);
    (void)ok;
    L->dls = (int32_t)dls;
  }
  return UB_OK;
}

static ub_result parse_trir(const ubk_reader *rd, const uint8_t *p, uint64_t size,
                            ub_bakefile *bf)
{
  static const char *where = "section TRIR";
  ubk_cursor c = {p, (size_t)size, NULL};
  uint32_t n, reserved;
  if (!cur_u32(&c, &n) || !cur_u32(&c, &reserved) || n != bf->triangle_count ||
      8u + align8(4u * (uint64_t)n) != size) {
    ubk_error(rd->log, rd->name, where, "size %llu does not match the %u triangles",
              (unsigned long long)size, bf->triangle_count);
    return UB_ERR_INVALID_DATA;
  }
  bf->tri_role = calloc_array((uint64_t)n + 1, sizeof *bf->tri_role);
  if (!bf->tri_role) {
    ubk_error(rd->log, rd->name, where, "out of memory");
    return UB_ERR_OUT_OF_MEMORY;
  }
  int ok = cur_u32s(&c, bf->tri_role, n);
  assert(ok);
  (void)ok;
  return UB_OK;
}

static ub_result parse_txlk(const ubk_reader *rd, const uint8_t *p, uint64_t size,
                            ub_bakefile *bf)
{
  static const char *where = "section TXLK";
  ubk_cursor c = {p, (size_t)size, NULL};
  uint32_t n, reserved;
  uint64_t total = ub_bakefile_atlas_pixels(bf);
  if (!cur_u32(&c, &n) || !cur_u32(&c, &reserved) || n != bf->atlas_count ||
      8u + align8(total) != size) {
    ubk_error(rd->log, rd->name, where, "size %llu does not match the %u atlases",
              (unsigned long long)size, bf->atlas_count);
    return UB_ERR_INVALID_DATA;
  }
  const uint8_t *q = p + 8;
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    ub_bakefile_atlas *at = &bf->atlases[a];
    size_t npx = (size_t)at->width * at->height;
    for (size_t i = 0; i < npx; i++)
      if (q[i] > (UB_LINK_X | UB_LINK_Y)) {
        ubk_error(rd->log, rd->name, where, "atlas %u: texel (%zu, %zu): link %u not in [0, 3]",
                  a, i % at->width, i / at->width, q[i]);
        return UB_ERR_INVALID_DATA;
      }
    at->link = malloc(npx + 1);
    if (!at->link) {
      ubk_error(rd->log, rd->name, where, "out of memory");
      return UB_ERR_OUT_OF_MEMORY;
    }
    memcpy(at->link, q, npx);
    q += npx;
  }
  return UB_OK;
}

static ub_result parse_llgm(const ubk_reader *rd, const uint8_t *p, uint64_t size,
                            ub_bakefile *bf)
{
  static const char *where = "section LLGM";
  ubk_cursor c = {p, (size_t)size, NULL};
  uint32_t nm, flags;
  if (!cur_u32(&c, &nm) || !cur_u32(&c, &flags)) {
    ubk_error(rd->log, rd->name, where, "size %llu too small for the count",
              (unsigned long long)size);
    return UB_ERR_INVALID_DATA;
  }
  if (flags & ~UB_LLGM_FLAG_SHARED) {
    ubk_error(rd->log, rd->name, where, "unknown flags 0x%x", flags);
    return UB_ERR_INVALID_DATA;
  }
  uint64_t hs = (flags & UB_LLGM_FLAG_SHARED) ? UB_LLGM_MODEL_HEADER_SHARED
                                              : UB_LLGM_MODEL_HEADER;
  if ((uint64_t)nm * hs > size - 8) {
    ubk_error(rd->log, rd->name, where, "%u models do not fit in %llu bytes", nm,
              (unsigned long long)size);
    return UB_ERR_INVALID_DATA;
  }
  /* Walk the model headers: dims range, sharing and the exact size before allocating
   * anything. */
  uint64_t expect = 8u + (uint64_t)nm * hs;
  for (uint32_t i = 0; i < nm && expect <= size; i++) {
    const uint8_t *h = p + 8 + (size_t)i * hs;
    uint32_t from = hs == UB_LLGM_MODEL_HEADER ? 0 : le_get32(h + 144);
    if (from) {
      const uint8_t *hsrc = from - 1 < i ? p + 8 + (size_t)(from - 1) * hs : NULL;
      if (!hsrc || le_get32(hsrc + 144) != 0 || le_get32(hsrc + 136) != le_get32(h + 136)) {
        ubk_error(rd->log, rd->name, where, "model %u: shares the self-visibility of model "
                  "%u, which is not an earlier model with its own and the same vertex count",
                  i, from - 1);
        return UB_ERR_INVALID_DATA;
      }
    }
    uint64_t np = 1;
    for (int a = 0; a < 3; a++) {
      uint32_t d = le_get32(h + 124 + 4 * a);
      if (d < 2 || d > UB_LLGM_MAX_DIM) {
        ubk_error(rd->log, rd->name, where, "model %u: %u probes along axis %d not in [2, %u]",
                  i, d, a, UB_LLGM_MAX_DIM);
        return UB_ERR_INVALID_DATA;
      }
      np *= d;
    }
    expect += align8(llgm_block_size(np, le_get32(h + 136), le_get32(h + 140), from == 0));
  }
  if (expect != size) {
    ubk_error(rd->log, rd->name, where, "size %llu does not match its %u models' counts",
              (unsigned long long)size, nm);
    return UB_ERR_INVALID_DATA;
  }
  bf->llgs = calloc_array(nm, sizeof *bf->llgs);
  if (nm && !bf->llgs) {
    ubk_error(rd->log, rd->name, where, "out of memory");
    return UB_ERR_OUT_OF_MEMORY;
  }
  bf->llg_count = nm;
  for (uint32_t i = 0; i < nm; i++) {
    ub_bakefile_llg *m = &bf->llgs[i];
    const uint8_t *nmp = NULL;
    int ok = cur_take(&c, 64, &nmp);
    assert(ok && nmp);
    memcpy(m->name, nmp, 64);
    ok = cur_f32s(&c, m->center, 3) && cur_f32s(&c, m->axes, 9) &&
         cur_f32s(&c, m->half, 3) && cur_u32s(&c, m->dims, 3) &&
         cur_u32(&c, &m->vertex_count) && cur_u32(&c, &m->triangle_count);
    if (hs == UB_LLGM_MODEL_HEADER_SHARED)
      ok = ok && cur_u32(&c, &m->vis_shared_from) && cur_f32s(&c, m->vis_rotation, 9);
    assert(ok);
    (void)ok;
  }
  for (uint32_t i = 0; i < nm; i++) {
    ub_bakefile_llg *m = &bf->llgs[i];
    uint64_t np = (uint64_t)m->dims[0] * m->dims[1] * m->dims[2], nv = m->vertex_count;
    m->probe_sh = calloc_array(np * UB_GLG_SH_FLOATS, sizeof(float));
    m->positions = calloc_array(nv * 3, sizeof(float));
    m->normals = calloc_array(nv * 3, sizeof(float));
    m->vis = calloc_array(nv * 9, sizeof(float));
    m->self = calloc_array(nv * 3, sizeof(float));
    m->indices = calloc_array((uint64_t)m->triangle_count * 3, sizeof(uint32_t));
    if (!m->probe_sh || (nv && (!m->positions || !m->normals || !m->vis || !m->self)) ||
        (m->triangle_count && !m->indices)) {
      ubk_error(rd->log, rd->name, where, "out of memory");
      return UB_ERR_OUT_OF_MEMORY;
    }
    int own = m->vis_shared_from == 0;
    uint64_t block = llgm_block_size(np, nv, m->triangle_count, own);
    const uint8_t *pad;
    int ok = cur_f32s(&c, m->positions, (size_t)nv * 3) &&
             cur_f32s(&c, m->normals, (size_t)nv * 3) &&
             cur_u32s(&c, m->indices, (size_t)m->triangle_count * 3) &&
             cur_halves(&c, m->probe_sh, (size_t)np * UB_GLG_SH_FLOATS) &&
             (!own || cur_halves(&c, m->vis, (size_t)nv * 9)) &&
             cur_halves(&c, m->self, (size_t)nv * 3) &&
             cur_take(&c, (size_t)(align8(block) - block), &pad);
    assert(ok); /* guaranteed by the exact size walk above */
    (void)ok;
    if (!own) { /* an instance: the earlier model's (already read) visibility, rotated */
      const ub_bakefile_llg *src = &bf->llgs[m->vis_shared_from - 1];
      float M[81];
      ub_llg_sh_rotation(m->vis_rotation, M);
      for (uint64_t v = 0; v < nv; v++)
        ub_llg_sh_rotate(M, src->vis + 9 * v, m->vis + 9 * v);
    }
  }
  return UB_OK;
}

static ub_result read_src(ubk_src *src, const char *name, const ub_log *log, unsigned flags,
                          ub_bakefile **out_bf);

ub_result ub_bakefile_read_memory(const void *data, size_t size, const char *name,
                                  const ub_log *log, ub_bakefile **out_bf)
{
  assert(data || size == 0);
  ubk_src src = {(const uint8_t *)data, -1, size, 0};
  if (!data) /* size 0: the header check below reports it */
    src.mem = (const uint8_t *)"";
  return read_src(&src, name ? name : "(memory)", log, 0, out_bf);
}

typedef ub_result (*ubk_parse_fn)(const ubk_reader *rd, const uint8_t *p, uint64_t size,
                                  ub_bakefile *bf);

/* One section parsed from src (a file: read whole, then freed). */
static ub_result parse_section(const ubk_reader *rd, ubk_src *src, uint64_t off, uint64_t size,
                               const char *tag, ubk_parse_fn fn, ub_bakefile *bf)
{
  uint8_t *owned;
  const uint8_t *p = src_view(src, off, size, &owned);
  if (!p) {
    char where[32];
    snprintf(where, sizeof where, "section %.4s", tag);
    return src_error(rd, src, where);
  }
  ub_result r = fn(rd, p, size, bf);
  tmp_free(owned);
  return r;
}

/* Reads and checks the header and section table, every section's CRC (a file: a chunk at a
 * time), then parses the sections one at a time (a file: each read when parsed, freed
 * after; the records streamed). */
static ub_result read_src(ubk_src *src, const char *name, const ub_log *log, unsigned flags,
                          ub_bakefile **out_bf)
{
  assert(src && name && out_bf);
  ubk_reader rd = {name, log, flags};
  const size_t size = (size_t)src->size;
  uint8_t hd[UB_UBK_HEADER_SIZE];
  if (size < UB_UBK_HEADER_SIZE) {
    ubk_error(log, rd.name, "header", "file is %zu bytes, shorter than the %u-byte header",
              size, UB_UBK_HEADER_SIZE);
    return UB_ERR_INVALID_DATA;
  }
  if (!src_read(src, 0, hd, UB_UBK_HEADER_SIZE))
    return src_error(&rd, src, "header");
  if (memcmp(hd, ub_ubk_magic, 4) != 0) {
    ubk_error(log, rd.name, "header", "not a .ubk file (bad magic)");
    return UB_ERR_INVALID_DATA;
  }
  uint32_t version = le_get32(hd + 4);
  if (version == 0) {
    ubk_error(log, rd.name, "header", "format version 0 is invalid");
    return UB_ERR_INVALID_DATA;
  }
  if (version < UB_BAKEFILE_VERSION) {
    ubk_error(log, rd.name, "header", "format version %u is older than this reader's (%u): "
              "bake the level again", version, UB_BAKEFILE_VERSION);
    return UB_ERR_UNSUPPORTED_VERSION;
  }
  if (version > UB_BAKEFILE_VERSION) {
    ubk_error(log, rd.name, "header", "format version %u is newer than this reader (%u)",
              version, UB_BAKEFILE_VERSION);
    return UB_ERR_UNSUPPORTED_VERSION;
  }
  uint32_t count = le_get32(hd + 8);
  uint64_t table_end = UB_UBK_HEADER_SIZE + (uint64_t)count * UB_UBK_ENTRY_SIZE;
  if (table_end > size) {
    ubk_error(log, rd.name, "header", "section table (%u entries) runs past the end of the "
              "file (%zu bytes)", count, size);
    return UB_ERR_INVALID_DATA;
  }
  uint8_t *table_owned;
  const uint8_t *d = src_view(src, 0, table_end, &table_owned);
  uint8_t *chunk = src->mem ? NULL : tmp_alloc(UBK_CHUNK);
  if (!d || (!src->mem && !chunk)) {
    tmp_free(table_owned);
    tmp_free(chunk);
    return src_error(&rd, src, "header");
  }
  ub_result r = UB_OK;
  uint32_t hcrc = ub_crc32_update(0, d, 12);
  hcrc = ub_crc32_update(hcrc, d + UB_UBK_HEADER_SIZE, (size_t)(table_end - UB_UBK_HEADER_SIZE));
  if (UB_UBK_CHECK_CRC && hcrc != le_get32(d + 12)) {
    ubk_error(log, rd.name, "header", "header CRC mismatch (0x%08x stored, 0x%08x computed)",
              le_get32(d + 12), hcrc);
    r = UB_ERR_INVALID_DATA;
    goto table_done;
  }

  /* Section table: in file order, 8-aligned, non-overlapping, gaps zero, no trailing
   * bytes: every byte of the file is covered by a CRC or checked to be zero. */
  int known[UB_SEC_KNOWN] = {0};
  uint64_t known_off[UB_SEC_KNOWN] = {0}, known_size[UB_SEC_KNOWN] = {0};
  uint64_t prev_end = table_end;
  for (uint32_t i = 0; i < count; i++) {
    const uint8_t *e = d + UB_UBK_HEADER_SIZE + (size_t)i * UB_UBK_ENTRY_SIZE;
    char tag[5] = {0};
    memcpy(tag, e, 4);
    char where[32];
    int printable = 1;
    for (int k = 0; k < 4; k++)
      if ((unsigned char)tag[k] < 0x20 || (unsigned char)tag[k] > 0x7e)
        printable = 0;
    if (!printable) {
      ubk_error(log, rd.name, "header", "section %u: tag is not printable ASCII", i);
      r = UB_ERR_INVALID_DATA;
      goto table_done;
    }
    snprintf(where, sizeof where, "section %s", tag);
    uint32_t flags = le_get32(e + 4);
    uint64_t off = le_get64(e + 8), sz = le_get64(e + 16);
    uint32_t crc = le_get32(e + 24);
    if (off % 8 != 0) {
      ubk_error(log, rd.name, where, "offset %llu is not 8-byte aligned",
                (unsigned long long)off);
      r = UB_ERR_INVALID_DATA;
      goto table_done;
    }
    if (off < prev_end || off > size || sz > size - off) {
      ubk_error(log, rd.name, where, "offset %llu size %llu outside [%llu, %zu] or overlapping",
                (unsigned long long)off, (unsigned long long)sz, (unsigned long long)prev_end,
                size);
      r = UB_ERR_INVALID_DATA;
      goto table_done;
    }
    for (uint64_t g = prev_end; g < off;) { /* the gap, a chunk at a time */
      size_t k = off - g < UBK_CHUNK ? (size_t)(off - g) : UBK_CHUNK;
      const uint8_t *gp = src->mem ? src->mem + g : (src_read(src, g, chunk, k) ? chunk : NULL);
      if (!gp) {
        r = src_error(&rd, src, where);
        goto table_done;
      }
      for (size_t j = 0; j < k; j++)
        if (gp[j] != 0) {
          ubk_error(log, rd.name, where, "non-zero padding byte at file offset %llu",
                    (unsigned long long)(g + j));
          r = UB_ERR_INVALID_DATA;
          goto table_done;
        }
      g += k;
    }
    prev_end = off + sz;
    uint32_t got_crc = 0;
    if (UB_UBK_CHECK_CRC && !src_crc(src, off, sz, chunk, &got_crc)) {
      r = src_error(&rd, src, where);
      goto table_done;
    }
    if (UB_UBK_CHECK_CRC && got_crc != crc) {
      ubk_error(log, rd.name, where, "CRC mismatch (corrupted or truncated file)");
      r = UB_ERR_INVALID_DATA;
      goto table_done;
    }
    int k;
    for (k = 0; k < UB_SEC_KNOWN; k++)
      if (memcmp(tag, ub_sec_tags[k], 4) == 0)
        break;
    if (k == UB_SEC_KNOWN) {
      if (flags & UB_UBK_FLAG_REQUIRED) {
        ubk_error(log, rd.name, where, "required by the file but unknown to this reader");
        r = UB_ERR_UNSUPPORTED_VERSION;
        goto table_done;
      }
      continue; /* optional and unknown: skipped (forward compatibility) */
    }
    if (known[k]) {
      ubk_error(log, rd.name, where, "appears twice");
      r = UB_ERR_INVALID_DATA;
      goto table_done;
    }
    known[k] = 1;
    known_off[k] = off;
    known_size[k] = sz;
  }
  if (prev_end != size) {
    ubk_error(log, rd.name, "header", "%llu bytes after the last section",
              (unsigned long long)(size - prev_end));
    r = UB_ERR_INVALID_DATA;
    goto table_done;
  }
  for (int k = 0; k < UB_SEC_MANDATORY; k++)
    if (!known[k]) {
      char where[32];
      snprintf(where, sizeof where, "section %s", ub_sec_tags[k]);
      ubk_error(log, rd.name, where, "missing");
      r = UB_ERR_INVALID_DATA;
      goto table_done;
    }

table_done:
  tmp_free(table_owned);
  tmp_free(chunk);
  if (r != UB_OK)
    return r;

  ub_bakefile *bf = calloc(1, sizeof *bf);
  if (!bf) {
    ubk_error(log, rd.name, "header", "out of memory");
    return UB_ERR_OUT_OF_MEMORY;
  }
#define SECTION(k, fn) parse_section(&rd, src, known_off[k], known_size[k], ub_sec_tags[k], fn, bf)
  r = SECTION(UB_SEC_META, parse_meta);
  if (r == UB_OK)
    r = SECTION(UB_SEC_GEOM, parse_geom);
  if (r == UB_OK)
    r = SECTION(UB_SEC_ATLS, parse_atls);
  if (r == UB_OK && known[UB_SEC_GLGP])
    r = SECTION(UB_SEC_GLGP, parse_glgp);
  if (r == UB_OK && known[UB_SEC_DLSR])
    r = parse_records(&rd, src, known_off[UB_SEC_DLSR], known_size[UB_SEC_DLSR],
                      "section DLSR", &bf->dls, &bf->dls_count);
  if (r == UB_OK && known[UB_SEC_ELEM])
    r = parse_records(&rd, src, known_off[UB_SEC_ELEM], known_size[UB_SEC_ELEM],
                      "section ELEM", &bf->elems, &bf->elem_count);
  if (r == UB_OK) {
    unpack_record_texels(bf, bf->dls, bf->dls_count);
    unpack_record_texels(bf, bf->elems, bf->elem_count);
  }
  if (r == UB_OK && known[UB_SEC_LITE])
    r = SECTION(UB_SEC_LITE, parse_lite);
  if (r == UB_OK && known[UB_SEC_LLGM])
    r = SECTION(UB_SEC_LLGM, parse_llgm);
  if (r == UB_OK && known[UB_SEC_TRIR])
    r = SECTION(UB_SEC_TRIR, parse_trir);
  if (r == UB_OK && known[UB_SEC_TXLK])
    r = SECTION(UB_SEC_TXLK, parse_txlk);
#undef SECTION
  if (r == UB_OK)
    r = validate(bf, rd.name, log);
  if (r != UB_OK) {
    ub_bakefile_free(bf);
    return r;
  }
  *out_bf = bf;
  return UB_OK;
}

ub_result ub_bakefile_read(const char *path, const ub_log *log, ub_bakefile **out_bf)
{
  return ub_bakefile_read_ex(path, log, 0, out_bf);
}

ub_result ub_bakefile_read_ex(const char *path, const ub_log *log, unsigned flags,
                              ub_bakefile **out_bf)
{
  assert(path && out_bf);
  FILE *f = fopen(path, "rb");
  if (!f) {
    ubk_error(log, path, "read", "cannot open: %s", strerror(errno));
    return UB_ERR_IO;
  }
  struct stat st;
  if (fstat(fileno(f), &st) != 0) {
    ubk_error(log, path, "read", "cannot stat: %s", strerror(errno));
    fclose(f);
    return UB_ERR_IO;
  }
  if (!S_ISREG(st.st_mode)) {
    ubk_error(log, path, "read", "not a regular file");
    fclose(f);
    return UB_ERR_IO;
  }
  if (st.st_size < 0 || (uint64_t)st.st_size > UB_UBK_MAX_FILE_SIZE ||
      (uint64_t)st.st_size > SIZE_MAX) {
    ubk_error(log, path, "read", "file size %lld outside [0, %llu]", (long long)st.st_size,
              (unsigned long long)UB_UBK_MAX_FILE_SIZE);
    fclose(f);
    return UB_ERR_INVALID_DATA;
  }
  /* Read where parsed (ubk_src): the load holds a section at a time, not the file. */
  ubk_src src = {NULL, fileno(f), (uint64_t)st.st_size, 0};
  ub_result r = read_src(&src, path, log, flags, out_bf);
  /* The CRCs are checked in a first read and the sections parsed from a second: a file
   * written while it was read (size, modification or status change time, to the
   * nanosecond, or another inode) may have mixed old and new bytes. The baker writes a
   * new file and renames it over the old, which an open reader does not see. */
  struct stat st2;
  if (r == UB_OK &&
      (fstat(fileno(f), &st2) != 0 || st2.st_size != st.st_size || st2.st_ino != st.st_ino ||
       st2.st_mtim.tv_sec != st.st_mtim.tv_sec || st2.st_mtim.tv_nsec != st.st_mtim.tv_nsec ||
       st2.st_ctim.tv_sec != st.st_ctim.tv_sec || st2.st_ctim.tv_nsec != st.st_ctim.tv_nsec)) {
    ubk_error(log, path, "read", "file changed while reading");
    ub_bakefile_free(*out_bf);
    *out_bf = NULL;
    r = UB_ERR_IO;
  }
  fclose(f);
  return r;
}

void ub_bakefile_free(ub_bakefile *bf)
{
  if (!bf)
    return;
  free(bf->positions);
  free(bf->indices);
  free(bf->tri_atlas);
  free(bf->tri_uv);
  free(bf->tri_albedo);
  for (uint32_t a = 0; a < bf->atlas_count; a++) {
    free(bf->atlases[a].sh);
    free(bf->atlases[a].coverage);
    free(bf->atlases[a].link);
    free(bf->atlases[a].normal);
  }
  free(bf->atlases);
  free(bf->glg_positions);
  free(bf->glg_sh);
  free(bf->glg_tets);
  free(bf->glg_neigh);
  free(bf->glg_planes);
  free(bf->glg_plane_of);
  for (int e = 0; e < 2; e++) {
    ub_bakefile_record *recs = e ? bf->elems : bf->dls;
    uint32_t count = e ? bf->elem_count : bf->dls_count;
    for (uint32_t d = 0; d < count; d++) {
      free(recs[d].texel_index);
      free(recs[d].texel_sh);
      free(recs[d].probe_index);
      free(recs[d].probe_sh);
      free(recs[d].llg_probe_index);
      free(recs[d].llg_probe_sh);
      free(recs[d].texel_sh_half);
      free(recs[d].probe_sh_half);
      free(recs[d].llg_probe_sh_half);
    }
    free(recs);
  }
  free(bf->tri_role);
  free(bf->lights);
  for (uint32_t i = 0; i < bf->llg_count; i++) {
    free(bf->llgs[i].probe_sh);
    free(bf->llgs[i].positions);
    free(bf->llgs[i].normals);
    free(bf->llgs[i].vis);
    free(bf->llgs[i].self);
    free(bf->llgs[i].indices);
  }
  free(bf->llgs);
  free(bf);
}
