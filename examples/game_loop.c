/* examples/game_loop.c — what a game does with the run-time library (include/ubake/runtime.h):
 * load a bake file, upload its lightmap atlases once, toggle dynamic light sets, and after
 * each update re-upload only what changed (the lightmap texels the update re-encoded, with
 * the padding pixels that copy them, and the LLG models whose grids it wrote), while a
 * moving object reads the global light grid through its cursor.
 *
 * The "GPU textures" here are plain arrays; after every toggle the program checks them bit
 * for bit against what the run-time holds (ub_runtime_atlas_ahd), so it is also a test
 * (CTest example_game_loop, on the estate_small bake test_estate writes): exit status 0
 * when every incremental upload matched, 1 otherwise.
 *
 * usage: example_game_loop FILE.ubk [--toggles N] */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ubake/ahd.h"
#include "ubake/glg.h"
#include "ubake/runtime.h"

/* One atlas as the game keeps it: its texture and, per covered texel, the padding pixels
 * that copy it (made once at load from ub_runtime_texel_source; a game could bake this
 * map into its own asset). */
typedef struct game_atlas {
  uint32_t w, h;
  ub_ahd_packed *tex;   /* w × h */
  uint32_t *pad_first;  /* w × h + 1: padding pixels of source pixel p are */
  uint32_t *pad;        /* pad[pad_first[p] .. pad_first[p + 1]) */
} game_atlas;

static int atlas_setup(const ub_runtime *rt, uint32_t a, game_atlas *g)
{
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  g->w = bf->atlases[a].width;
  g->h = bf->atlases[a].height;
  const size_t n = (size_t)g->w * g->h;
  g->tex = malloc((n ? n : 1) * sizeof *g->tex);
  g->pad_first = calloc(n + 1, sizeof *g->pad_first);
  uint32_t *src = malloc((n ? n : 1) * sizeof *src);
  if (!g->tex || !g->pad_first || !src) {
    free(src);
    return 0;
  }
  /* the first upload: the whole atlas, padding filled, empty pixels zero */
  if (ub_runtime_atlas_ahd(rt, a, g->tex) != UB_OK) {
    free(src);
    return 0;
  }
  uint32_t npad = 0;
  for (size_t i = 0; i < n; i++) {
    uint32_t sx, sy;
    src[i] = UINT32_MAX;
    if (bf->atlases[a].coverage[i] == 2 &&
        ub_runtime_texel_source(rt, a, (uint32_t)(i % g->w), (uint32_t)(i / g->w), &sx, &sy) ==
            UB_OK) {
      src[i] = (uint32_t)((size_t)sy * g->w + sx); /* < w × h: fits (a texture's pixels) */
      g->pad_first[src[i] + 1]++;
      npad++;
    }
  }
  for (size_t i = 0; i < n; i++)
    g->pad_first[i + 1] += g->pad_first[i];
  g->pad = malloc((npad ? npad : 1) * sizeof *g->pad);
  uint32_t *fill = malloc((n ? n : 1) * sizeof *fill);
  if (!g->pad || !fill) {
    free(src);
    free(fill);
    return 0;
  }
  memcpy(fill, g->pad_first, n * sizeof *fill);
  for (size_t i = 0; i < n; i++)
    if (src[i] != UINT32_MAX)
      g->pad[fill[src[i]]++] = (uint32_t)i;
  free(fill);
  free(src);
  return 1;
}

static void atlases_free(game_atlas *ga, uint32_t n)
{
  for (uint32_t a = 0; ga && a < n; a++) {
    free(ga[a].tex);
    free(ga[a].pad_first);
    free(ga[a].pad);
  }
  free(ga);
}

/* After an update: the changed texels into the textures, with their padding (what a game
 * copies into a staging buffer and uploads as dirty regions). Returns the texels read. */
static uint64_t upload_changes(const ub_runtime *rt, game_atlas *ga)
{
  enum { BATCH = 4096 };
  static ub_runtime_texel_change batch[BATCH];
  const uint64_t n = ub_runtime_changed_texel_count(rt);
  for (uint64_t start = 0; start < n; start += BATCH) {
    size_t got = ub_runtime_changed_texels(rt, start, BATCH, batch);
    for (size_t i = 0; i < got; i++) {
      game_atlas *g = &ga[batch[i].atlas];
      const uint32_t p = batch[i].y * g->w + batch[i].x;
      g->tex[p] = batch[i].ahd;
      for (uint32_t k = g->pad_first[p]; k < g->pad_first[p + 1]; k++)
        g->tex[g->pad[k]] = batch[i].ahd;
    }
  }
  return n;
}

/* The textures equal the run-time's atlases, bit for bit. */
static int textures_match(const ub_runtime *rt, const game_atlas *ga, uint32_t atlases)
{
  for (uint32_t a = 0; a < atlases; a++) {
    const size_t n = (size_t)ga[a].w * ga[a].h;
    ub_ahd_packed *want = malloc((n ? n : 1) * sizeof *want);
    int ok = want && ub_runtime_atlas_ahd(rt, a, want) == UB_OK &&
             memcmp(want, ga[a].tex, n * sizeof *want) == 0;
    free(want);
    if (!ok)
      return 0;
  }
  return 1;
}

