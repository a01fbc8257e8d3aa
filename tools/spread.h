/* tools/spread.h — `ubake spread A.ubk B.ubk …`: how far each dynamic element's record
 * varies between bakes of one level with different seeds (noise, and single samples that
 * outweigh the rest). Part of the command-line program: prints its table and errors
 * itself; returns the exit status. argv holds the arguments after "spread". */
#ifndef UBAKE_TOOLS_SPREAD_H
#define UBAKE_TOOLS_SPREAD_H

int ub_cli_spread(int argc, char **argv);

#endif
