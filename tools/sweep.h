/* tools/sweep.h — `ubake sweep`: what accuracy costs in time, for one level.
 *
 * Bakes a ladder of settings (gather rays, bounces, texel size, GLG spacing, the presets),
 * each knob varied alone from the middle setting (the `fast` preset), and measures every
 * bake against ground truth:
 *   - the reference path tracer at a fixed set of points (lightmap surface points and
 *     GLG points in free space), computed once per point and cached in
 *     DIR/reference_points.csv, so a rerun (or a resumed run) traces nothing twice;
 *   - a converged bake (many gather rays, same texel size) at every covered texel.
 * Writes DIR/sweep.csv (rewritten after every rung), DIR/sweep.gp and DIR/sweep.png
 * (gnuplot: error vs seconds, log-log, one curve per knob), and, when the ladder has preset
 * rungs, DIR/presets.md: README's preset table rows (`--ladder presets` bakes only those).
 *
 * Part of the command-line program: it prints progress and errors itself. Returns the
 * process exit status (0 ok, 1 error). argv holds the arguments after "sweep".
 */
#ifndef UBAKE_TOOLS_SWEEP_H
#define UBAKE_TOOLS_SWEEP_H

int ub_cli_sweep(int argc, char **argv);

#endif
