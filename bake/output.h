/* bake/output.h — the bake's last stage: encode and write every output file.
 * Writes DIR/NAME.ubk, DIR/NAME_lm<i>.exr (AHD, half), DIR/NAME_lm<i>.png (irradiance
 * preview) and the report, all staged and renamed into place only on success. */
#ifndef UBAKE_BAKE_OUTPUT_H
#define UBAKE_BAKE_OUTPUT_H

#include "bake/pass.h"
#include "bake/plan.h"

ub_result ub_output_write(const ub_scene *scene, const ub_lightmap *lm, const ub_plan *plan,
                          const ub_pass_result *base, const ub_bake_options *opt,
                          ub_bake_stats *stats, const ub_log *log);

long ub_peak_rss_kb(void);

#endif
