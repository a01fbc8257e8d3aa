/* The bake, as a script: load → rays → receivers → plan → passes → encode → write. */
#include "ubake/bake.h"

#include <errno.h>
#include <math.h>
#include <omp.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "bake/dls.h"
#include "bake/geomstate.h"
#include "bake/lights.h"
#include "bake/outdir.h"
#include "bake/output.h"
#include "bake/pass.h"
#include "bake/plan.h"
#include "bake/rt.h"
#include "doors/door.h"
#include "doors/object.h"
#include "lightmaps/lightmap.h"
#include "probes/leak.h"
#include "probes/llg.h"
#include "probes/placement.h"
#include "probes/tetgen.h"
#include "ubake/scene.h"

void ub_bake_options_default(ub_bake_options *o)
{
  memset(o, 0, sizeof *o);
  o->quality = UB_QUALITY_FAST;
  o->bounces = -1;
  o->seed = 1;
}

const char *ub_quality_name(ub_quality q)
{
  switch (q) {
  case UB_QUALITY_DRAFT: return "draft";
  case UB_QUALITY_FAST: return "fast";
  case UB_QUALITY_HIGH: return "high";
  }
  return "?";
}

int ub_quality_from_name(const char *name, ub_quality *out)
{
  static const ub_quality all[] = {UB_QUALITY_DRAFT, UB_QUALITY_FAST, UB_QUALITY_HIGH};
  for (size_t i = 0; name && i < sizeof all / sizeof all[0]; i++)
    if (!strcmp(name, ub_quality_name(all[i]))) {
      *out = all[i];
      return 1;
    }
  return 0;
}