static void log_stderr(void *user, ub_log_level level, const char *message)
{
  (void)user;
  fprintf(stderr, "%s: %s\n", level == UB_LOG_ERROR ? "error" : level == UB_LOG_WARNING ? "warning" : "info", message);
}

int main(int argc, char **argv)
{
  if (argc < 2 || !strcmp(argv[1], "--help")) {
    fprintf(argc < 2 ? stderr : stdout,
            "usage: example_game_loop FILE.ubk [--toggles N]\n"
            "Loads FILE.ubk with the run-time library, uploads its lightmaps, toggles its\n"
            "dynamic light sets N times (default 2 per set) re-uploading only what changed,\n"
            "and checks the incremental uploads against the whole atlases.\n");
    return argc < 2 ? 2 : 0;
  }
  uint32_t toggles = 0;
  if (argc >= 4 && !strcmp(argv[2], "--toggles"))
    toggles = (uint32_t)strtoul(argv[3], NULL, 10);
  const ub_log log = {log_stderr, NULL};
  ub_runtime *rt = NULL;
  if (ub_runtime_load(argv[1], &log, &rt) != UB_OK)
    return 1;
  /* The level's normal lighting (as loaded: every set on) is what the game returns to:
   * kept, a set turned back on costs a copy of its texels instead of a re-encode. */
  if (ub_runtime_keep_state(rt) != UB_OK) {
    fprintf(stderr, "example_game_loop: out of memory keeping the load state\n");
    ub_runtime_free(rt);
    return 1;
  }
  const ub_bakefile *bf = ub_runtime_bakefile(rt);
  const uint32_t sets = ub_runtime_dls_count(rt), atlases = bf->atlas_count;
  if (!toggles)
    toggles = 2 * sets;
  game_atlas *ga = calloc(atlases ? atlases : 1, sizeof *ga);
  int ok = ga != NULL;
  for (uint32_t a = 0; ok && a < atlases; a++)
    ok = atlas_setup(rt, a, &ga[a]);
  if (!ok) {
    fprintf(stderr, "example_game_loop: out of memory\n");
    atlases_free(ga, atlases);
    ub_runtime_free(rt);
    return 1;
  }
  printf("%s: %u atlas(es), %u dynamic light sets, %u LLG models; AHD scale %g\n", argv[1],
         atlases, sets, bf->llg_count, (double)ub_runtime_ahd_scale(rt));

  ub_glg_cursor cursor; /* one moving object */
  ub_glg_cursor_init(&cursor);
  uint64_t texels = 0, models = 0, kept = 0;
  ub_runtime_update_stats us;
  uint32_t bad = 0;
  uint32_t h = 2024u;
  for (uint32_t t = 0; t < toggles && sets; t++) {
    /* the game turns a set off or on (or tints it) ... */
    h = h * 1664525u + 1013904223u;
    const uint32_t s = (h >> 8) % sets;
    const uint32_t kind = h >> 29; /* off, back on, or tinted */
    const float w = kind < 3 ? 0.0f : kind < 5 ? 1.0f : (float)((h >> 12) & 0xff) / 128.0f;
    const float rgb[3] = {w, kind < 5 ? w : w * 0.8f, kind < 5 ? w : w * 1.1f};
    if (ub_runtime_set_dls(rt, s, rgb) != UB_OK)
      bad++;
    /* ... updates: every other frame split into jobs (ub_runtime_update_job(rt, j) would
     * run on the job system's threads; here one after the other), else in one call */
    if (t & 1) {
      uint32_t jobs = 0;
      if (ub_runtime_update_begin(rt, 2, &jobs) != UB_OK) {
        bad++;
        break;
      }
      for (uint32_t j = 0; j < jobs; j++)
        ub_runtime_update_job(rt, j);
      ub_runtime_update_end(rt, &us);
    } else if (ub_runtime_update(rt, &us) != UB_OK) {
      bad++;
      break;
    }
    kept += us.texels_kept;
    /* ... re-uploads the lightmap texels and LLG grids that changed ... */
    texels += upload_changes(rt, ga);
    for (uint32_t m = 0; m < bf->llg_count; m++)
      models += (uint64_t)ub_runtime_llg_changed(rt, m); /* upload bf->llgs[m].probe_sh */
    /* ... and the moving object reads the global grid where it is now */
    if (bf->glg_probe_count) {
      const float p[3] = {0.1f * (float)t, 1.0f, 0.0f}, n[3] = {0.0f, 1.0f, 0.0f};
      float e[3];
      if (ub_runtime_query_glg_cursor(rt, p, n, &cursor, e) != UB_OK)
        bad++;
    }
    bad += !textures_match(rt, ga, atlases);
  }
  printf("%u toggles: %llu texels (%llu of them copied back from the kept state) and %llu LLG "
         "grids re-uploaded; textures %s the run-time's atlases after every one (%u "
         "mismatches)\n", toggles, (unsigned long long)texels, (unsigned long long)kept,
         (unsigned long long)models, bad ? "DIFFER from" : "equal", bad);
  atlases_free(ga, atlases);
  ub_runtime_free(rt);
  return bad ? 1 : 0;
}
