/* Replays the fuzz inputs through the loaders in the normal build (no clang needed):
 * tests/fuzz/regress-<target>/ (crashers and hand-made hostile inputs; the file name says
 * what must happen: accept_* must load, reject_* must fail cleanly) and the seed corpora
 * tests/fuzz/corpus-<target>/ (every seed must load: they are valid files).
 * Targets: fuzz_gltf → ub_scene_load_memory, fuzz_ubk → ub_bakefile_read_memory,
 * fuzz_ubk_crc → the same after rewriting the CRCs as that target does. Under
 * make test-sanitize this is where a regression of a fixed crash shows up. */
#include <dirent.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "runtime/crc32.h"
#include "test_util.h"
#include "ubake/bakefile.h"
#include "ubake/scene.h"

static unsigned char *read_file(const char *path, size_t *out_n)
{
  FILE *f = fopen(path, "rb");
  if (!f)
    return NULL;
  size_t cap = 1 << 16, n = 0;
  unsigned char *buf = malloc(cap);
  size_t k;
  while (buf && (k = fread(buf + n, 1, cap - n, f)) > 0) {
    n += k;
    if (n == cap) {
      unsigned char *nb = realloc(buf, cap *= 2);
      if (!nb) {
        free(buf);
        buf = NULL;
      }
      buf = nb;
    }
  }
  fclose(f);
  *out_n = n;
  return buf;
}

static int cmp_str(const void *a, const void *b)
{
  return strcmp(*(char *const *)a, *(char *const *)b);
}

/* Scene invariants scene.h promises (same as the fuzz target checks). */
static int scene_ok(const ub_scene *s)
{
  for (uint32_t t = 0; t < s->triangle_count; t++)
    for (int k = 0; k < 3; k++)
      if (s->indices[3 * (size_t)t + k] >= s->vertex_count || s->tri_material[t] >= s->material_count)
        return 0;
  for (size_t i = 0; i < (size_t)s->vertex_count * 3; i++)
    if (!isfinite(s->positions[i]) || !isfinite(s->normals[i]))
      return 0;
  return isfinite(ub_scene_extent(s));
}

/* tests/fuzz/fuzz_ubk_crc.c's fix-up: section CRCs, then the header CRC, rewritten. */
static uint32_t rd32(const unsigned char *p)
{
  return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static void wr32(unsigned char *p, uint32_t v)
{
  for (int i = 0; i < 4; i++)
    p[i] = (unsigned char)(v >> (8 * i));
}
static void fix_crcs(unsigned char *buf, size_t size)
{
  if (size < 16)
    return;
  uint64_t n = rd32(buf + 8);
  if (n > (size - 16) / 32)
    return;
  for (uint64_t i = 0; i < n; i++) {
    unsigned char *e = buf + 16 + 32 * i;
    uint64_t off = rd32(e + 8) | (uint64_t)rd32(e + 12) << 32;
    uint64_t len = rd32(e + 16) | (uint64_t)rd32(e + 20) << 32;
    if (off <= size && len <= size - off)
      wr32(e + 24, ub_crc32_update(0, buf + off, (size_t)len));
  }
  uint32_t crc = ub_crc32_update(0, buf, 12);
  wr32(buf + 12, ub_crc32_update(crc, buf + 16, (size_t)(32 * n)));
}

/* 1: loaded, 0: rejected. */
static int run_one(const char *target, unsigned char *data, size_t n, const char *name)
{
  if (!strcmp(target, "fuzz_gltf")) {
    ub_scene *s = NULL;
    if (ub_scene_load_memory(data, n, name, NULL, &s) != UB_OK)
      return 0;
    int ok = scene_ok(s);
    ASSERT_TRUE(ok);
    ub_scene_free(s);
    return 1;
  }
  if (!strcmp(target, "fuzz_ubk_crc"))
    fix_crcs((unsigned char *)data, n);
  ub_bakefile *bf = NULL;
  if (ub_bakefile_read_memory(data, n, name, NULL, &bf) != UB_OK)
    return 0;
  ub_bakefile_free(bf);
  return 1;
}

static void run_dir(const char *source, const char *target, const char *kind)
{
  char dir[1024];
  snprintf(dir, sizeof dir, "%s/tests/fuzz/%s-%s", source, kind, target);
  DIR *d = opendir(dir);
  if (!d) {
    printf("%s: none\n", dir);
    return;
  }
  char **names = NULL;
  size_t count = 0;
  struct dirent *e;
  while ((e = readdir(d)) != NULL) {
    if (e->d_name[0] == '.')
      continue;
    names = realloc(names, (count + 1) * sizeof *names);
    names[count++] = strdup(e->d_name);
  }
  closedir(d);
  qsort(names, count, sizeof *names, cmp_str);
  size_t loaded = 0, wrong = 0;
  for (size_t i = 0; i < count; i++) {
    char path[2048];
    snprintf(path, sizeof path, "%s/%s", dir, names[i]);
    size_t n = 0;
    unsigned char *data = read_file(path, &n);
    ASSERT_TRUE(data != NULL);
    if (!data)
      continue;
    int ok = run_one(target, data, n, names[i]);
    loaded += ok;
    /* .ubk seeds go stale when the format version moves on: reported, not failed */
    int want = !strcmp(kind, "corpus") ? (strncmp(target, "fuzz_ubk", 8) ? 1 : -1)
               : !strncmp(names[i], "accept_", 7) ? 1
               : !strncmp(names[i], "reject_", 7) ? 0
                                                  : -1;
    if (want >= 0 && ok != want) {
      fprintf(stderr, "%s: %s, expected %s\n", path, ok ? "loaded" : "rejected",
              want ? "to load" : "a rejection");
      wrong++;
    }
    free(data);
    free(names[i]);
  }
  free(names);
  printf("%s: %zu inputs, %zu loaded, %zu unexpected\n", dir, count, loaded, wrong);
  if (!strcmp(kind, "corpus") && loaded < count)
    printf("  note: %zu seed(s) of %s no longer load; regenerate the corpus\n", count - loaded, target);
  ASSERT_TRUE(wrong == 0);
}

int main(void)
{
  const char *src = getenv("UB_SOURCE");
  if (!src)
    src = ".";
  const char *targets[3] = {"fuzz_gltf", "fuzz_ubk", "fuzz_ubk_crc"};
  for (int t = 0; t < 3; t++) {
    run_dir(src, targets[t], "regress");
    run_dir(src, targets[t], "corpus");
  }
  /* NULL and zero-size edges of the memory loader */
  ub_scene *s = NULL;
  ASSERT_TRUE(ub_scene_load_memory(NULL, 0, NULL, NULL, &s) != UB_OK && s == NULL);
  ASSERT_TRUE(ub_scene_load_memory(NULL, 4, "x", NULL, &s) == UB_ERR_INVALID_ARGUMENT);
  ASSERT_TRUE(ub_scene_load_memory("{}", 2, "x", NULL, NULL) == UB_ERR_INVALID_ARGUMENT);
  TEST_MAIN_END();
}