static double now_seconds(void)
{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

long ub_peak_rss_kb(void)
{
  struct rusage ru;
  if (getrusage(RUSAGE_SELF, &ru) != 0)
    return 0;
  return ru.ru_maxrss;
}

long ub_proc_status_kb(const char *key)
{
  long kb = -1;
  char line[256];
  size_t n = strlen(key);
  FILE *f = fopen("/proc/self/status", "r");
  if (!f)
    return -1;
  while (fgets(line, sizeof line, f))
    if (!strncmp(line, key, n)) {
      kb = strtol(line + n, NULL, 10);
      break;
    }
  fclose(f);
  return kb;
}

int ub_peak_rss_reset(void)
{
  FILE *f = fopen("/proc/self/clear_refs", "w"); /* "5": reset VmHWM */
  if (!f)
    return 0;
  int ok = fputs("5", f) >= 0;
  return fclose(f) == 0 && ok;
}

typedef struct stage_clock {
  ub_bake_stats *stats;
  const ub_log *log;
  double t0;
} stage_clock;

static void stage_begin(stage_clock *sc, const char *name)
{
  ub_bake_stats *st = sc->stats;
  if (st->stage_count < UB_BAKE_MAX_STAGES) {
    snprintf(st->stage_name[st->stage_count], sizeof st->stage_name[0], "%s", name);
    st->stage_seconds[st->stage_count] = 0.0;
  }
  sc->t0 = now_seconds();
}

static void stage_end(stage_clock *sc, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void stage_end(stage_clock *sc, const char *fmt, ...)
{
  ub_bake_stats *st = sc->stats;
  double dt = now_seconds() - sc->t0;
  const char *name = "?";
  if (st->stage_count < UB_BAKE_MAX_STAGES) {
    st->stage_seconds[st->stage_count] = dt;
    name = st->stage_name[st->stage_count];
    st->stage_count++;
  }
  char msg[512];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg, sizeof msg, fmt, ap);
  va_end(ap);
  ub_log_printf(sc->log, UB_LOG_INFO, "[%-9s] %6.2f s  %s", name, dt, msg);
}

ub_result ub_bake_level(const char *level_path, const ub_bake_options *opt, const ub_log *log,
                        ub_bake_stats *out_stats)
{
  ub_bake_stats stats;
  memset(&stats, 0, sizeof stats);
  double t_start = now_seconds();
  stage_clock sc = {&stats, log, 0.0};
  /* opt->threads for this bake's parallel regions; the caller's default comes back after
   * (omp_set_num_threads is the calling thread's setting: a tool running references or
   * another bake afterwards would otherwise inherit it) */
  const int caller_threads = omp_get_max_threads();
  if (opt->threads > 0)
    omp_set_num_threads(opt->threads);

  ub_scene *scene = NULL;
  ub_rt *rt = NULL;
  ub_lightmap *lm = NULL;
  ub_emitters *em = NULL;
  ub_glg_points gp;
  memset(&gp, 0, sizeof gp);
  ub_tetmesh *tm = NULL;
  ub_glg_leak leak;
  memset(&leak, 0, sizeof leak);
  ub_plan plan;
  memset(&plan, 0, sizeof plan);
  ub_llg_set llg;
  memset(&llg, 0, sizeof llg);
  ub_pass_result base;
  memset(&base, 0, sizeof base);
  ub_pass_cache *pass_cache = NULL;
  ub_bakefile_record *dls = NULL;
  ub_dls_stats dstats;
  memset(&dstats, 0, sizeof dstats);
  ub_bakefile_record *elems = NULL; /* doors, objects, combinations */
  uint32_t elem_count = 0;
  uint32_t *orig_material = NULL;   /* materials before closed leaves turned black */
  uint8_t *base_mask = NULL;
  ub_output *out = NULL;
  ub_result r;

  /* The level's name and the output folder first: a bad one fails now, not after the bake
   * (the staging folder is made here; ub_output_close removes it whatever happens). */
  r = ub_outdir_level_name(level_path, log, stats.level_name, sizeof stats.level_name);
  if (r != UB_OK)
    goto fail;
  if (!opt->plan_only) {
    r = ub_output_open(stats.level_name, opt, log, &out);
    if (r != UB_OK)
      goto fail;
  }

  /* load */
  stage_begin(&sc, "load");
  r = ub_scene_load(level_path, log, &scene);
  if (r != UB_OK)
    goto fail;
  stats.triangles = scene->triangle_count;
  stats.lights = scene->light_count;
  stage_end(&sc, "%u triangles (%u degenerate), %u materials, %u lights, %u nodes",
            scene->triangle_count, scene->degenerate_count, scene->material_count,
            scene->light_count, scene->node_count);

  /* rays: the base geometry state (bake/geomstate.h) */
  stage_begin(&sc, "rays");
  r = ub_geom_prepare(scene, log, &orig_material);
  if (r != UB_OK)
    goto fail;
  base_mask = ub_geom_mask(scene, NULL);
  if (!base_mask) {
    r = UB_ERR_OUT_OF_MEMORY;
    goto fail;
  }
  r = ub_rt_create(scene, base_mask, log, &rt);
  if (r != UB_OK)
    goto fail;
  r = ub_emitters_build(scene, &em);
  if (r != UB_OK)
    goto fail;
  stats.emissive_triangles = em->count;
  stage_end(&sc, "Embree BVH over %u triangles, %u emissive, %llu facing another in their plane",
            scene->triangle_count, em->count, (unsigned long long)ub_rt_twin_count(rt));

  /* receivers */
  stage_begin(&sc, "receivers");
  if (opt->texel_size > 0.0f)
    scene->texel_size = opt->texel_size; /* the command line overrides the level default */
  r = ub_lightmap_build(scene, rt, scene->texel_size, log, &lm);
  if (r != UB_OK)
    goto fail;
  /* Small untagged props whose charts came out poor become LLG receivers (a tag always
   * wins); the lightmap is then laid out again without them. */
  {
    ub_llg_auto_stats as;
    r = ub_llg_auto_select(scene, lm, &as);
    if (r != UB_OK)
      goto fail;
    stats.llg_auto_nodes = as.switched;
    if (as.switched) {
      ub_log_printf(log, UB_LOG_INFO, "  llg auto: %u of %u small untagged node(s) have poor "
                    "lightmap charts (%u charts, %llu texels): made LLG receivers",
                    as.switched, as.considered, as.charts_freed,
                    (unsigned long long)as.texels_freed);
      for (uint32_t n = 0; n < scene->node_count; n++)
        if (scene->nodes[n].receiver_source == UB_RECEIVER_AUTO)
          ub_log_printf(log, UB_LOG_INFO, "    llg auto: %s", scene->nodes[n].name);
      ub_lightmap_free(lm);
      lm = NULL;
      r = ub_lightmap_build(scene, rt, scene->texel_size, log, &lm);
      if (r != UB_OK)
        goto fail;
    }
  }
  stats.atlases = lm->atlas_count;
  stats.texels = lm->texel_count;
  stats.backface_fixes = lm->backface_fixes;
  stage_end(&sc, "%u atlases, %u texels, %u sample points moved off back faces",
            lm->atlas_count, lm->texel_count, lm->backface_fixes);

  /* probes: GLG placement and its tetrahedralisation (TetGen, child process) */
  stage_begin(&sc, "probes");
  if (opt->glg_spacing > 0.0f)
    scene->glg_spacing = opt->glg_spacing;
  r = ub_glg_place(scene, rt, lm, scene->glg_spacing,
                   opt->glg_max_cells ? opt->glg_max_cells : UB_GLG_MAX_OCCUPIED_DEFAULT, log,
                   &gp);
  if (r != UB_OK)
    goto fail;
  scene->glg_spacing = gp.spacing; /* widened or not: what the report says */
  r = ub_tetgen_build(gp.pos, gp.count, log, &tm);
  if (r != UB_OK)
    goto fail;
  stats.glg_probes = tm->point_count;
  stats.glg_tets = tm->tet_count;
  stage_end(&sc, "GLG: %u probes (%u coarse, %u near geometry, %u inside solids dropped, %u "
            "added hull), %u tets",
            tm->point_count, gp.coarse, gp.fine, gp.rejected_inside, tm->added_count,
            tm->tet_count);

  /* local light grids: boxes, probes, per-vertex self-visibility */
  stage_begin(&sc, "llg");
  {
    uint32_t vis_rays = opt->quality == UB_QUALITY_DRAFT ? 128u
                        : opt->quality == UB_QUALITY_FAST ? 256u : 1024u;
    r = ub_llg_build(scene, vis_rays, opt->seed, log, &llg);
    if (r != UB_OK)
      goto fail;
    uint32_t nv = 0;
    for (uint32_t i = 0; i < llg.model_count; i++)
      nv += llg.models[i].vertex_count;
    stage_end(&sc, "%u model(s) (%u share an instance's self-visibility), %u probes (%u moved "
              "out of other geometry, %u filled), %u vertices, %.2f M rays", llg.model_count,
              llg.vis_shared, llg.probe_count, llg.moved_count, llg.invalid_count, nv,
              llg.rays * 1e-6);
  }

  /* plan */
  stage_begin(&sc, "plan");
  r = ub_plan_build(scene, rt, em, lm, tm->point_count, opt, log, &plan);
  if (r != UB_OK)
    goto fail;
  char reach_s[64] = "";
  if (scene->dls_count) /* DLS work done here, reused by the sets' stage */
    snprintf(reach_s, sizeof reach_s, " (the sets' reach %.2f s)", plan.dls_reach_seconds);
  stage_end(&sc, "%u pass(es), %u of %u lights in the base pass, sky %s, emissive %s%s",
            plan.pass_count, plan.base_lights, scene->light_count, plan.sky ? "yes" : "no",
            plan.emissive ? "yes" : "no", reach_s);
  ub_plan_print(&plan, scene, log);
  if (opt->plan_only) {
    stats.total_seconds = now_seconds() - t_start;
    stats.peak_rss_kb = ub_peak_rss_kb();
    goto fail; /* r == UB_OK: nothing is written */
  }

  /* passes */
  stage_begin(&sc, "base pass");
  ub_pass_desc pd;
  memset(&pd, 0, sizeof pd);
  pd.scene = scene;
  pd.rt = rt;
  pd.emitters = em;
  pd.lightmap = lm;
  pd.light_enabled = plan.base_light_enabled;
  pd.emissive = plan.emissive;
  pd.sky = plan.sky;
  pd.gather_rays = plan.gather_rays;
  pd.emissive_samples = plan.emissive_samples;
  pd.shadow_samples = plan.shadow_samples;
  pd.near_samples = plan.near_samples;
  pd.probe_count = tm->point_count;
  pd.probe_pos = tm->points;
  pd.probe_rays = plan.probe_rays;
  pd.llg = llg.model_count ? &llg : NULL;
  pd.bounces = opt->bounces;
  pd.bounce_full_rays = opt->bounce_full_rays;
  pd.stop_fraction = plan.stop_fraction;
  pd.seed = opt->seed;
  pd.pass_id = 0;
  pd.target_error = opt->target_error > 0.0 && isfinite(opt->target_error) ? opt->target_error
                                                                            : 0.0;
  pd.progress = opt->progress;
  pd.progress_user = opt->progress_user;
  pd.progress_base = 0.0;
  pd.progress_span = 1.0;
  pass_cache = ub_pass_cache_create(); /* shared by the base pass and every element's */
  pd.cache = pass_cache;
  double tg = now_seconds();
  r = ub_pass_run(&pd, log, &base);
  stats.gather_seconds = now_seconds() - tg;
  if (r != UB_OK)
    goto fail;
  stats.bounces = base.bounces;
  memcpy(stats.bounce_energy, base.bounce_energy, sizeof stats.bounce_energy);
  stats.bounce_cap_tail = base.bounce_cap_tail;
  stats.rays_gather = base.rays_gather;
  stats.rays_adaptive = base.rays_adaptive;
  pd.target_error = 0.0; /* dynamic light sets: their own sample counts, not adaptive */
  stats.rays_shadow = base.rays_shadow;
  stats.rays_total = ub_rt_rays_traced(rt);
  stats.clamped_values += base.clamped;
  stats.backface_hits = base.backface_hits;
  stats.unlit_hits = base.unlit_hits;
  stats.rays_emissive = base.rays_emissive;
  stats.sky_hits = base.sky_hits;
  stats.emitter_hits = base.emitter_hits;
  stage_end(&sc, "%u bounces, %.1f M gather + %.1f M shadow rays, %.2f M rays/s",
            base.bounces, base.rays_gather * 1e-6, base.rays_shadow * 1e-6,
            stats.gather_seconds > 0 ? (base.rays_gather + base.rays_shadow) * 1e-6 /
                                           stats.gather_seconds
                                     : 0.0);

  /* LLG self-inter-reflection: what each model's own surfaces reflect onto its vertices */
  if (llg.model_count) {
    stage_begin(&sc, "llg self");
    uint64_t r0 = llg.rays;
    uint32_t self_rays = opt->quality == UB_QUALITY_DRAFT ? 64u
                         : opt->quality == UB_QUALITY_FAST ? 256u : 1024u;
    r = ub_llg_self_bounce(&llg, scene, rt, base.llg_sh, plan.base_light_enabled, self_rays,
                           opt->seed);
    if (r != UB_OK)
      goto fail;
    stage_end(&sc, "%u model(s), %u iterations, %.2f M rays", llg.model_count,
              UB_LLG_SELF_ITERATIONS, (llg.rays - r0) * 1e-6);
  }

  /* dynamic light sets: influence pass + full pass over the kept receivers, per set */
  if (scene->dls_count) {
    stage_begin(&sc, "dls");
    r = ub_dls_bake(&pd, &plan, log, &dls, &dstats);
    if (r != UB_OK)
      goto fail;
    stats.dls_sets = dstats.sets_baked;
    stats.rays_total = ub_rt_rays_traced(rt);
    stage_end(&sc, "%u set(s) baked, %u reach nothing; influence %.1f M rays %.2f s, full %.1f "
              "M rays %.2f s (bounce-1 gathers at %.1f%% of the full rays%s)",
              dstats.sets_baked, dstats.sets_empty, dstats.rays_influence * 1e-6,
              dstats.seconds_influence, dstats.rays_full * 1e-6, dstats.seconds_full,
              dstats.gather_units_full ? 100.0 * dstats.gather_units / dstats.gather_units_full
                                       : 100.0,
              plan.dls_scaled_rays ? ", scaled where faint" : "");
  }

  /* doors: one pass each (doors/door.h), records S_open − S_base for their influence */
  ub_door_desc dd;
  memset(&dd, 0, sizeof dd);
  if (plan.door_passes) {
    stage_begin(&sc, "doors");
    dd.base = &pd;
    dd.base_result = &base;
    dd.rays = plan.door_rays;
    dd.influence_rays = plan.door_influence_rays;
    dd.photons = plan.door_photons;
    dd.guiding = !opt->door_no_guiding;
    ub_door_stats ds;
    r = ub_door_bake(&dd, log, &elems, &ds);
    if (r != UB_OK)
      goto fail;
    elem_count = scene->door_count;
    stats.door_passes = ds.doors_baked;
    stage_end(&sc, "%u door(s) baked%s, %u photons in %u box(es); influence %.1f M rays %.2f "
              "s, full %.1f M rays %.2f s", ds.doors_baked, dd.guiding ? "" : " (no guiding)",
              ds.photons_deposited, ds.boxes, ds.rays_influence * 1e-6, ds.seconds_influence,
              ds.rays_full * 1e-6, ds.seconds_full);
  }

  /* show/hide objects (doors/object.h): after any door records, objects then combinations */
  if (scene->object_count) {
    stage_begin(&sc, "objects");
    ub_object_stats ost;
    r = ub_object_bake(&pd, &plan, &base, dls, log, &elems, &elem_count, &ost);
    if (r != UB_OK)
      goto fail;
    stats.rays_total = ub_rt_rays_traced(rt);
    stage_end(&sc, "%u of %u object(s), %u pair correction(s), %u set × object, %.1f M rays",
              ost.objects_baked, ost.objects, ost.pairs, ost.set_objects, ost.rays * 1e-6);
  }

  /* door × set combinations (doors/door.h): tagged, regions overlapping; listed last */
  if (plan.combo_count && plan.door_passes) {
    stage_begin(&sc, "combinations");
    ub_door_stats cs;
    memset(&cs, 0, sizeof cs);
    r = ub_door_combine(&dd, &plan, dls, log, &elems, &elem_count, &cs);
    if (r != UB_OK)
      goto fail;
    stage_end(&sc, "%u combination(s) baked, %u skipped; %.1f M rays %.2f s",
              cs.combos_baked, cs.combos_skipped, (cs.rays_influence + cs.rays_full) * 1e-6,
              cs.seconds_influence + cs.seconds_full);
  }

  /* No pass after this one: the passes' shared scratch (level-sized images and arrays the
   * element passes kept for each other, ~650 MB at ESTATE scale) goes before the write
   * stage adds its own images on top (the bake's peak RSS was there). */
  ub_pass_cache_free(pass_cache);
  pass_cache = NULL;
  pd.cache = NULL;

  /* leak control: a separating plane for every tet that straddles a surface */
  stage_begin(&sc, "leak");
  r = ub_glg_leak_build(rt, tm->point_count, tm->points, tm->tet_count, tm->tets, &leak);
  if (r != UB_OK)
    goto fail;
  stats.glg_leak_tets = leak.tets;
  stage_end(&sc, "%u of %u tets straddle a surface, %u distinct planes (%.2f M rays)", leak.tets,
            tm->tet_count, leak.plane_count, leak.rays * 1e-6);

  /* encode + write: the time and peak so far go in; the write stage adds its own before
   * it writes the report, and the bake's totals stay the report's */
  stage_begin(&sc, "write");
  stats.peak_rss_kb = ub_peak_rss_kb();
  stats.total_seconds = now_seconds() - t_start;
  ub_glg_bake glg = {tm, base.probe_sh, &leak};
  r = ub_output_write(out, scene, lm, &glg, &llg, base.llg_sh, dls, &dstats, elems, elem_count,
                      orig_material, &plan, &base, opt, &stats, log);
  if (r != UB_OK)
    goto fail;
  stage_end(&sc, "%s", stats.ubk_path);

fail:
  ub_output_close(out);
  ub_pass_result_free(&base);
  ub_pass_cache_free(pass_cache);
  ub_dls_records_free(elems, elem_count);
  free(base_mask);
  free(orig_material);
  ub_dls_records_free(dls, scene ? scene->dls_count : 0);
  ub_dls_stats_free(&dstats);
  ub_plan_free(&plan);
  ub_llg_free(&llg);
  ub_glg_leak_free(&leak);
  ub_tetmesh_free(tm);
  ub_glg_points_free(&gp);
  ub_lightmap_free(lm);
  ub_emitters_free(em);
  ub_rt_free(rt);
  ub_scene_free(scene);
  if (out_stats)
    *out_stats = stats;
  omp_set_num_threads(caller_threads);
  return r;
}
